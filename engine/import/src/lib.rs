//! import: what human fitters write, converted into a dataset v1 directory (`talkin
//! import`), with the numpy pickle reader their layouts need ([`pickle`]).
//!
//! Must not know about training, rendering or the samplers; the dataset format it writes
//! and the arrays it reads are `talkin-data`'s, which in turn knows nothing of these
//! layouts.
//!
//! Each format module reads its tool's exact layout into a [`Source`]: the subject's rest
//! joints, and per frame an image, a mask, an OpenCV camera (pixel centres at integer
//! coordinates, optional lens distortion) and SMPL-X parameters in that camera's world.
//! [`import`] then keeps every `--every`th frame, holds out test frames, undistorts and
//! downscales the pixels, converts the camera to the dataset's conventions (pixel centres
//! at `x + 0.5`, pinhole) and writes everything into a hidden directory beside `--out`,
//! renamed into place at the end: a failure never leaves a half-written dataset.
//!
//! - [`humannerf`]: HumanNeRF's wild-video input (`metadata.json`) and its prepared layout
//!   (`cameras.pkl`, `mesh_infos.pkl`).
//! - [`smplerx`]: SMPLer-X's results (`smplx/*.npz`, `meta/*.json`), its per-crop virtual
//!   cameras replaced by one real camera.
//! - [`peoplesnapshot`]: InstantAvatar's processed PeopleSnapshot.
//!
//! The formats' conventions and their sources are in docs/bring-your-own-video.md.

mod body;
mod error;
pub mod humannerf;
pub mod peoplesnapshot;
pub mod pickle;
pub mod smplerx;
pub mod undistort;
mod write;

use std::path::{Path, PathBuf};

use glam::DVec3;

use talkin_data::dataset::Split;
use talkin_human::body::{FrameParams, N_JOINTS};

pub use body::{complete_from_body, fit_body_joints};
pub use error::ImportError;
pub use write::ImportReport;

pub use talkin_data::dataset::IMPORT_REPORT;

/// Frames per second assumed when `--fps` is not given (phone videos, and what the
/// fitters' frame extraction defaults to).
pub const DEFAULT_FPS: f64 = 30.0;
/// Frames held out as `test_same` when a format has no splits: every 5th kept frame.
pub const DEFAULT_TEST_EVERY: usize = 5;

/// The layouts `talkin import` reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    SmplerX,
    HumanNerf,
    PeopleSnapshot,
}

impl Format {
    pub const ALL: [Format; 3] = [Format::SmplerX, Format::HumanNerf, Format::PeopleSnapshot];

    pub const fn name(self) -> &'static str {
        match self {
            Format::SmplerX => "smplerx",
            Format::HumanNerf => "humannerf",
            Format::PeopleSnapshot => "peoplesnapshot",
        }
    }
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Format::ALL
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| {
                format!("unknown format {s:?}: expected smplerx, humannerf or peoplesnapshot")
            })
    }
}

/// What `talkin import` was asked to do.
#[derive(Clone, Debug)]
pub struct ImportOptions {
    pub format: Format,
    /// The tool's output folder.
    pub src: PathBuf,
    /// The dataset directory to create (absent or empty).
    pub out: PathBuf,
    /// The SMPL-X model file (`SMPLX_NEUTRAL.npz`): rest joints from betas, mean hands.
    pub body_model: Option<PathBuf>,
    /// The frames the fitter ran on (SMPLer-X: `%06d.jpg`).
    pub images: Option<PathBuf>,
    /// One 8-bit PNG mask per frame, same stem as the frame; overrides the format's.
    pub masks: Option<PathBuf>,
    /// The subject's name in the dataset (default: the source folder's name).
    pub subject: Option<String>,
    /// Frame rate of the source frames (default [`DEFAULT_FPS`]).
    pub fps: Option<f64>,
    /// Keep every `every`th frame (1 keeps all).
    pub every: usize,
    /// Hold out every `test_every`th kept frame as `test_same` (0: none). `None`: the
    /// format's own splits, or [`DEFAULT_TEST_EVERY`] where it has none.
    pub test_every: Option<usize>,
    /// Downscale so that the longer image side is at most this many pixels.
    pub max_size: Option<u32>,
    /// Focal length in pixels of the one camera replacing SMPLer-X's virtual ones.
    pub focal: Option<f64>,
    /// PeopleSnapshot: InstantAvatar's yaml of the subject
    /// (`confs/dataset/peoplesnapshot/<subject>.yaml`), whose train, val and test ranges
    /// say which frames the rows of the split files belong to.
    pub splits: Option<PathBuf>,
}

