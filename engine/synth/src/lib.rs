//! Synthetic talking humans: the embedded default dataset. A capsule/SDF mannequin on the
//! SMPL-X skeleton (fingers, a palm, a face whose mouth opens with the jaw and whose brows,
//! eyes and mouth corners follow the expression coefficients, hair with a bun or a
//! ponytail, loose clothing with procedural patterns glued to the limbs), driven by a
//! talking motion, rendered by its own sphere tracer (independent of the engine's
//! samplers) and written in dataset format v1.
//!
//! Must not know about training, rendering or the samplers (of `talkin-grids` it takes
//! only the workspace's generator, `SplitMix64`): it writes what a user's
//! importer would, through `talkin-data`, and its ground truth never comes from the
//! engine's own code paths.
//!
//! # Expression coefficients
//! The generator (and any motion file rendered by it) reads the 10 coefficients as:
//! `0` smile (mouth corners up, cheeks up), `1` brow raise, `2` brow furrow (inner ends
//! down and in), `3` eye blink/squint (1 = half closed, >= 2.2 closed; negative widens),
//! `4` mouth width, `5` lip pucker (narrower, forward), `6` cheek puff, `7` smirk (left
//! corner up, right down), `8` upper-lip raise, `9` brow asymmetry (left up, right down).
//! Values are clamped to [-3, 3]. The jaw opens the mouth with `jaw_pose.x > 0`.
//!
//! # Splits (built-in motion)
//! Per identity a clip of about `frames * 5 / 4` steps at 25 fps: every 5th step (index 4, 9,
//! ...) is `test_same`, the others `train`. `test_cross`: the identity's body driven by the
//! next identity's clip (a few frames). `test_ood`: a separate clip with arms raised forward
//! and up, wider head turns, 2.4x stronger expressions and a wider jaw. The camera is
//! frontal and fixed per identity, framed from mid-thigh up and widened (smaller focal) if
//! needed so the whole head and both hands stay in every frame of that identity.
//!
//! With `motion: Some(..)` every identity performs that motion, every frame `train`,
//! `time = index / 25`, the camera aimed at the clip's mean translation.

pub mod body;
pub mod capture;
mod framing;
mod plan;
pub mod sdf;
pub mod talk;
pub mod tracer;
mod write;

use std::path::{Path, PathBuf};

use glam::Vec3;

use talkin_data::dataset::{Dataset, DatasetError, Frame};
use talkin_human::body::FrameParams;
use talkin_human::camera::CameraError;

pub use body::{default_rest_joints, look, proportions};
pub use capture::{CAPTURE_FPS, CaptureConfig, TRUE_FITS_FILE, biased_fits, capture_clip};
pub use framing::Framing;
pub use talk::{FPS, Style, talking_clip};

/// Background colour of every synthetic image (white), also the dataset's `background`.
pub const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];

/// What to generate.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// Number of identities (at least 1). 0..3 are authored, later ones are variations.
    pub identities: usize,
    /// Training frames per identity (built-in motion).
    pub frames: usize,
    /// Image height in pixels; the width is 3/4 of it rounded to a multiple of 8.
    pub size: u32,
    /// Seed of the motion.
    pub seed: u64,
    /// Render this motion instead of the built-in one (all frames `train`).
    pub motion: Option<Vec<FrameParams>>,
    /// The capture-like scene ([`capture`]): its performance (unless `motion` is given),
    /// the whole body in frame, and its flaws; `None`: the clean talking scene.
    pub capture: Option<CaptureConfig>,
    /// What the camera frames; `None`: the scene's own (the talking scene from mid-thigh
    /// up, the capture-like scene whole).
    pub framing: Option<Framing>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            identities: 3,
            frames: 48,
            size: 192,
            seed: 0,
            motion: None,
            capture: None,
            framing: None,
        }
    }
}

impl SynthConfig {
    /// What the camera frames.
    pub fn framing(&self) -> Framing {
        self.framing.unwrap_or(if self.capture.is_some() {
            Framing::FullBody
        } else {
            Framing::Waist
        })
    }

    /// The authored person (proportions and look) identity `i` is: itself, and in the
    /// capture-like scene the next one, so that its first identity wears a jacket and
    /// trousers as people in captures mostly do (the first talking identity wears a skirt).
    pub fn appearance(&self, i: usize) -> usize {
        i + usize::from(self.capture.is_some())
    }

