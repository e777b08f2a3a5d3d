//! Building a trainer: a fresh run, or one adapted from another run to a novel subject.

use std::path::{Path, PathBuf};

use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use talkin_avatar::checkpoint::{Checkpoint, dataset_sha256};
use talkin_avatar::subject::{SubjectModel, SubjectSlot, bone_prior};
use talkin_data::dataset::Dataset;
use talkin_grids::OccUpdateOpts;
use talkin_nets::init::WeightRng;
use talkin_nets::loss::{Backbone, PerceptualLoss};
use talkin_nets::{ComputeDevice, FieldConfig, FrameCodes, TalkinField};

use crate::error::TrainError;
use crate::grid_update::GridUpdates;
use crate::preset::Preset;
use crate::rays::FrameCaches;
use crate::recipe::TrainOptions;
use crate::refine::{PoseRefiner, RefineMode};
use crate::step_log::journal::Journal;
use crate::step_log::{LOG_FILE, TrainLog};
use talkin_avatar::refined::RefinerState;
use talkin_nets::kernels::adam::FusedAdam;

use crate::recipe::write_recipe;
use crate::setup::{
    clear_run, clip_of, fit_field_box, fit_subjects, training_frames, unknown_subject,
};

use super::progress::RunProgress;
use super::save::Checkpoints;
use super::{RunWriter, StepMode, Trainer, is_imported};

/// What a trainer is built from: a fresh run's start (`start`) or a checkpoint's contents
/// (`resume`).
pub(super) struct Parts {
    pub opts: TrainOptions,
    pub config: FieldConfig,
    pub field: TalkinField,
    /// The optimizer's moments (`None`: a fresh one).
    pub optim: Option<ModuleOptimizer>,
    pub subjects: Vec<SubjectSlot>,
    pub progress: RunProgress,
    /// The training frames' recorded corrections (`None`: fresh ones, where the options
    /// refine the fits).
    pub pose_refinement: Option<RefinerState>,
    pub log: TrainLog,
    /// The checkpoint resumed from, and its step.
    pub resumed_from: Option<(usize, PathBuf)>,
    /// What loading that checkpoint had to say.
    pub notes: Vec<String>,
    pub mode: StepMode,
    pub writes: RunWriter,
}

impl<'a> Trainer<'a> {
    /// A fresh run of `opts` on `dataset`, writing into `out` (created).
    pub fn new(dataset: &'a Dataset, out: &Path, opts: &TrainOptions) -> Result<Self, TrainError> {
        Trainer::new_as(dataset, out, opts, RunWriter::Writes)
    }

    /// [`Trainer::new`]; with [`RunWriter::ReadsOnly`] (a peer other than 0) nothing is
    /// written into `out`.
    pub fn new_as(
        dataset: &'a Dataset,
        out: &Path,
        opts: &TrainOptions,
        writes: RunWriter,
    ) -> Result<Self, TrainError> {
        opts.check()?;
        let frames = training_frames(dataset, opts.identities.names(), opts.clip_seconds)?;
        let n_subjects = dataset.subjects.len();
        let mut config = opts.preset.field_config(n_subjects);
        config.use_d_hands = opts.ablation.use_d_hands;
        if !opts.ablation.non_rigid {
            config.non_rigid_start_step = None;
        }
        config.hand_background = opts.ablation.hand_background;
        config.face_uses_jaw = opts.ablation.face_uses_jaw;
        config.face_uses_expression = opts.ablation.face_uses_expression;
        config.has_face = opts.ablation.face;
        config.has_hands = opts.ablation.hands;
        if !opts.ablation.hands {
            config.use_d_hands = false;
        }
        opts.apply_hash_grid(&mut config);
        config.skinning.finger_bones = Some(opts.skin_fingers.finger_bones());
        config.mlp_path = Some(opts.mlp_path());
        config.density = Some(opts.density);
        config.frame_codes = (opts.frame_code_dim > 0).then_some(FrameCodes {
            count: frames.len(),
            dim: opts.frame_code_dim,
            deform: opts.frame_code_deform,
        });
        let subjects = fit_subjects(dataset, &frames, opts.grid_resolution)?;
        fit_field_box(&mut config, &subjects);
        let device = open_device(opts.device)?;
        let skeletons = subjects
            .iter()
            .filter_map(|s| s.model.as_ref().map(|m| &m.skeleton));
        // The initial weights are drawn on the host whatever the device, so one seed gives
        // one field on every device.
        let cpu = Device::flex().autodiff();
        let field = config
            .init(
                &bone_prior(skeletons),
                &cpu,
                &mut WeightRng::seeded(opts.seed),
            )
            .map_err(|source| TrainError::Field { source })?;
        let field = if device == cpu {
            field
        } else {
            field.fork(&device)
        };
        let slot_of = (0..n_subjects).map(Some).collect();
        Trainer::start(
            dataset, out, opts, config, field, subjects, frames, slot_of, writes,
        )
    }