impl ImportOptions {
    /// Options with defaults for everything but the format and the folders.
    pub fn new(format: Format, src: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        ImportOptions {
            format,
            src: src.into(),
            out: out.into(),
            body_model: None,
            images: None,
            masks: None,
            subject: None,
            fps: None,
            every: 1,
            test_every: None,
            max_size: None,
            focal: None,
            splits: None,
        }
    }

    pub(crate) fn fps(&self) -> f64 {
        self.fps.unwrap_or(DEFAULT_FPS)
    }
}

/// Where a frame's mask comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum MaskFile {
    /// An 8-bit image (grey or colour; 0/1 masks are scaled to 0/255).
    Image(PathBuf),
    /// A 2-D numpy array, 0/1 or 0/255 (InstantAvatar's `mask_XXXX.npy`).
    Npy(PathBuf),
}

/// One frame as a format gives it, before resampling and writing.
#[derive(Clone, Debug)]
pub struct SourceFrame {
    /// The frame's name in the source (for messages and the report).
    pub name: String,
    /// Seconds since the first source frame.
    pub time: f64,
    /// The format's split, if it has splits.
    pub split: Option<Split>,
    pub image: PathBuf,
    pub mask: MaskFile,
    /// OpenCV intrinsics (pixel centres at integer coordinates) of the image as stored.
    pub intrinsics: [[f64; 3]; 3],
    /// World to camera (OpenCV axes).
    pub extrinsics: [[f64; 4]; 4],
    /// OpenCV distortion k1, k2, p1, p2, k3 of the stored image, if any.
    pub distortion: Option<[f64; 5]>,
    /// SMPL-X parameters in the camera's world.
    pub params: FrameParams,
}

/// A frame the importer left out, and why.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Skipped {
    pub frame: String,
    pub reason: String,
}

/// What a format module reads: one subject's frames.
#[derive(Clone, Debug)]
pub struct Source {
    pub rest_joints: [DVec3; N_JOINTS],
    /// How the rest joints were obtained (printed and recorded in import.json).
    pub body_shape: String,
    pub frames: Vec<SourceFrame>,
    pub skipped: Vec<Skipped>,
    /// Assumptions worth telling the user (printed and recorded in import.json).
    pub notes: Vec<String>,
}