    /// Image (width, height).
    pub fn image_size(&self) -> (u32, u32) {
        let w = ((self.size as f64 * 0.75 / 8.0).round() as u32 * 8).max(8);
        (w, self.size)
    }
}

/// Why generation failed.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("synth config: {0}")]
    Config(String),
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot write PNG: {message}", file.display())]
    Png { file: PathBuf, message: String },
    #[error("camera of identity {identity}: {source}")]
    Camera {
        identity: usize,
        #[source]
        source: CameraError,
    },
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

/// Why `cfg` cannot be generated, before anything is written.
fn check(cfg: &SynthConfig) -> Result<(), SynthError> {
    if cfg.identities == 0 {
        return Err(SynthError::Config("identities must be at least 1".into()));
    }
    if !(16..=4096).contains(&cfg.size) {
        return Err(SynthError::Config(format!(
            "size {} is not in 16..=4096 pixels",
            cfg.size
        )));
    }
    match &cfg.motion {
        None if cfg.frames == 0 => {
            return Err(SynthError::Config("frames must be at least 1".into()));
        }
        Some(m) if m.is_empty() => {
            return Err(SynthError::Config("the motion has no frames".into()));
        }
        Some(m) => {
            if let Some(i) = m.iter().position(|p| !p.is_finite()) {
                return Err(SynthError::Config(format!(
                    "motion frame {i} has a non-finite number"
                )));
            }
        }
        None => {}
    }
    Ok(())
}

/// Generates the dataset into `out` (created if missing) and writes `out/dataset.json`.
/// `progress(done, total)` is called once before the first frame and after every frame.
/// The output is byte-identical for the same config.
pub fn generate(
    cfg: &SynthConfig,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Dataset, SynthError> {
    check(cfg)?;
    let (width, height) = cfg.image_size();
    let masks_only = cfg.capture.is_some_and(|c| c.masks_only);
    let dirs = if masks_only {
        &write::DIRS[..2]
    } else {
        &write::DIRS[..]
    };
    for dir in dirs {
        let d = out.join(dir);
        std::fs::create_dir_all(&d).map_err(|source| SynthError::Io {
            file: d.clone(),
            source,
        })?;
    }
    let plan::Plan { subjects, jobs } = plan::plan(cfg)?;
    let total = jobs.len();
    progress(0, total);
    let background = Vec3::from(BACKGROUND);
    let smooth_skin = cfg.capture.map_or(0.0, |c| c.smooth_skin_m);
    let mut frames = Vec::with_capacity(total);
    let mut true_fits = Vec::with_capacity(total);
    for (index, (job, camera)) in jobs.into_iter().enumerate() {
        let skeleton = &subjects[job.subject].skeleton;
        let fig = body::figure(
            skeleton,
            &proportions(cfg.appearance(job.subject)),
            &look(cfg.appearance(job.subject)),
            &job.params,
        );
        let posed = skeleton.pose(&job.params);
        let img = tracer::Scene::new(&fig, &posed, background)
            .with_smooth_skin(smooth_skin)
            .render(&camera);
        let paths = write::write_frame(out, index, &img, (width, height), masks_only)?;
        // A biased fit is recorded; the pose rendered goes to the true fits.
        let params = match job.fit {
            Some(fit) => {
                true_fits.push(job.params);
                fit
            }
            None => job.params,
        };
        frames.push(Frame {
            subject: job.subject,
            split: job.split,
            time: job.time,
            image: paths.image,
            mask: paths.mask,
            segmentation: paths.segmentation,
            depth: paths.depth,
            camera,
            params,
        });
        progress(index + 1, total);
    }
    let dataset = Dataset {
        root: out.to_path_buf(),
        background: BACKGROUND,
        matting: talkin_data::dataset::Matting::Matted,
        // The renderer knows each pixel's covered fraction: the person can be shown
        // over any colour, as camera captures are scored.
        masks: talkin_data::dataset::Masks::Coverage,
        subjects,
        frames,
    };
    dataset.save_index()?;
    if !true_fits.is_empty() {
        write::write_true_fits(&dataset, true_fits)?;
    }
    Ok(dataset)
}
