//! The recipe as a run records it: `options` in every checkpoint's `state.json` and in
//! `RUN/recipe.json`. It is its own serde type, versioned, built from the command line's
//! [`TrainOptions`] and back, so a flag or a field of the options can be renamed without
//! changing what runs on disk say, and a run saved by an earlier build still resumes.
//!
//! Each field's default is what a run recorded before the field existed did; a record
//! without `version` is from before versions were recorded (version 0, the same fields).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use talkin_avatar::checkpoint::path_json;
use talkin_grids::SamplerKind;
use talkin_nets::ComputeDevice;

use crate::preset::Preset;
use crate::recipe::{Ablation, Budget, FingerSkinning, Identities, TrainOptions};
use crate::refine::{RefineMode, RefineOptions};

/// The record's version this build writes; it reads every version up to it.
pub const RECIPE_VERSION: u32 = 1;

/// A run's options as recorded (see the module's doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecordedOptions {
    /// Absent: recorded before versions were (0).
    #[serde(default)]
    version: u32,
    preset: Preset,
    /// Where the run trained (informative: a run resumes on any device).
    #[serde(default)]
    device: ComputeDevice,
    sampler: SamplerKind,
    /// Absent: the fingers moved with their wrist.
    #[serde(default = "fingers_with_wrist")]
    skin_fingers: FingerSkinning,
    /// Absent: the fused op.
    #[serde(default = "yes")]
    mlp_fused: bool,
    #[serde(default = "default_slice_rows")]
    mlp_slice_rows: usize,
    budget: Budget,
    seed: u64,
    identities: Identities,
    batch_rays: usize,
    patches: usize,
    #[serde(default)]
    lr: Option<f64>,
    bbox_fraction: f32,
    /// Absent: no silhouette term.
    #[serde(default)]
    mask_weight: f32,
    #[serde(default)]
    distortion: f32,
    #[serde(default)]
    frame_code_dim: usize,
    #[serde(default)]
    frame_code_deform: bool,
    /// Absent: over the dataset's background.
    #[serde(default)]
    random_background: bool,
    /// Absent: every pixel trained.
    #[serde(default = "every_pixel")]
    mask_edge_px: Option<u32>,
    /// Absent: D_nr at the field's rate.
    #[serde(default = "one")]
    non_rigid_lr_scale: f64,
    occ_every: u32,
    grid_resolution: u32,
    /// The LPIPS weights' directory in [`path_json`]'s form (a path that is not UTF-8
    /// round-trips).
    #[serde(default)]
    perceptual: Option<Value>,
    checkpoint_every_s: f64,
    /// Absent: the full method.
    #[serde(default)]
    ablation: RecordedAblation,
    /// Absent: all of the video.
    #[serde(default)]
    clip_seconds: Option<f64>,
    /// Absent: the fits trusted.
    #[serde(default = "RecordedRefine::recorded_before")]
    refine: RecordedRefine,
}

/// [`Ablation`] as recorded.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct RecordedAblation {
    use_d_hands: bool,
    /// Absent: D_nr on.
    #[serde(default = "yes")]
    non_rigid: bool,
    hand_background: bool,
    face_uses_jaw: bool,
}

impl Default for RecordedAblation {
    fn default() -> Self {
        RecordedAblation::from(Ablation::default())
    }
}

/// [`RefineOptions`] as recorded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct RecordedRefine {
    refine_poses: RefineMode,
    pose_lr: f64,
    /// Absent: the rate of the first refining runs.
    #[serde(default = "default_pose_lr_jitter")]
    pose_lr_jitter: f64,
    pose_warmup: usize,
    pose_prior: f64,
    pose_smooth: f64,
}

impl RecordedRefine {
    /// What a run recorded before refinement existed did: trust its fits.
    fn recorded_before() -> Self {
        RecordedRefine::from(&RefineOptions {
            refine_poses: RefineMode::Off,
            ..RefineOptions::default()
        })
    }
}

