//! `talkin inspect`: full validation of a dataset (every pixel decoded), a summary, a
//! contact sheet with segmentation overlay and projected skeleton, and the posed joints
//! with their projections, so a person can check that fits and images line up.

mod joints;
mod sheet;
mod summary;

pub use joints::{FrameJoints, frame_joints};
pub use sheet::contact_sheet;
pub use summary::{Summary, summarize};