    /// Adapts the run in `base` to the subject `subject` of `dataset` (a novel identity:
    /// a new identity code initialised to the mean of the others), training every
    /// parameter on that subject's first `opts.clip_seconds` of training frames with `opts`
    /// (the paper: lr 1e-5, a few iterations). Writes a new run into `out`.
    pub fn adapt(
        dataset: &'a Dataset,
        base: &Path,
        subject: &str,
        out: &Path,
        opts: &TrainOptions,
    ) -> Result<Self, TrainError> {
        opts.check()?;
        if same_dir(base, out) {
            return Err(TrainError::BadOption {
                flag: "--out",
                problem: format!(
                    "{} is the run being adapted; give the adapted run its own directory",
                    out.display()
                ),
            });
        }
        let index_file = dataset.root.join(talkin_data::dataset::INDEX_FILE);
        let s = dataset
            .subject_index(subject)
            .ok_or_else(|| unknown_subject(dataset, "--subject", subject))?;
        let frames = clip_of(dataset, s, opts.clip_seconds);
        if frames.is_empty() {
            return Err(TrainError::NoTrainFrames { file: index_file });
        }
        let checkpoint = Checkpoint::load(base)?;
        let device = open_device(opts.device)?;
        let mut field = checkpoint.field(&device)?;
        let mut config = checkpoint.config.clone();
        let mut subjects = checkpoint.subjects.clone();
        let name = dataset.subjects[s].name.clone();
        let model = SubjectModel::fit(dataset, s, &frames, opts.grid_resolution)?;
        // A subject the base run holds a code for but never trained reuses that code;
        // anyone else gets a new one.
        let slot = match subjects.iter().position(|x| x.name == name) {
            Some(i) if subjects[i].model.is_some() => {
                return Err(TrainError::BadOption {
                    flag: "--subject",
                    problem: format!(
                        "`{name}` was already trained in {}; continue it with `train --resume`",
                        base.display()
                    ),
                });
            }
            Some(i) => {
                subjects[i].model = Some(model);
                i
            }
            None => {
                let (grown, i) = field.add_identity();
                field = grown;
                subjects.push(SubjectSlot {
                    name,
                    model: Some(model),
                });
                i
            }
        };
        config.n_identities = field.n_identities();
        // The clip's frames are not the base run's: each starts from the codes' mean.
        if let Some(codes) = &mut config.frame_codes {
            field = field.reset_frame_codes(frames.len());
            codes.count = field.n_frame_codes();
        }
        // The field's codes are the base run's: the recipe records them as they are.
        let opts = &TrainOptions {
            frame_code_dim: config.frame_codes.map_or(0, |c| c.dim),
            frame_code_deform: config.frame_codes.is_some_and(|c| c.deform),
            ..opts.clone()
        };
        let mut slot_of = vec![None; dataset.subjects.len()];
        slot_of[s] = Some(slot);
        Trainer::start(
            dataset,
            out,
            opts,
            config,
            field,
            subjects,
            frames,
            slot_of,
            RunWriter::Writes,
        )
    }

