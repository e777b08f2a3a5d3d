//! Wiring the grids crate to the human: per-frame capsules and rays, the margins the
//! training masks decide, the canonical occupancy grid and the posed-to-canonical map
//! that culls samples, and the sampling benchmark.

mod bench;
mod canonical;
mod frame;
mod margins;

pub use bench::{PartCoverage, SamplingReport, bench_sampling, format_report};
pub use canonical::{CanonicalGrid, PosedToCanonical};
pub use frame::{FrameScene, foreground_rays, shell_capsules};
pub use margins::{CapsuleShells, SubjectMargins, fit_subject_margins};
