//! What to render: per identity, the frames of the built-in talking motion (train,
//! `test_same`, `test_cross`, `test_ood`; see the crate docs) or of a given motion, each
//! with its split, time, pose and the identity's camera.

use glam::DVec3;

use talkin_data::dataset::{Split, Subject};
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;

use crate::capture::{CAPTURE_FPS, biased_fits, capture_clip};
use crate::framing::frame_camera;
use crate::talk::{self, FPS, Style, talking_clip};
use crate::{SynthConfig, SynthError, default_rest_joints, proportions};

/// Names of the authored identities.
const NAMES: [&str; 3] = ["ada", "ben", "cleo"];

fn subject_name(i: usize) -> String {
    NAMES
        .get(i)
        .map_or_else(|| format!("synth{i}"), |n| n.to_string())
}

/// One frame to render, before rendering.
pub(crate) struct Job {
    pub subject: usize,
    pub split: Split,
    pub time: f64,
    /// The pose rendered.
    pub params: FrameParams,
    /// The capture-like scene's biased fit, which the dataset records instead of
    /// `params` (`None`: the fit is exact).
    pub fit: Option<FrameParams>,
}

impl Job {
    fn exact(subject: usize, split: Split, time: f64, params: FrameParams) -> Job {
        Job {
            subject,
            split,
            time,
            params,
            fit: None,
        }
    }
}

fn mix(seed: u64, stream: u64) -> u64 {
    talk::scene_rng(seed ^ stream.wrapping_mul(0xa076_1d64_78bd_642f)).next_u64()
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
        jobs.push(Job::exact(i, split, s as f64 / FPS, params));
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
        jobs.push(Job::exact(
            i,
            Split::TestCross,
            s as f64 / FPS,
            other_clip[s].clone(),
        ));
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
        jobs.push(Job::exact(
            i,
            Split::TestOod,
            s as f64 / FPS,
            ood[s].clone(),
        ));
    }
    jobs
}

/// The capture-like frames of identity `i` (`capture` module docs): a clip with every
/// sixth frame `test_same`, then a separate wider clip for `test_ood`; each clip's fits
/// biased as `cfg.capture` asks.
fn capture_jobs(cfg: &SynthConfig, i: usize) -> Vec<Job> {
    let capture = cfg.capture.unwrap_or_default();
    let n = (cfg.frames..)
        .find(|&n| n - (n + 1) / 6 >= cfg.frames)
        .expect("unbounded");
    let k = eval_count(cfg.frames);
    let ood_stride = 6;
    let clips = [
        (capture_clip(mix(cfg.seed, 2000 + i as u64), n, false), 1),
        (
            capture_clip(mix(cfg.seed, 3000 + i as u64), k * ood_stride, true),
            ood_stride,
        ),
    ];
    let mut jobs = Vec::new();
    for (c, (clip, stride)) in clips.into_iter().enumerate() {
        let times: Vec<f64> = (0..clip.len()).map(|s| s as f64 / CAPTURE_FPS).collect();
        let fits = biased_fits(
            &clip,
            &times,
            capture.fit_bias_deg,
            capture.fit_bias_m,
            mix(cfg.seed, 4000 + 2 * i as u64 + c as u64),
        );
        for s in (0..clip.len()).skip(stride / 2).step_by(stride) {
            let split = match c {
                0 if s % 6 == 5 => Split::TestSame,
                0 => Split::Train,
                _ => Split::TestOod,
            };
            jobs.push(Job {
                subject: i,
                split,
                time: times[s],
                params: clip[s].clone(),
                fit: capture.biased().then(|| fits[s].clone()),
            });
        }
    }
    jobs
}

/// Every frame of `motion` as a training frame of identity `i`.
fn motion_jobs(motion: &[FrameParams], i: usize) -> Vec<Job> {
    motion
        .iter()
        .enumerate()
        .map(|(k, p)| Job::exact(i, Split::Train, k as f64 / FPS, p.clone()))
        .collect()
}

/// What `generate` renders and writes.
pub(crate) struct Plan {
    pub subjects: Vec<Subject>,
    /// Every frame in output order, with its identity's camera.
    pub jobs: Vec<(Job, Camera)>,
}

/// The subjects, and every frame to render in output order with its identity's camera.
pub(crate) fn plan(cfg: &SynthConfig) -> Result<Plan, SynthError> {
    let (width, height) = cfg.image_size();
    let mut subjects = Vec::new();
    let mut planned: Vec<(Job, Camera)> = Vec::new();
    for i in 0..cfg.identities {
        let skeleton = default_rest_joints(cfg.appearance(i));
        let prop = proportions(cfg.appearance(i));
        let jobs = match (&cfg.motion, cfg.capture) {
            (Some(m), _) => motion_jobs(m, i),
            (None, Some(_)) => capture_jobs(cfg, i),
            (None, None) => builtin_jobs(cfg, i),
        };
        // A given motion may walk off: aim at where it stays on average.
        let aim = match &cfg.motion {
            None => DVec3::ZERO,
            Some(m) => m.iter().map(|p| p.transl).sum::<DVec3>() / m.len() as f64,
        };
        let posed: Vec<_> = jobs.iter().map(|j| skeleton.pose(&j.params)).collect();
        let camera = frame_camera(
            &skeleton,
            prop.head,
            (width, height),
            &posed,
            aim,
            cfg.framing(),
        )
        .map_err(|source| SynthError::Camera {
            identity: i,
            source,
        })?;
        planned.extend(jobs.into_iter().map(|j| (j, camera)));
        subjects.push(Subject {
            name: subject_name(cfg.appearance(i)),
            skeleton,
        });
    }
    Ok(Plan {
        subjects,
        jobs: planned,
    })
}