    /// A new run directory: creates it (clearing any run it held), writes the recipe and
    /// a fresh log.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn start(
        dataset: &'a Dataset,
        out: &Path,
        opts: &TrainOptions,
        config: FieldConfig,
        field: TalkinField,
        subjects: Vec<SubjectSlot>,
        frames: Vec<usize>,
        slot_of: Vec<Option<usize>>,
        writes: RunWriter,
    ) -> Result<Self, TrainError> {
        if writes == RunWriter::Writes {
            std::fs::create_dir_all(out).map_err(|source| TrainError::Io {
                file: out.to_path_buf(),
                source,
            })?;
            clear_run(out)?;
        }
        // The mask defines the person: a frame declared matted that shows its
        // surroundings is composited by its mask when decoded; say so before training.
        let contradicting = dataset.contradicting_frames(&frames)?;
        if !contradicting.is_empty() {
            tracing::warn!(
                "{}: {} of {} training frames are not over the declared background outside \
                 their masks: they are composited by their masks (declare `\"matting\": \
                 \"by_mask\"` in dataset.json to say so; `talkin inspect` lists them)",
                dataset
                    .root
                    .join(talkin_data::dataset::INDEX_FILE)
                    .display(),
                contradicting.len(),
                frames.len()
            );
        }
        // `auto` is decided once, here, and recorded as what it decided.
        let mut opts = opts.clone();
        opts.refine.refine_poses = if opts.refine.is_on(is_imported(dataset)) {
            RefineMode::On
        } else {
            RefineMode::Off
        };
        let log = match writes {
            RunWriter::Writes => {
                write_recipe(out, &opts, &config, None)?;
                TrainLog::open(&out.join(LOG_FILE), None)?
            }
            RunWriter::ReadsOnly => TrainLog::sink(&out.join(LOG_FILE)),
        };
        let progress = RunProgress::start(opts.seed, frames, slot_of);
        Trainer::assemble(
            dataset,
            out,
            Parts {
                opts,
                config,
                field,
                optim: None,
                subjects,
                progress,
                pose_refinement: None,
                log,
                resumed_from: None,
                notes: Vec::new(),
                mode: StepMode::Train,
                writes,
            },
        )
    }

    /// The trainer of `parts`, writing into `out`.
    pub(super) fn assemble(
        dataset: &'a Dataset,
        out: &Path,
        parts: Parts,
    ) -> Result<Self, TrainError> {
        let Parts {
            opts,
            config,
            field,
            optim,
            subjects,
            progress,
            pose_refinement,
            log,
            resumed_from,
            notes,
            mode,
            writes,
        } = parts;
        let device = field.identity.val().device();
        let perceptual = match opts.perceptual_dir() {
            Some(dir) => Some(
                PerceptualLoss::from_dir(dir, Backbone::Alex, &device)
                    .map_err(|source| TrainError::Perceptual { source })?,
            ),
            _ => None,
        };
        // No full-grid warm-up: every update evaluates the occupied cells and a random
        // quarter. Evaluating all ~10^6 cells of a 128-cell grid with three nets took
        // ~6 s per subject on 2 cores (measured on the demo scene), 75x a step.
        let occ_opts = OccUpdateOpts {
            n: opts.occ_every,
            seed: opts.seed,
            warmup_steps: 0,
            ..OccUpdateOpts::default()
        };
        let optim = optim.unwrap_or_else(|| optimizer(opts.preset));
        let dataset_sha256 = dataset_sha256(dataset)?;
        let refiner = (opts.refine.refine_poses == RefineMode::On).then(|| {
            let refine = opts.refine.clone();
            match (pose_refinement, mode) {
                (Some(recorded), _) => PoseRefiner::from_state(dataset, recorded, refine),
                (None, StepMode::Train) => PoseRefiner::new(dataset, &progress.frames, refine),
                (None, StepMode::FitPoses { .. }) => {
                    PoseRefiner::untrusting(dataset, &progress.frames, refine)
                }
            }
        });
        let mut checkpoints = Checkpoints::new(opts.checkpoint_every_s);
        if let Some((step, dir)) = resumed_from {
            checkpoints.resumed_from(step, dir);
        }
        Ok(Trainer {
            refiner,
            dataset,
            out: out.to_path_buf(),
            checkpoints,
            opts,
            config,
            field: Some(field),
            optim,
            subjects,
            progress,
            frame_caches: FrameCaches::default(),
            perceptual,
            journal: Journal::new(log),
            grids: GridUpdates::new(occ_opts),
            dataset_sha256,
            notes,
            mode,
            writer: writes,
            peers: None,
        })
    }
}

/// Whether `a` and `b` name the same existing directory.
fn same_dir(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Adam with the preset's settings, fused into one pass per parameter ([`FusedAdam`]).
pub(super) fn optimizer(preset: Preset) -> ModuleOptimizer {
    let a = preset.adam();
    ModuleOptimizer::from(FusedAdam::new(a.beta_1, a.beta_2, a.epsilon))
}

/// `on`, opened for training (with autodiff).
pub(super) fn open_device(on: ComputeDevice) -> Result<Device, TrainError> {
    Ok(on.open()?.autodiff())
}
