//! Motion files: pose sequences that drive a subject (`talkin synth --motion`,
//! `talkin render --motion`/`--poses`). One reader, [`read_motion`], for:
//!
//! - `.json`: a list of `params` objects as in dataset.json (or of objects carrying one
//!   under `"params"`), parsed by [`FrameParams::from_json`]; errors name `[i].field`.
//!   Our conventions: y up, absolute hand poses, no frame rate.
//! - `.npz` in the **BEAT2** layout (BEAT2, EMAGE, SynTalker): `poses` (N, 165),
//!   `expressions` (N, >= 10; the first 10 are used), `trans` (N, 3), `betas` (any
//!   length), `mocap_frame_rate` (0-d int or float), `model`, `gender`. y up; hand poses
//!   relative to the model's mean hand (`flat_hand_mean=False`).
//! - `.npz` in the **AMASS** layout (MoSh++ SMPL-X `*_stageii.npz`, or legacy SMPL+H):
//!   `poses` (N, 165), or (N, 156) for SMPL+H (22 body joints and two hands, no jaw or
//!   eyes), `trans`, `betas`, `mocap_frame_rate` or `mocap_framerate`, `gender`,
//!   optionally `expression`. z up; absolute hand poses.
//!
//! The layout is told from the keys (AMASS-only keys such as `mocap_framerate`,
//! `surface_model_type`, `mocap_time_length`, `dmpls` or 156 pose columns mean AMASS;
//! otherwise BEAT2), or forced with [`MotionLayout`]. `poses` is required; `trans`,
//! expressions and `betas` default to zeros. Any numeric dtype is read; NaN and infinities
//! are rejected, naming the file, the array and where.
//!
//! [`read_motion`] returns the frames as the file stores them, with what is needed to
//! bring them into our conventions for a given subject: [`Motion::prepare`] (mean hands
//! added with a model file, z-up turned y-up about the subject's rest pelvis, translation
//! anchored at the subject's rest position, resampled to a frame rate; see
//! [`convert`]).

pub mod convert;
mod npz;

use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::json_shape::ShapeError;
use crate::npz::NpzError;
use crate::params_json::ParamsJson;
use crate::smplx_model::ModelError;
use talkin_human::body::{FrameParams, N_BODY_JOINTS, N_HAND_JOINTS};

pub use convert::{Prepare, Prepared, Z_UP_TO_Y_UP, change_frame, resample, z_up_to_y_up};

/// Columns of the SMPL-X `poses` array (55 joints).
pub const POSE_COLUMNS: usize = 3 * (1 + (N_BODY_JOINTS - 1) + 3 + 2 * N_HAND_JOINTS);
/// Columns of an SMPL+H `poses` array (52 joints: no jaw, no eyes).
pub const SMPLH_POSE_COLUMNS: usize = 3 * (N_BODY_JOINTS + 2 * N_HAND_JOINTS);

/// How a motion file lays out its data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionLayout {
    /// BEAT2 / EMAGE / SynTalker `.npz`: y up, hands relative to the mean hand.
    Beat2,
    /// AMASS `.npz` (SMPL-X or SMPL+H): z up, absolute hands.
    Amass,
    /// A JSON list of `params` objects: our conventions.
    Params,
}

impl std::str::FromStr for MotionLayout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "beat2" | "emage" => Ok(MotionLayout::Beat2),
            "amass" => Ok(MotionLayout::Amass),
            _ => Err(format!("unknown motion layout {s:?} (beat2 or amass)")),
        }
    }
}

impl std::fmt::Display for MotionLayout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MotionLayout::Beat2 => "BEAT2",
            MotionLayout::Amass => "AMASS",
            MotionLayout::Params => "params JSON",
        })
    }
}

/// Which way is up in a motion's world.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    Y,
    Z,
}

/// How a motion stores hand poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Hands {
    /// Absolute local rotations (our convention; AMASS).
    Absolute,
    /// Offsets from the SMPL-X model's mean hand (`flat_hand_mean=False`; BEAT2, SMPLer-X).
    RelativeToMean,
}

/// A motion as its file stores it.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    pub file: PathBuf,
    pub layout: MotionLayout,
    /// One per frame, as stored: hands as `hands` says, translation in the file's world.
    pub frames: Vec<FrameParams>,
    /// Frames per second, if the file says.
    pub fps: Option<f64>,
    /// The body shape the motion was captured with (SMPL-X betas; empty if none).
    pub betas: Vec<f64>,
    pub gender: Option<String>,
    pub up: UpAxis,
    pub hands: Hands,
}

/// Why a motion file was rejected. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: malformed JSON: {message}", file.display())]
    Json { file: PathBuf, message: String },
    #[error("{}: {source}", file.display())]
    Shape {
        file: PathBuf,
        #[source]
        source: ShapeError,
    },
    #[error(transparent)]
    Npz(#[from] NpzError),
    #[error("{}: array `{array}`: {problem}", file.display())]
    Array {
        file: PathBuf,
        array: String,
        problem: String,
    },
    #[error("{}: {problem}", file.display())]
    Format { file: PathBuf, problem: String },
    #[error("body model: {0}")]
    Model(#[from] ModelError),
}

/// Reads a motion file (`.json` or `.npz`); `layout` forces the `.npz` layout instead of
/// telling it from the keys.
pub fn read_motion(
    path: impl AsRef<Path>,
    layout: Option<MotionLayout>,
) -> Result<Motion, MotionError> {
    let file = path.as_ref().to_path_buf();
    let ext = file
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("json") => {
            let frames = load_json(&file)?;
            Ok(Motion {
                file,
                layout: MotionLayout::Params,
                frames,
                fps: None,
                betas: Vec::new(),
                gender: None,
                up: UpAxis::Y,
                hands: Hands::Absolute,
            })
        }
        Some("npz") => npz::read(&file, layout),
        _ => Err(MotionError::Format {
            file,
            problem: "expected a .json or .npz motion file".into(),
        }),
    }
}

/// The frames of a motion file exactly as stored (no conversion), for `talkin synth
/// --motion`, which renders them in the file's own world.
pub fn load_motion(path: impl AsRef<Path>) -> Result<Vec<FrameParams>, MotionError> {
    Ok(read_motion(path, None)?.frames)
}

fn load_json(file: &Path) -> Result<Vec<FrameParams>, MotionError> {
    let text = std::fs::read_to_string(file).map_err(|source| MotionError::Io {
        file: file.into(),
        source,
    })?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| MotionError::Json {
        file: file.into(),
        message: e.to_string(),
    })?;
    parse_json(&doc, file)
}

/// A motion from a parsed JSON document: a non-empty list of params objects.
pub fn parse_json(doc: &Value, file: &Path) -> Result<Vec<FrameParams>, MotionError> {
    let Some(list) = doc.as_array().filter(|a| !a.is_empty()) else {
        return Err(MotionError::Format {
            file: file.into(),
            problem: "expected a non-empty JSON list of params objects".into(),
        });
    };
    list.iter()
        .enumerate()
        .map(|(i, v)| {
            let (v, path) = match v.get("params") {
                Some(p) => (p, format!("[{i}].params")),
                None => (v, format!("[{i}]")),
            };
            FrameParams::from_json(v, &path).map_err(|source| MotionError::Shape {
                file: file.into(),
                source,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests;
