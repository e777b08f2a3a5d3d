//! The command line's pose-refinement options (flattened into [`crate::TrainOptions`]).

use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};

/// Whether a run refines its training fits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum RefineMode {
    /// On for imported datasets (an `import.json` beside `dataset.json`), off for the
    /// built-in synthetic scene, whose fits are exact.
    #[default]
    Auto,
    On,
    Off,
}

/// How a run refines its training fits.
#[derive(Clone, Debug, PartialEq, Args)]
pub struct RefineOptions {
    /// Learn per-frame corrections of the training fits (pose, hands, jaw, expression,
    /// translation): `on`, `off` or `auto` (on for imported datasets); the bare flag
    /// means `on`.
    #[arg(
        long = "refine-poses",
        value_enum,
        num_args = 0..=1,
        default_value_t = RefineMode::Auto,
        default_missing_value = "on",
        value_name = "on|off|auto"
    )]
    pub refine_poses: RefineMode,
    /// Learning rate of the corrections of fits that move at least as smoothly as a
    /// random walk (radians per step; translation at 0.2x, metres).
    #[arg(long = "pose-lr", default_value_t = RefineOptions::default().pose_lr)]
    pub pose_lr: f64,
    /// Learning rate of the corrections of fits that jitter like white noise (fits in
    /// between get a rate in between, by the same measure of jitter as `--pose-smooth`).
    #[arg(long = "pose-lr-jitter", default_value_t = RefineOptions::default().pose_lr_jitter)]
    pub pose_lr_jitter: f64,
    /// Steps before the corrections start learning from the images (the prior and the
    /// smoothness act from the first step).
    #[arg(long = "pose-warmup", value_name = "STEPS", default_value_t = RefineOptions::default().pose_warmup)]
    pub pose_warmup: usize,
    /// Pull of a correction toward zero: the fraction of it removed at each visit.
    #[arg(long = "pose-prior", default_value_t = RefineOptions::default().pose_prior)]
    pub pose_prior: f64,
    /// Pull of a frame's corrected pose toward its neighbours' in time: the fraction of
    /// the way to their mean at each visit, for fits that jitter like white noise (less
    /// for smoother fits, none for fits as smooth as a random walk).
    #[arg(long = "pose-smooth", default_value_t = RefineOptions::default().pose_smooth)]
    pub pose_smooth: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            refine_poses: RefineMode::Auto,
            pose_lr: 1e-3,
            pose_lr_jitter: 5e-3,
            pose_warmup: 500,
            pose_prior: 0.01,
            pose_smooth: 0.5,
        }
    }
}

impl RefineOptions {
    /// Whether the options turn refinement on for a dataset that is (or is not)
    /// imported.
    pub fn is_on(&self, imported: bool) -> bool {
        match self.refine_poses {
            RefineMode::On => true,
            RefineMode::Off => false,
            RefineMode::Auto => imported,
        }
    }

    /// Checks every option; `Err((flag, problem))`.
    pub fn check(&self) -> Result<(), (&'static str, &'static str)> {
        if !(self.pose_lr.is_finite() && self.pose_lr > 0.0) {
            return Err(("--pose-lr", "must be a positive number"));
        }
        if !(self.pose_lr_jitter.is_finite() && self.pose_lr_jitter > 0.0) {
            return Err(("--pose-lr-jitter", "must be a positive number"));
        }
        if !(0.0..1.0).contains(&self.pose_prior) {
            return Err(("--pose-prior", "must lie in [0, 1)"));
        }
        if !(0.0..=1.0).contains(&self.pose_smooth) {
            return Err(("--pose-smooth", "must lie in [0, 1]"));
        }
        Ok(())
    }
}
