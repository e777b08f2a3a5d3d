//! The recipe as a run records it: `options` in every checkpoint's `state.json` and in
//! `RUN/recipe.json`. The command line's [`TrainOptions`] carry no serde of their own;
//! what runs write is declared here, field by field (serde's remote definitions of
//! [`TrainOptions`], [`Ablation`] and [`RefineOptions`]), with a version. A field of the
//! options renamed or added is then a compile error here until the record says how it is
//! written (`#[serde(rename = ...)]` keeps the name runs have on disk) and what its
//! absence means, and a run saved by an earlier build still resumes.
//!
//! Each field's default is what a run recorded before the field existed did, written
//! here rather than taken from today's defaults. A record without `version` is from
//! before versions were recorded (version 0: the same fields).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use talkin_grids::SamplerKind;
use talkin_nets::{ComputeDevice, Density};

use crate::plan::record::Plan;
use crate::preset::Preset;
use crate::recipe::{Ablation, Budget, FingerSkinning, Identities, TrainOptions};
use crate::refine::{RefineMode, RefineOptions};

/// The record's version this build writes; it reads every version up to it.
pub const RECIPE_VERSION: u32 = 1;

/// `opts` as runs record them.
pub fn to_json(opts: &TrainOptions) -> Result<Value, String> {
    serde_json::to_value(Recorded {
        version: RECIPE_VERSION,
        options: opts.clone(),
    })
    .map_err(|e| e.to_string())
}

/// The options a record holds; `Err` says which field cannot be read (a version newer
/// than this build's, a missing or mistyped field, a path in neither of
/// [`path_json`](talkin_avatar::checkpoint::path_json)'s forms).
pub fn from_json(record: Value) -> Result<TrainOptions, String> {
    let version = match record.get("version") {
        None => 0,
        Some(v) => v
            .as_u64()
            .ok_or_else(|| format!("`version`: expected a whole number, found {v}"))?,
    };
    if version > u64::from(RECIPE_VERSION) {
        return Err(format!(
            "`version` {version} is a newer build's recipe (this build reads up to \
             {RECIPE_VERSION})"
        ));
    }
    serde_json::from_value::<Recorded>(record)
        .map(|r| r.options)
        .map_err(|e| e.to_string())
}

#[derive(Serialize, Deserialize)]
struct Recorded {
    #[serde(default)]
    version: u32,
    #[serde(flatten, with = "TrainOptionsRecord")]
    options: TrainOptions,
}

/// [`TrainOptions`] as recorded.
#[derive(Serialize, Deserialize)]
#[serde(remote = "TrainOptions")]
struct TrainOptionsRecord {
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
    /// Absent: slices of 256 rows (the environment's default then).
    #[serde(default = "slices_of_256")]
    mlp_slice_rows: usize,
    /// Absent: softplus.
    #[serde(default)]
    density: Density,
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
    /// Absent: no hard-surface term.
    #[serde(default)]
    hard_surface: f32,
    #[serde(default)]
    frame_code_dim: usize,
    #[serde(default)]
    frame_code_deform: bool,
    /// Absent: every step its frame's own code.
    #[serde(default)]
    frame_code_dropout: f32,
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
    /// Absent: the preset's.
    #[serde(default)]
    hash_levels: Option<usize>,
    /// Absent: the preset's.
    #[serde(default)]
    hash_table_log2: Option<usize>,
    /// The LPIPS weights' directory (a path that is not UTF-8 round-trips).
    #[serde(default, with = "lpips_dir")]
    perceptual: Option<PathBuf>,
    /// `null`: never (JSON has no infinity; the benches' runs checkpoint only at the end).
    #[serde(with = "seconds_or_never")]
    checkpoint_every_s: f64,
    /// Absent: the full method.
    #[serde(default, with = "AblationRecord")]
    ablation: Ablation,
    /// Absent: all of the video.
    #[serde(default)]
    clip_seconds: Option<f64>,
    /// Absent: the fits trusted.
    #[serde(default = "fits_trusted", with = "RefineRecord")]
    refine: RefineOptions,
    /// Absent: no plan, the options as given.
    #[serde(default)]
    plan: Option<Plan>,
}

/// [`Ablation`] as recorded.
#[derive(Serialize, Deserialize)]
#[serde(remote = "Ablation")]
struct AblationRecord {
    use_d_hands: bool,
    /// Absent: D_nr on.
    #[serde(default = "yes")]
    non_rigid: bool,
    hand_background: bool,
    /// Absent: F_hands built.
    #[serde(default = "yes")]
    hands: bool,
    /// Absent: F_face built.
    #[serde(default = "yes")]
    face: bool,
    /// Absent: F_face reads psi.
    #[serde(default = "yes")]
    face_uses_expression: bool,
    face_uses_jaw: bool,
}

/// [`RefineOptions`] as recorded.
#[derive(Serialize, Deserialize)]
#[serde(remote = "RefineOptions")]
struct RefineRecord {
    refine_poses: RefineMode,
    pose_lr: f64,
    /// Absent: the rate of the first refining runs.
    #[serde(default = "jitter_rate_5e3")]
    pose_lr_jitter: f64,
    pose_warmup: usize,
    pose_prior: f64,
    pose_smooth: f64,
}

/// `--lpips-dir` in [`path_json`](talkin_avatar::checkpoint::path_json)'s form.
mod lpips_dir {
    use std::path::PathBuf;

    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use serde_json::Value;
    use talkin_avatar::checkpoint::path_json;

    pub fn serialize<S: Serializer>(dir: &Option<PathBuf>, s: S) -> Result<S::Ok, S::Error> {
        dir.as_deref()
            .map(path_json::to_json)
            .transpose()
            .map_err(serde::ser::Error::custom)?
            .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<PathBuf>, D::Error> {
        match Option::<Value>::deserialize(d)? {
            None | Some(Value::Null) => Ok(None),
            Some(p) => path_json::from_json(&p)
                .map(Some)
                .map_err(|e| serde::de::Error::custom(format!("`perceptual`: {e}"))),
        }
    }
}

/// A period in seconds, where an infinite one (never) is `null`.
mod seconds_or_never {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(seconds: &f64, s: S) -> Result<S::Ok, S::Error> {
        seconds.is_finite().then_some(*seconds).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
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

fn slices_of_256() -> usize {
    256
}

fn jitter_rate_5e3() -> f64 {
    5e-3
}

fn fits_trusted() -> RefineOptions {
    RefineOptions {
        refine_poses: RefineMode::Off,
        ..RefineOptions::default()
    }
}

#[cfg(test)]
mod tests;
