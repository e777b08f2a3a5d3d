//! What a run is told, recorded in every checkpoint's `state.json` and in `RUN/recipe.json`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use talkin_grids::SamplerKind;

use crate::trainer::TrainError;

/// How long to train.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Budget {
    /// Optimizer steps (reproducible to the bit).
    Steps(usize),
    /// Wall-clock seconds of training (the schedule follows elapsed time; evaluation
    /// pauses in the benchmark do not count).
    Seconds(f64),
}

/// Everything a run is told.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainOptions {
    /// `fast` or `paper`.
    pub preset: String,
    pub sampler: SamplerKind,
    pub budget: Budget,
    /// Seed of the initialisation, frame and ray choice and sample jitter.
    pub seed: u64,
    /// Names of the subjects to train on; `None`: all with training frames.
    pub identities: Option<Vec<String>>,
    /// Random pixel rays per step (besides the LPIPS patches).
    pub batch_rays: usize,
    /// 32x32 LPIPS patches per step (the paper: 6).
    pub patches: usize,
    /// Initial Adam learning rate (decays x0.1 per 500k virtual steps); `None`: the
    /// preset's (`paper` 5e-4 as the paper, `fast` 1e-2: its hash grid and small MLPs take
    /// a larger rate; 1e-2 beat 5e-3 on every metric of the demo, see the README).
    pub lr: Option<f64>,
    /// Fraction of random rays drawn inside the person's bounding box (the paper: 80%).
    pub bbox_fraction: f32,
    /// Weight of the silhouette term: the mean squared error between each ray's rendered
    /// opacity and its pixel's mask (0: off, the paper's loss). Runs written before the
    /// term existed read as 0.
    #[serde(default)]
    pub mask_weight: f32,
    /// Update the occupancy grids every this many steps (0: never). Accelerated only.
    pub occ_every: u32,
    /// Occupancy-grid cells along the longest axis.
    pub grid_resolution: u32,
    /// Directory of the LPIPS weights (`alex.safetensors`); without them the perceptual
    /// term is 1 - SSIM, and the run says so.
    pub perceptual: Option<PathBuf>,
    /// Write a checkpoint every this many seconds of training (and always at the end).
    pub checkpoint_every_s: f64,
    /// The paper's ablation switches (all on: the full method).
    #[serde(default)]
    pub ablation: Ablation,
    /// Train on each subject's first this many seconds of training video only (a short
    /// clip, as the novel-identity experiment's from-scratch baseline); `None`: all of it.
    /// Runs written before the option existed read as `None`.
    #[serde(default)]
    pub clip_seconds: Option<f64>,
}

/// The paper's ablations (Tables 1 and 3), as switches on the field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ablation {
    /// D_hands deforms hand samples (off: "w/o D_hands").
    pub use_d_hands: bool,
    /// The body's rendered colour is the hands' background (off: "w/o background").
    pub hand_background: bool,
    /// F_face is conditioned on [psi; jaw] (off: psi only).
    pub face_uses_jaw: bool,
}

impl Default for Ablation {
    fn default() -> Self {
        Ablation {
            use_d_hands: true,
            hand_background: true,
            face_uses_jaw: true,
        }
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            preset: "fast".into(),
            sampler: SamplerKind::Accelerated,
            budget: Budget::Steps(1000),
            seed: 0,
            identities: None,
            batch_rays: 1024,
            patches: 1,
            lr: None,
            bbox_fraction: 0.8,
            mask_weight: 0.0,
            occ_every: 64,
            grid_resolution: 128,
            perceptual: None,
            checkpoint_every_s: 120.0,
            ablation: Ablation::default(),
            clip_seconds: None,
        }
    }
}

impl TrainOptions {
    /// The initial learning rate: the option, else the preset's.
    pub fn initial_lr(&self) -> f64 {
        self.lr
            .unwrap_or(if self.preset == "paper" { 5e-4 } else { 1e-2 })
    }

    pub(crate) fn check(&self) -> Result<(), TrainError> {
        let bad = |field, problem: &str| {
            Err(TrainError::BadOption {
                field,
                problem: problem.to_string(),
            })
        };
        match self.budget {
            Budget::Steps(0) => return bad("steps", "must be at least 1"),
            Budget::Seconds(s) if !(s.is_finite() && s > 0.0) => {
                return bad("minutes", "must be a positive number");
            }
            _ => {}
        }
        if self.batch_rays == 0 && self.patches == 0 {
            return bad(
                "batch_rays",
                "a step needs rays: batch_rays or patches must be > 0",
            );
        }
        if !(self.initial_lr().is_finite() && self.initial_lr() > 0.0) {
            return bad("lr", "must be a positive number");
        }
        if !(self.mask_weight.is_finite() && self.mask_weight >= 0.0) {
            return bad("mask_weight", "must be a finite number >= 0");
        }
        if !(0.0..=1.0).contains(&self.bbox_fraction) {
            return bad("bbox_fraction", "must lie in [0, 1]");
        }
        if self.grid_resolution < 8 || self.grid_resolution > 512 {
            return bad("grid_resolution", "must be in 8..=512");
        }
        if self.checkpoint_every_s.is_nan() || self.checkpoint_every_s <= 0.0 {
            return bad("checkpoint_every_s", "must be positive");
        }
        if let Some(c) = self.clip_seconds
            && !(c.is_finite() && c > 0.0)
        {
            return bad("clip_seconds", "must be a positive number of seconds");
        }
        if self.preset != "fast" && self.preset != "paper" {
            return bad("preset", "expected `fast` or `paper`");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_name_their_field() {
        let field_of = |opts: TrainOptions| match opts.check() {
            Err(TrainError::BadOption { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        for w in [-0.1, f32::NAN, f32::INFINITY] {
            let opts = TrainOptions {
                mask_weight: w,
                ..TrainOptions::default()
            };
            assert_eq!(field_of(opts), "mask_weight");
        }
        let opts = TrainOptions {
            lr: Some(0.0),
            ..TrainOptions::default()
        };
        assert_eq!(field_of(opts), "lr");
        for c in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let opts = TrainOptions {
                clip_seconds: Some(c),
                ..TrainOptions::default()
            };
            assert_eq!(field_of(opts), "clip_seconds");
        }
        assert!(TrainOptions::default().check().is_ok());
    }

    /// `state.json` of a run from before the silhouette term resumes with it off.
    #[test]
    fn options_without_mask_weight_read_as_off() {
        let mut json = serde_json::to_value(TrainOptions::default()).unwrap();
        json.as_object_mut().unwrap().remove("mask_weight");
        let opts: TrainOptions = serde_json::from_value(json).unwrap();
        assert_eq!(opts.mask_weight, 0.0);
    }
}
