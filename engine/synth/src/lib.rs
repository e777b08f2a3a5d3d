//! Synthetic talking humans: the embedded default dataset. A capsule/SDF mannequin on the
//! SMPL-X skeleton (fingers, a palm, a face whose mouth opens with the jaw and whose brows,
//! eyes and mouth corners follow the expression coefficients, hair with a bun or a
//! ponytail, loose clothing with procedural patterns glued to the limbs), driven by a
//! talking motion, rendered by its own sphere tracer (independent of the engine's
//! samplers) and written in dataset format v1.
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
pub mod render;
pub mod sdf;
pub mod talk;

use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};

use talkin_data::dataset::{DEPTH_UNIT_M, Dataset, DatasetError, Frame, Split, Subject};
use talkin_human::body::skeleton::joint;
use talkin_human::body::{FrameParams, PosedSkeleton, Skeleton};
use talkin_human::camera::{Camera, CameraError};

pub use body::{default_rest_joints, look, proportions};
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
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            identities: 3,
            frames: 48,
            size: 192,
            seed: 0,
            motion: None,
        }
    }
}

impl SynthConfig {
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

/// Names of the authored identities.
const NAMES: [&str; 3] = ["ada", "ben", "cleo"];

fn subject_name(i: usize) -> String {
    NAMES
        .get(i)
        .map_or_else(|| format!("synth{i}"), |n| n.to_string())
}

/// One frame to render, before rendering.
struct Job {
    subject: usize,
    split: Split,
    time: f64,
    params: FrameParams,
}

fn mix(seed: u64, stream: u64) -> u64 {
    talk::SplitMix::new(seed ^ stream.wrapping_mul(0xa076_1d64_78bd_642f)).next_u64()
}

/// The motion style of identity `i`'s built-in clip.
fn style_of(i: usize) -> Style {
    Style {
        tempo: [1.0, 0.8, 1.25][i % 3],
        wide: false,
    }
}

/// Frames of one split per identity for `test_cross` and `test_ood`.
fn eval_count(frames: usize) -> usize {
    (frames / 5).clamp(2, 10)
}

/// The built-in frames of identity `i`.
fn builtin_jobs(cfg: &SynthConfig, i: usize) -> Vec<Job> {
    let mut jobs = Vec::new();
    // Steps until `frames` of them are training steps (every 5th is held out).
    let n = (cfg.frames..)
        .find(|&n| n - (n + 1) / 5 >= cfg.frames)
        .expect("unbounded");
    for (s, params) in talking_clip(mix(cfg.seed, i as u64), n, style_of(i))
        .into_iter()
        .enumerate()
    {
        let split = if s % 5 == 4 {
            Split::TestSame
        } else {
            Split::Train
        };
        jobs.push(Job {
            subject: i,
            split,
            time: s as f64 / FPS,
            params,
        });
    }
    let k = eval_count(cfg.frames);
    // Another identity's motion (or, alone, another clip).
    let other = if cfg.identities > 1 {
        (i + 1) % cfg.identities
    } else {
        1
    };
    let other_clip = talking_clip(mix(cfg.seed, other as u64), n, style_of(other));
    for c in 0..k {
        let s = (c * n) / k + (n / k) / 2;
        jobs.push(Job {
            subject: i,
            split: Split::TestCross,
            time: s as f64 / FPS,
            params: other_clip[s].clone(),
        });
    }
    let ood_stride = 6;
    let ood = talking_clip(
        mix(cfg.seed, 1000 + i as u64),
        k * ood_stride,
        Style {
            tempo: 1.0,
            wide: true,
        },
    );
    for c in 0..k {
        let s = c * ood_stride + ood_stride / 2;
        jobs.push(Job {
            subject: i,
            split: Split::TestOod,
            time: s as f64 / FPS,
            params: ood[s].clone(),
        });
    }
    jobs
}

/// Points that must stay inside the image: the head with its hair, the hands.
fn keypoints(head_scale: f64, posed: &PosedSkeleton) -> Vec<DVec3> {
    let mut pts = Vec::new();
    let head = &posed.world_from_joint[joint::HEAD];
    for off in [
        DVec3::new(0.0, 0.23, 0.0),
        DVec3::new(0.1, 0.1, 0.0),
        DVec3::new(-0.1, 0.1, 0.0),
        DVec3::new(0.0, 0.17, -0.16),
        DVec3::new(0.0, -0.04, -0.19),
        DVec3::new(0.0, 0.0, 0.12),
    ] {
        pts.push(head.transform_point3(off * head_scale));
    }
    for j in [joint::LEFT_WRIST, joint::RIGHT_WRIST]
        .into_iter()
        .chain(joint::LEFT_HAND_FIRST..talkin_human::body::N_JOINTS)
    {
        pts.push(posed.joint(j));
    }
    // Finger tips: one more segment past the last joint.
    for first in [joint::LEFT_HAND_FIRST, joint::RIGHT_HAND_FIRST] {
        for f in 0..5 {
            let (a, b) = (
                posed.joint(first + 3 * f + 1),
                posed.joint(first + 3 * f + 2),
            );
            pts.push(b + (b - a) * 1.1);
        }
    }
    pts
}

/// A frontal camera for one identity, framed from mid-thigh up and widened so every
/// keypoint of every frame lies at least `margin` pixels inside.
fn frame_camera(
    skeleton: &Skeleton,
    head_scale: f64,
    width: u32,
    height: u32,
    posed: &[PosedSkeleton],
    aim: DVec3,
) -> Result<Camera, CameraError> {
    let r = &skeleton.rest_joints;
    let bottom = (r[joint::LEFT_HIP].y + r[joint::LEFT_KNEE].y) * 0.5;
    let top = r[joint::HEAD].y + 0.24 * head_scale;
    let centre = DVec3::new(0.0, (top + bottom) * 0.5, 0.0) + aim;
    let distance = 3.2;
    let eye = centre + DVec3::new(0.0, 0.05, distance);
    let f0 = height as f64 * distance / (top - bottom);
    let probe = Camera::look_at(width, height, f0, eye, centre, DVec3::Y)?;
    let margin = 2.0 + height as f64 * 0.02;
    let (half_w, half_h) = (width as f64 / 2.0 - margin, height as f64 / 2.0 - margin);
    let mut focal = f0;
    for p in posed {
        for k in keypoints(head_scale, p) {
            let c = probe.camera_from_world.transform_point3(k);
            if c.z > 0.1 {
                focal = focal
                    .min(half_w * c.z / c.x.abs().max(1e-9))
                    .min(half_h * c.z / c.y.abs().max(1e-9));
            }
        }
    }
    Camera::look_at(width, height, focal, eye, centre, DVec3::Y)
}

fn png_err(file: &Path) -> impl Fn(image::ImageError) -> SynthError + '_ {
    move |e| SynthError::Png {
        file: file.to_path_buf(),
        message: e.to_string(),
    }
}

