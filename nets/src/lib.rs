//! talkin-nets: the burn side of talkin. Owns the encodings (sinusoidal with a Hann
//! window, multiresolution hash grid), the TalkinNeRF field (inverse LBS with a learned
//! weight volume, D_nr, F_body with segmentation, F_face, D_hands + F_hands with hard
//! routing), volume rendering of packed samples, and the losses.
//!
//! It must not know about the acceleration structures (`grids`) or the pipeline
//! (`engine`): samples, candidate masks and per-frame transforms come in as plain slices.
//! The backend is chosen at run time through burn's `Device` (`Device::flex()` on CPU,
//! `.autodiff()` for training).
pub mod loss;
pub mod encoding;
pub mod error;
pub mod field;
pub mod mlp;
pub mod render;
pub mod skinning;
mod util;

pub use error::NetsError;
pub use field::{FieldConfig, FieldInput, FieldOutput, FrameConditions, TalkinField};
pub use render::{RaySamples, RenderedRays, render_packed};