impl RecordedOptions {
    /// The record of `opts`.
    pub fn of(opts: &TrainOptions) -> Result<Self, String> {
        let o = opts.clone();
        Ok(RecordedOptions {
            version: RECIPE_VERSION,
            preset: o.preset,
            device: o.device,
            sampler: o.sampler,
            skin_fingers: o.skin_fingers,
            mlp_fused: o.mlp_fused,
            mlp_slice_rows: o.mlp_slice_rows,
            budget: o.budget,
            seed: o.seed,
            identities: o.identities,
            batch_rays: o.batch_rays,
            patches: o.patches,
            lr: o.lr,
            bbox_fraction: o.bbox_fraction,
            mask_weight: o.mask_weight,
            distortion: o.distortion,
            frame_code_dim: o.frame_code_dim,
            frame_code_deform: o.frame_code_deform,
            random_background: o.random_background,
            mask_edge_px: o.mask_edge_px,
            non_rigid_lr_scale: o.non_rigid_lr_scale,
            occ_every: o.occ_every,
            grid_resolution: o.grid_resolution,
            perceptual: o
                .perceptual
                .as_deref()
                .map(path_json::to_json)
                .transpose()?,
            checkpoint_every_s: o.checkpoint_every_s,
            ablation: o.ablation.into(),
            clip_seconds: o.clip_seconds,
            refine: RecordedRefine::from(&o.refine),
        })
    }

    /// The options recorded; `Err` names the field that cannot be read (a version newer
    /// than this build's, a path in neither of [`path_json`]'s forms).
    pub fn into_options(self) -> Result<TrainOptions, String> {
        if self.version > RECIPE_VERSION {
            return Err(format!(
                "`version` {} is a newer build's recipe (this build reads up to {RECIPE_VERSION})",
                self.version
            ));
        }
        let perceptual: Option<PathBuf> = match &self.perceptual {
            None | Some(Value::Null) => None,
            Some(p) => Some(path_json::from_json(p).map_err(|e| format!("`perceptual`: {e}"))?),
        };
        let (a, r) = (self.ablation, self.refine);
        Ok(TrainOptions {
            preset: self.preset,
            device: self.device,
            sampler: self.sampler,
            skin_fingers: self.skin_fingers,
            mlp_fused: self.mlp_fused,
            mlp_slice_rows: self.mlp_slice_rows,
            budget: self.budget,
            seed: self.seed,
            identities: self.identities,
            batch_rays: self.batch_rays,
            patches: self.patches,
            lr: self.lr,
            bbox_fraction: self.bbox_fraction,
            mask_weight: self.mask_weight,
            distortion: self.distortion,
            frame_code_dim: self.frame_code_dim,
            frame_code_deform: self.frame_code_deform,
            random_background: self.random_background,
            mask_edge_px: self.mask_edge_px,
            non_rigid_lr_scale: self.non_rigid_lr_scale,
            occ_every: self.occ_every,
            grid_resolution: self.grid_resolution,
            perceptual,
            checkpoint_every_s: self.checkpoint_every_s,
            ablation: Ablation {
                use_d_hands: a.use_d_hands,
                non_rigid: a.non_rigid,
                hand_background: a.hand_background,
                face_uses_jaw: a.face_uses_jaw,
            },
            clip_seconds: self.clip_seconds,
            refine: RefineOptions {
                refine_poses: r.refine_poses,
                pose_lr: r.pose_lr,
                pose_lr_jitter: r.pose_lr_jitter,
                pose_warmup: r.pose_warmup,
                pose_prior: r.pose_prior,
                pose_smooth: r.pose_smooth,
            },
        })
    }

    /// The record as JSON.
    pub fn to_json(&self) -> Result<Value, String> {
        serde_json::to_value(self).map_err(|e| e.to_string())
    }
}

impl From<Ablation> for RecordedAblation {
    fn from(a: Ablation) -> Self {
        RecordedAblation {
            use_d_hands: a.use_d_hands,
            non_rigid: a.non_rigid,
            hand_background: a.hand_background,
            face_uses_jaw: a.face_uses_jaw,
        }
    }
}

impl From<&RefineOptions> for RecordedRefine {
    fn from(r: &RefineOptions) -> Self {
        RecordedRefine {
            refine_poses: r.refine_poses,
            pose_lr: r.pose_lr,
            pose_lr_jitter: r.pose_lr_jitter,
            pose_warmup: r.pose_warmup,
            pose_prior: r.pose_prior,
            pose_smooth: r.pose_smooth,
        }
    }
}

fn fingers_with_wrist() -> FingerSkinning {
    FingerSkinning::Wrist
}

fn yes() -> bool {
    true
}

fn one() -> f64 {
    1.0
}

fn every_pixel() -> Option<u32> {
    Some(0)
}

/// The slice runs took before the option existed (the environment's default then).
fn default_slice_rows() -> usize {
    256
}

/// The jitter rate runs refined at before the option existed.
fn default_pose_lr_jitter() -> f64 {
    5e-3
}

#[cfg(test)]
mod tests;