/// Generates the dataset into `out` (created if missing) and writes `out/dataset.json`.
/// `progress(done, total)` is called once before the first frame and after every frame.
/// The output is byte-identical for the same config.
pub fn generate(
    cfg: &SynthConfig,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Dataset, SynthError> {
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
    let (width, height) = cfg.image_size();
    for dir in ["images", "masks", "segmentation", "depth"] {
        let d = out.join(dir);
        std::fs::create_dir_all(&d).map_err(|source| SynthError::Io {
            file: d.clone(),
            source,
        })?;
    }

    let mut subjects = Vec::new();
    let mut plan: Vec<(Job, Camera)> = Vec::new();
    for i in 0..cfg.identities {
        let skeleton = default_rest_joints(i);
        let prop = proportions(i);
        let jobs = match &cfg.motion {
            None => builtin_jobs(cfg, i),
            Some(m) => m
                .iter()
                .enumerate()
                .map(|(k, p)| Job {
                    subject: i,
                    split: Split::Train,
                    time: k as f64 / FPS,
                    params: p.clone(),
                })
                .collect(),
        };
        let aim = match &cfg.motion {
            None => DVec3::ZERO,
            Some(m) => m.iter().map(|p| p.transl).sum::<DVec3>() / m.len() as f64,
        };
        let posed: Vec<PosedSkeleton> = jobs.iter().map(|j| skeleton.pose(&j.params)).collect();
        let camera =
            frame_camera(&skeleton, prop.head, width, height, &posed, aim).map_err(|source| {
                SynthError::Camera {
                    identity: i,
                    source,
                }
            })?;
        plan.extend(jobs.into_iter().map(|j| (j, camera)));
        subjects.push(Subject {
            name: subject_name(i),
            skeleton,
        });
    }

    let total = plan.len();
    progress(0, total);
    let background = Vec3::from(BACKGROUND);
    let mut frames = Vec::with_capacity(total);
    for (index, (job, camera)) in plan.into_iter().enumerate() {
        let skeleton = &subjects[job.subject].skeleton;
        let fig = body::figure(
            skeleton,
            &proportions(job.subject),
            &look(job.subject),
            &job.params,
        );
        let posed = skeleton.pose(&job.params);
        let scene = render::Scene::new(&fig, &posed, background);
        let img = scene.render(&camera);
        let name = format!("{index:05}.png");
        let rel = |dir: &str| PathBuf::from(dir).join(&name);
        let (w, h) = (width, height);
        let file = out.join(rel("images"));
        image::RgbImage::from_raw(w, h, img.rgb.iter().flatten().copied().collect())
            .expect("buffer matches the camera")
            .save_with_format(&file, image::ImageFormat::Png)
            .map_err(png_err(&file))?;
        let file = out.join(rel("masks"));
        image::GrayImage::from_raw(
            w,
            h,
            img.label
                .iter()
                .map(|&l| if l > 0 { 255 } else { 0 })
                .collect(),
        )
        .expect("buffer matches the camera")
        .save_with_format(&file, image::ImageFormat::Png)
        .map_err(png_err(&file))?;
        let file = out.join(rel("segmentation"));
        image::GrayImage::from_raw(w, h, img.label.clone())
            .expect("buffer matches the camera")
            .save_with_format(&file, image::ImageFormat::Png)
            .map_err(png_err(&file))?;
        let file = out.join(rel("depth"));
        let depth: Vec<u16> = img
            .depth
            .iter()
            .zip(&img.label)
            .map(|(&z, &l)| {
                if l == 0 {
                    0
                } else {
                    (z as f64 / DEPTH_UNIT_M).round().clamp(1.0, 65535.0) as u16
                }
            })
            .collect();
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, depth)
            .expect("buffer matches the camera")
            .save_with_format(&file, image::ImageFormat::Png)
            .map_err(png_err(&file))?;
        frames.push(Frame {
            subject: job.subject,
            split: job.split,
            time: job.time,
            image: rel("images"),
            mask: rel("masks"),
            segmentation: rel("segmentation"),
            depth: Some(rel("depth")),
            camera,
            params: job.params,
        });
        progress(index + 1, total);
    }
    let dataset = Dataset {
        root: out.to_path_buf(),
        background: BACKGROUND,
        subjects,
        frames,
    };
    dataset.save_index()?;
    Ok(dataset)
}
