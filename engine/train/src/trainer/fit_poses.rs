//! A test-time fit of held-out frames' poses: the trained field frozen as its checkpoint
//! left it, each frame's correction moved down the loss training uses, as InstantAvatar
//! evaluates novel poses (it optimises each test frame's SMPL parameters with the model
//! frozen before scoring). `talkin eval --pose-fit` scores the refitted frames beside
//! the plain score, never instead of it.

use std::path::Path;
use std::time::Instant;

use talkin_avatar::refined::{RefinedFits, layout};
use talkin_data::dataset::Dataset;
use talkin_nets::ComputeDevice;

use crate::error::TrainError;
use crate::recipe::{Budget, TrainOptions};
use crate::refine::{RefineMode, RefineOptions};
use crate::step_log::{LOG_FILE, TrainLog};

use super::construct::{Parts, open_device};
use super::progress::RunProgress;
use super::resume::Recorded;
use super::{StepMode, Trainer};

/// How held-out frames' poses are fitted.
#[derive(Clone, Debug, PartialEq)]
pub struct FitPosesOptions {
    /// Steps per frame (the frames are visited in turn).
    pub steps_per_frame: usize,
    /// Adam's rate for every group of the correction (radians a step; translation at
    /// 0.2x, metres).
    pub lr: f64,
}

impl Default for FitPosesOptions {
    fn default() -> Self {
        FitPosesOptions {
            steps_per_frame: 100,
            lr: 3e-3,
        }
    }
}

/// The fitted corrections and what they amount to.
#[derive(Clone, Debug)]
pub struct FittedPoses {
    /// The corrections, keyed by dataset frame, for the dataset the run trained on.
    pub fits: RefinedFits,
    pub steps: usize,
    pub seconds: f64,
    /// Root mean square over the frames and body joints (global orientation included) of
    /// the correction's rotation angle, degrees.
    pub rotation_rms_deg: f64,
    /// Mean over the frames of the translation's correction, metres.
    pub translation_mean_m: f64,
}

/// Fits the poses of dataset frames `frames` to the newest checkpoint of `run` (trained
/// on `dataset`) on the CPU, the field, its grids and codes frozen. The fit's log goes to
/// `scratch` (created); `progress` hears the steps taken and their total.
pub fn fit_held_out_poses(
    dataset: &Dataset,
    run: &Path,
    frames: &[usize],
    opts: &FitPosesOptions,
    scratch: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<FittedPoses, TrainError> {
    let start = Instant::now();
    let mut trainer = Trainer::fit_poses(dataset, run, frames, opts, scratch)?;
    let total = opts.steps_per_frame * frames.len();
    while !trainer.done() {
        trainer.step()?;
        progress(trainer.steps_taken(), total);
    }
    trainer.settle()?;
    let fits = trainer
        .refined_fits()
        .expect("a pose fit always refines its frames");
    let deltas: Vec<&Vec<f32>> = frames.iter().filter_map(|i| fits.delta.get(i)).collect();
    let n = deltas.len().max(1) as f64;
    let angle2 = |d: &[f32], k: usize| (0..3).map(|a| (d[k + a] as f64).powi(2)).sum::<f64>();
    let joints = (layout::BODY.end - layout::ORIENT.start) / 3;
    let rotation_ms = deltas
        .iter()
        .map(|d| (0..joints).map(|j| angle2(d, 3 * j)).sum::<f64>() / joints as f64)
        .sum::<f64>()
        / n;
    let translation_mean_m = deltas
        .iter()
        .map(|d| angle2(d, layout::TRANSL.start).sqrt())
        .sum::<f64>()
        / n;
    Ok(FittedPoses {
        fits,
        steps: trainer.steps_taken(),
        seconds: start.elapsed().as_secs_f64(),
        rotation_rms_deg: rotation_ms.sqrt().to_degrees(),
        translation_mean_m,
    })
}

impl<'a> Trainer<'a> {
    /// A trainer that moves only the pose corrections of `frames`, from zero, on the
    /// field of `run`'s newest checkpoint as it is ([`StepMode::FitPoses`]).
    fn fit_poses(
        dataset: &'a Dataset,
        run: &Path,
        frames: &[usize],
        opts: &FitPosesOptions,
        scratch: &Path,
    ) -> Result<Self, TrainError> {
        let Recorded {
            checkpoint,
            state,
            options: recorded,
            ..
        } = Recorded::load(dataset, run)?;
        let slot_of = state.progress.slot_of.clone();
        if let Some(&i) = frames.iter().find(|&&i| {
            dataset
                .frames
                .get(i)
                .is_none_or(|f| slot_of.get(f.subject).copied().flatten().is_none())
        }) {
            return Err(TrainError::BadOption {
                flag: "--pose-fit",
                problem: format!(
                    "frame {i} of {} is not of a subject {} trained",
                    dataset.root.display(),
                    run.display()
                ),
            });
        }
        if !(opts.lr.is_finite() && opts.lr > 0.0) {
            return Err(TrainError::BadOption {
                flag: "--pose-fit-lr",
                problem: "must be a positive number".into(),
            });
        }
        if frames.is_empty() || opts.steps_per_frame == 0 {
            return Err(TrainError::BadOption {
                flag: "--pose-fit",
                problem: "needs at least one frame and one step a frame".into(),
            });
        }
        let fit = TrainOptions {
            device: ComputeDevice::Cpu,
            budget: Budget::Steps(opts.steps_per_frame * frames.len()),
            checkpoint_every_s: f64::INFINITY,
            refine: RefineOptions {
                refine_poses: RefineMode::On,
                pose_lr: opts.lr,
                pose_lr_jitter: opts.lr,
                pose_warmup: 0,
                pose_prior: 0.0,
                pose_smooth: 0.0,
            },
            ..recorded
        };
        std::fs::create_dir_all(scratch).map_err(|source| TrainError::Io {
            file: scratch.to_path_buf(),
            source,
        })?;
        let log = TrainLog::open(&scratch.join(LOG_FILE), None)?;
        let device = open_device(fit.device)?;
        Trainer::assemble(
            dataset,
            scratch,
            Parts {
                progress: RunProgress::start(fit.seed, frames.to_vec(), slot_of),
                opts: fit,
                config: checkpoint.config.clone(),
                field: checkpoint.field(&device)?,
                optim: None,
                subjects: checkpoint.subjects.clone(),
                pose_refinement: None,
                log,
                resumed_from: None,
                notes: Vec::new(),
                mode: StepMode::FitPoses {
                    field_step: state.field_step,
                },
                writes: super::RunWriter::Writes,
            },
        )
    }
}
