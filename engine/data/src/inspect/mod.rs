//! `talkin inspect`: full validation of a dataset (every pixel decoded), a summary, a
//! contact sheet with segmentation overlay and projected skeleton, the overlay check
//! (fitted capsules and skeleton on the images, per-frame share of joints on the person)
//! and the posed joints with their projections. [`validate`] is the same check, run by
//! every command before any work.

mod expressions;
mod joints;
mod overlay;
mod sheet;
mod summary;
mod validate;

pub use expressions::extra_expression_note;
pub use joints::{FrameJoints, frame_joints};
pub use overlay::{overlay_frames, overlay_sheet};
pub use sheet::contact_sheet;
pub use summary::{FrameCheck, Summary, summarize};
pub use validate::{
    FRAME_MIN_JOINTS_ON_PERSON, MAX_MASK_SEG_DISAGREEMENT, MIN_JOINTS_ON_PERSON, Problem, validate,
};
