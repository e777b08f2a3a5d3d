//! Wiring the grids crate to the human: per-frame capsules and rays, the margins the
//! training masks decide, the canonical occupancy grid (carved to the training surfaces
//! when depth is known) and the posed-to-canonical map that culls samples, (its
//! report is `talkin bench sampling`, in the benches crate).

mod carve;
mod frame;
mod frame_sampler;
mod initial_grid;
mod shells;

pub use carve::{CARVED_PARTS, canonical_surface_points};
pub use frame::{FrameScene, capsule_bounds, foreground_rays, median_dense_step, shell_capsules};
pub use frame_sampler::{DENSE_BOX_MARGIN_M, DENSE_SAMPLES_PER_RAY, DilatedGrids, FrameSampler};
pub use initial_grid::{CanonicalGrid, SURFACE_REACH_M};
pub use shells::{CapsuleShells, SubjectMargins, fit_subject_margins, grid_error};
