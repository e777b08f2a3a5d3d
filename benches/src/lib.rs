//! benches: the experiments behind the numbers in `docs/results.md`, called by the CLI's
//! `talkin bench` commands: speed against error (accelerated against dense), the paper's
//! ablations, novel-identity adaptation, quality against budget (convergence), the
//! sampling report, the device report and the step's roofline. The
//! micro-benchmarks (`cargo bench`) sit beside them in `micro/`.
//!
//! Must not know about the server (its load bench lives with it) or the CLI.

pub mod ablations;
pub mod convergence;
pub mod device;
pub mod error;
pub mod noisy_fits;
pub mod novel_identity;
mod plot_style;
pub mod sampling;
pub mod shared;
pub mod speed_vs_error;
pub mod step;
