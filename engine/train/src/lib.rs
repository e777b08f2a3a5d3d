//! train: one training step and the run around it. The modules read in the order a step
//! runs: a frame's [`rays`] (its scene, conditions and samplers come from `talkin-avatar`),
//! the [`loss`] (whose chunks' gradients nets' fused `grad_sum` adds), Adam (nets'
//! fused kernel), the [`grid_update`]; the [`trainer`]'s step strings them together and
//! it runs steps until the budget is spent, writing the [`step_log`] (through its
//! `journal`: on a GPU a few steps' losses at a time, read in one transfer by `pending`)
//! and the avatar's checkpoints. A run is told its [`recipe`] (on a camera capture, the
//! capture recipe wherever the command line named nothing; runs record it as
//! [`recipe::record`] declares, versioned, in `recipe.json`; the [`plan`], decided from the
//! census of the training frames, sets which networks, inputs, finger bones and grid
//! levels it builds), whose [`preset`] names the architecture and optimiser settings; with
//! [`refine`] it also learns per-frame corrections of the training fits.
//!
//! Must not know about rendering whole frames, evaluation, the server or the
//! experiments: they read what it writes (checkpoints, through `talkin-avatar`) or drive
//! a [`Trainer`].

pub mod error;
pub mod grid_update;
pub mod loss;
pub mod peers;
pub mod plan;
pub mod preset;
pub mod rays;
pub mod recipe;
pub mod refine;
pub mod run_lock;
pub mod schedule;
pub mod setup;
pub mod step_log;
pub mod trainer;

pub use error::TrainError;
pub use preset::Preset;
pub use recipe::RECIPE_FILE;
pub use recipe::{
    Ablation, Budget, DEFAULT_LPIPS_DIR, DEVICE_ARG, FingerSkinning, Identities, TrainOptions,
};
pub use run_lock::{LOCK_FILE, RunLock, RunLockError};
pub use setup::existing_run;
pub use step_log::{LOG_FILE, StepLog};
pub use talkin_grids::SamplerKind;
pub use trainer::{
    FitPosesOptions, FittedPoses, RunWriter, ScheduleAnchor, TrainReport, Trainer,
    fit_held_out_poses, train,
};