/// Reads `opts.src` in `opts.format` and writes the dataset to `opts.out`.
/// `progress(done, total)` is called as frames are written.
pub fn import(
    opts: &ImportOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ImportReport, ImportError> {
    write::check_out(&opts.out)?;
    if opts.every == 0 {
        return Err(ImportError::Usage("--every must be at least 1".into()));
    }
    if let Some(f) = opts.fps
        && !(f.is_finite() && f > 0.0)
    {
        return Err(ImportError::Usage(format!(
            "--fps {f} is not a positive number"
        )));
    }
    if let Some(f) = opts.focal
        && !(f.is_finite() && f > 0.0)
    {
        return Err(ImportError::Usage(format!(
            "--focal {f} is not a positive number of pixels"
        )));
    }
    if opts.splits.is_some() && opts.format != Format::PeopleSnapshot {
        return Err(ImportError::Usage(format!(
            "--splits is for peoplesnapshot (InstantAvatar's subject yaml), not {}",
            opts.format.name()
        )));
    }
    if !opts.src.is_dir() {
        return Err(ImportError::file(&opts.src, "is not a directory"));
    }
    write::write(opts, read_source(opts)?, progress)
}

/// Reads what `opts.src` holds in `opts.format`, every frame's parameters finite and
/// within [`PARAM_LIMIT`](talkin_data::params_json::PARAM_LIMIT): a fitter's frame beyond them
/// (a diverged fit, a damaged file) is refused here, naming it, rather than written into a
/// dataset whose own loader refuses it.
pub fn read_source(opts: &ImportOptions) -> Result<Source, ImportError> {
    let source = match opts.format {
        Format::HumanNerf => humannerf::read(opts)?,
        Format::SmplerX => smplerx::read(opts)?,
        Format::PeopleSnapshot => peoplesnapshot::read(opts)?,
    };
    for f in &source.frames {
        let path = format!("{}.params", f.name);
        talkin_data::params_json::check_param_limits(&f.params, &path).map_err(|e| {
            ImportError::field(
                &opts.src,
                e.field,
                format!("expected {}, found {}", e.expected, e.found),
            )
        })?;
    }
    Ok(source)
}

/// The folder `dir` looks like the input of a format `talkin import` reads: the format and
/// what gave it away.
pub fn detect_layout(dir: &Path) -> Option<(Format, &'static str)> {
    let has = |p: &str| dir.join(p).exists();
    if has("cameras.pkl") && has("mesh_infos.pkl") {
        Some((
            Format::HumanNerf,
            "cameras.pkl and mesh_infos.pkl (HumanNeRF's prepared layout)",
        ))
    } else if has("metadata.json") && has("images") {
        Some((
            Format::HumanNerf,
            "metadata.json (HumanNeRF's wild-video input)",
        ))
    } else if has("smplx") && has("meta") {
        Some((Format::SmplerX, "smplx/ and meta/ (SMPLer-X's results)"))
    } else if has("cameras.npz") && has("poses") {
        Some((
            Format::PeopleSnapshot,
            "cameras.npz and poses/ (InstantAvatar's PeopleSnapshot)",
        ))
    } else {
        None
    }
}

/// SMPL's 72 pose numbers (24 joints) as SMPL-X parameters: joints 0..21 are shared in
/// the same order; SMPL's two hand joints (22, 23) have no SMPL-X counterpart and are
/// dropped; jaw, eyes, fingers and expression stay zero.
pub fn params_from_smpl(poses: &[f64], transl: DVec3) -> FrameParams {
    let v = |j: usize| DVec3::new(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2]);
    let mut p = FrameParams {
        global_orient: v(0),
        transl,
        ..FrameParams::default()
    };
    for j in 1..22 {
        p.body_pose[j - 1] = v(j);
    }
    p
}

/// Reads an SMPL-X model file if one was given.
pub(crate) fn load_model(
    opts: &ImportOptions,
) -> Result<Option<talkin_data::smplx_model::SmplxModel>, ImportError> {
    opts.body_model
        .as_ref()
        .map(talkin_data::smplx_model::SmplxModel::load)
        .transpose()
        .map_err(ImportError::from)
}

/// Row-major 3x3 from 9 numbers.
pub(crate) fn mat3(v: &[f64]) -> [[f64; 3]; 3] {
    [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]]
}

/// Row-major 4x4 from 16 numbers.
pub(crate) fn mat4(v: &[f64]) -> [[f64; 4]; 4] {
    std::array::from_fn(|r| std::array::from_fn(|c| v[4 * r + c]))
}

/// The subject name: `--subject`, or the source folder's name.
pub(crate) fn subject_name(opts: &ImportOptions) -> String {
    opts.subject.clone().unwrap_or_else(|| {
        opts.src
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| "subject".into())
    })
}

/// Image files (`.png`, `.jpg`, `.jpeg`) in `dir` by stem.
pub(crate) fn images_by_stem(
    dir: &Path,
) -> Result<std::collections::BTreeMap<String, PathBuf>, ImportError> {
    let mut out = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(dir).map_err(ImportError::io(dir))? {
        let path = entry.map_err(ImportError::io(dir))?.path();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg"))
            && let Some(stem) = path.file_stem()
        {
            out.insert(stem.to_string_lossy().into_owned(), path);
        }
    }
    Ok(out)
}

/// The mask of frame `stem`: from `--masks` if given (which must have it), else `default`.
pub(crate) fn mask_for(
    opts: &ImportOptions,
    stem: &str,
    default: Option<MaskFile>,
) -> Result<MaskFile, ImportError> {
    match &opts.masks {
        Some(dir) => {
            let path = dir.join(format!("{stem}.png"));
            if path.is_file() {
                Ok(MaskFile::Image(path))
            } else {
                Err(ImportError::file(
                    &path,
                    format!("missing: frame {stem} has no mask in --masks (one PNG per frame, same stem)"),
                ))
            }
        }
        None => default.ok_or_else(|| {
            ImportError::Usage(format!(
                "frame {stem} has no mask: masks are required; give --masks DIR (one 8-bit PNG per frame from a matting tool)"
            ))
        }),
    }
}
