//! The run around the step: a trainer is built fresh ([`Trainer::new`]), adapted from
//! another run to a novel subject ([`Trainer::adapt`]) or resumed exactly from its newest
//! checkpoint ([`Trainer::resume`]), optionally to a new budget ([`Trainer::set_budget`]);
//! [`Trainer::run`] steps it ([`crate::step`]) until its budget is spent or it is told to
//! stop ([`Trainer::run_until`]), checkpointing every few minutes and at the end.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use burn::tensor::Bytes;
use serde::{Deserialize, Serialize};
use talkin_avatar::checkpoint::{
    Checkpoint, CheckpointContents, CheckpointError, dataset_sha256, path_json,
};
use talkin_avatar::device_rng::DeviceRng;
use talkin_avatar::refined::RefinerState;
use talkin_avatar::subject::{SubjectModel, SubjectSlot, bone_prior};
use talkin_data::dataset::Dataset;
use talkin_grids::OccUpdateOpts;
use talkin_nets::loss::{Backbone, PerceptualLoss};
use talkin_nets::{ComputeDevice, FieldConfig, TalkinField};

use crate::error::TrainError;
use crate::log::{LOG_FILE, StepLog, TrainLog};
use crate::preset::Preset;
use crate::rays::FrameCache;
use crate::recipe::TrainOptions;
use crate::refine::{PoseRefiner, RefineMode};
use crate::rng::SplitMix64;
use crate::schedule;
use talkin_nets::kernels::adam::FusedAdam;
mod budget;

pub use budget::ScheduleAnchor;

use crate::setup::{
    clear_run, clip_of, fit_field_box, fit_subjects, options_serde, training_frames,
    unknown_subject, write_recipe,
};

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    pub logs: Vec<StepLog>,
    /// The checkpoint written at the end (or at the interruption).
    pub checkpoint: PathBuf,
    /// Steps of the run in all (earlier calls included): the checkpoint's step.
    pub steps: usize,
    /// Whether the run stopped early because [`Trainer::run_until`]'s flag was set.
    pub interrupted: bool,
    /// What loading the checkpoint it resumed from had to say (a fallback from a damaged
    /// checkpoint, a checkpoint without a manifest or dataset fingerprint).
    pub notes: Vec<String>,
    pub log_file: PathBuf,
    /// Training seconds of this call.
    pub seconds: f64,
    /// `Some` when the perceptual term is SSIM rather than LPIPS: why.
    pub perceptual_note: Option<String>,
}

/// What `state.json` holds: enough to continue exactly.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TrainState {
    step: usize,
    /// The step the field saw last (virtual; see [`schedule`]).
    field_step: usize,
    elapsed_seconds: f64,
    rng_state: u64,
    #[serde(with = "options_serde")]
    options: TrainOptions,
    /// The dataset directory, as given (for messages).
    #[serde(with = "path_json::serde_path")]
    data: PathBuf,
    /// SHA-256 of the dataset's `dataset.json`; with `frames`, the dataset's fingerprint
    /// (absent in runs from before it was recorded).
    #[serde(default)]
    dataset_sha256: Option<String>,
    /// Dataset frames trained on.
    frames: Vec<usize>,
    /// Per dataset subject: its identity code and subject slot.
    slot_of: Vec<Option<usize>>,
    /// Where the schedule was last re-anchored to a new budget (absent: never).
    #[serde(default)]
    schedule_anchor: Option<ScheduleAnchor>,
    /// The training frames' pose corrections and their optimizer (absent: the run
    /// trusts its fits).
    #[serde(default)]
    pose_refinement: Option<RefinerState>,
}

/// A run in progress.
pub struct Trainer<'a> {
    pub(crate) dataset: &'a Dataset,
    pub(crate) out: PathBuf,
    pub(crate) opts: TrainOptions,
    pub(crate) config: FieldConfig,
    /// Always `Some` between steps; the optimizer step takes it out so that no other
    /// handle shares the parameters' buffers and Adam updates them in place.
    pub(crate) field: Option<TalkinField>,
    pub(crate) optim: ModuleOptimizer,
    pub(crate) subjects: Vec<SubjectSlot>,
    pub(crate) frames: Vec<usize>,
    pub(crate) rng: SplitMix64,
    pub(crate) cache: HashMap<usize, FrameCache>,
    pub(crate) perceptual: Option<PerceptualLoss>,
    pub(crate) step: usize,
    pub(crate) elapsed: f64,
    pub(crate) since_checkpoint: f64,
    pub(crate) log: TrainLog,
    pub(crate) occ_opts: OccUpdateOpts,
    /// Occupied fraction of the grid last updated, for the log.
    pub(crate) grid_occupied: f64,
    /// Per dataset subject: its identity code and subject slot.
    pub(crate) slot_of: Vec<Option<usize>>,
    /// SHA-256 of the dataset's `dataset.json`, recorded in every checkpoint.
    pub(crate) dataset_sha256: String,
    pub(crate) anchor: Option<ScheduleAnchor>,
    /// The checkpoint written or resumed from last (kept as the fallback by the next
    /// save) and its step.
    pub(crate) last_checkpoint: Option<(usize, PathBuf)>,
    pub(crate) notes: Vec<String>,
    /// The training fits' corrections (`None`: the fits are trusted).
    pub(crate) refiner: Option<PoseRefiner>,
}

impl<'a> Trainer<'a> {
    /// A fresh run of `opts` on `dataset`, writing into `out` (created).
    pub fn new(dataset: &'a Dataset, out: &Path, opts: &TrainOptions) -> Result<Self, TrainError> {
        opts.check()?;
        let frames = training_frames(dataset, opts.identities.names(), opts.clip_seconds)?;
        let n_subjects = dataset.subjects.len();
        let mut config = opts.preset.field_config(n_subjects);
        config.use_d_hands = opts.ablation.use_d_hands;
        config.hand_background = opts.ablation.hand_background;
        config.face_uses_jaw = opts.ablation.face_uses_jaw;
        let subjects = fit_subjects(dataset, &frames, opts.grid_resolution)?;
        fit_field_box(&mut config, &subjects);
        let device = open_device(opts.device)?;
        let skeletons = subjects
            .iter()
            .filter_map(|s| s.model.as_ref().map(|m| &m.skeleton));
        let field = {
            // The initial weights are drawn on the CPU whatever the device, so one seed
            // gives one field on every device. The CPU's RNG is process-wide: seeding and
            // drawing take one turn at it, or another trainer's draws (tests, benches in
            // threads) would interleave and the same seed give different weights.
            let cpu = Device::flex().autodiff();
            let mut rng = DeviceRng::take_turn();
            rng.seed(&cpu, opts.seed);
            let field = config
                .init(&bone_prior(skeletons), &cpu)
                .map_err(|source| TrainError::Field { source })?;
            // burn draws a layer's weights lazily, on first use: draw them all now, on
            // the CPU and during the turn, or a forked field would draw them on its device.
            materialize(&field);
            if device == cpu {
                field
            } else {
                field.fork(&device)
            }
        };
        let slot_of = (0..n_subjects).map(Some).collect();
        Trainer::start(dataset, out, opts, config, field, subjects, frames, slot_of)
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
        // The field's initial draw is overwritten by the checkpoint's record; the seed is
        // for what the adaptation draws after it.
        let mut field = {
            let mut rng = DeviceRng::take_turn();
            rng.seed(&device, opts.seed);
            checkpoint.field(&device, &mut rng)?
        };
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
        let mut slot_of = vec![None; dataset.subjects.len()];
        slot_of[s] = Some(slot);
        Trainer::start(dataset, out, opts, config, field, subjects, frames, slot_of)
    }

    /// Continues the run in `run` from its newest usable checkpoint, with the same options
    /// and budget ([`Trainer::set_budget`] gives it another). Refuses a dataset other
    /// than the one the run was trained on. It trains on the CPU.
    pub fn resume(dataset: &'a Dataset, run: &Path) -> Result<Self, TrainError> {
        Trainer::resume_on(dataset, run, ComputeDevice::Cpu)
    }

    /// [`Trainer::resume`] on device `on`, whichever device wrote the checkpoint
    /// (checkpoints hold host arrays).
    pub fn resume_on(
        dataset: &'a Dataset,
        run: &Path,
        on: ComputeDevice,
    ) -> Result<Self, TrainError> {
        let checkpoint = Checkpoint::load(run)?;
        let mut notes = checkpoint.notes.clone();
        let state_file = checkpoint.dir.join(talkin_avatar::checkpoint::STATE_FILE);
        let state: TrainState =
            serde_json::from_value(checkpoint.state.clone()).map_err(|e| TrainError::Resume {
                file: state_file.clone(),
                problem: format!("not a training state: {e}"),
            })?;
        let given_sha256 = dataset_sha256(dataset)?;
        match &state.dataset_sha256 {
            Some(trained) if *trained != given_sha256 => {
                return Err(TrainError::OtherDataset {
                    run: run.to_path_buf(),
                    trained_on: state.data.clone(),
                    trained_sha256: trained.clone(),
                    given: dataset.root.join(talkin_data::dataset::INDEX_FILE),
                    given_sha256,
                });
            }
            Some(_) => {}
            None => {
                let note = format!(
                    "{}: no dataset fingerprint (a run from an older build): cannot \
                     check that {} is the dataset it was trained on",
                    state_file.display(),
                    dataset.root.display()
                );
                tracing::warn!("{note}");
                notes.push(note);
            }
        }
        if let Some(&bad) = state.frames.iter().find(|&&i| i >= dataset.frames.len()) {
            return Err(TrainError::Resume {
                file: state_file,
                problem: format!(
                    "frame {bad} is not in {} ({} frames): resume with the dataset the run \
                     was trained on ({})",
                    dataset.root.display(),
                    dataset.frames.len(),
                    state.data.display()
                ),
            });
        }
        let device = open_device(on)?;
        let field = checkpoint.field(&device, &mut DeviceRng::take_turn())?;
        let optim_bytes = checkpoint
            .optimizer_bytes()
            .ok_or_else(|| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: "missing: an inference-only checkpoint cannot be resumed".into(),
            })?
            .to_vec();
        let log = TrainLog::open(&run.join(LOG_FILE), Some(state.step))?;
        let mut t = Trainer::assemble(
            dataset,
            run,
            TrainOptions {
                device: on,
                ..state.options.clone()
            },
            checkpoint.config.clone(),
            field,
            checkpoint.subjects.clone(),
            state.frames.clone(),
            state.slot_of.clone(),
            log,
        )?;
        t.optim = optimizer(t.opts.preset)
            .from_bytes(Bytes::from_bytes_vec(optim_bytes))
            .map_err(|e| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: e.to_string(),
            })?;
        t.step = state.step;
        t.elapsed = state.elapsed_seconds;
        t.rng = SplitMix64::from_state(state.rng_state);
        t.anchor = state.schedule_anchor;
        match (&mut t.refiner, state.pose_refinement) {
            (Some(r), Some(recorded)) if recorded.frames == t.frames => {
                *r = PoseRefiner::from_state(dataset, recorded, r.opts.clone());
            }
            (None, None) => {}
            _ => {
                return Err(TrainError::Resume {
                    file: state_file,
                    problem: "`pose_refinement` does not match the recorded options and \
                              training frames"
                        .into(),
                });
            }
        }
        t.last_checkpoint = Some((state.step, checkpoint.dir.clone()));
        t.notes = notes;
        Ok(t)
    }

    /// A new run directory: creates it (clearing any run it held), writes the recipe and
    /// a fresh log.
    #[allow(clippy::too_many_arguments)]
    fn start(
        dataset: &'a Dataset,
        out: &Path,
        opts: &TrainOptions,
        config: FieldConfig,
        field: TalkinField,
        subjects: Vec<SubjectSlot>,
        frames: Vec<usize>,
        slot_of: Vec<Option<usize>>,
    ) -> Result<Self, TrainError> {
        std::fs::create_dir_all(out).map_err(|source| TrainError::Io {
            file: out.to_path_buf(),
            source,
        })?;
        clear_run(out)?;
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
        write_recipe(out, &opts, &config, None)?;
        let log = TrainLog::open(&out.join(LOG_FILE), None)?;
        Trainer::assemble(
            dataset, out, opts, config, field, subjects, frames, slot_of, log,
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        dataset: &'a Dataset,
        out: &Path,
        opts: TrainOptions,
        config: FieldConfig,
        field: TalkinField,
        subjects: Vec<SubjectSlot>,
        frames: Vec<usize>,
        slot_of: Vec<Option<usize>>,
        log: TrainLog,
    ) -> Result<Self, TrainError> {
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
        let optim = optimizer(opts.preset);
        let dataset_sha256 = dataset_sha256(dataset)?;
        let refiner = (opts.refine.refine_poses == RefineMode::On)
            .then(|| PoseRefiner::new(dataset, &frames, opts.refine.clone()));
        Ok(Trainer {
            refiner,
            dataset,
            out: out.to_path_buf(),
            rng: SplitMix64::new(opts.seed ^ 0x7A1C_11E5_EED5_0001),
            opts,
            config,
            field: Some(field),
            optim,
            subjects,
            frames,
            cache: HashMap::new(),
            perceptual,
            step: 0,
            elapsed: 0.0,
            since_checkpoint: 0.0,
            log,
            occ_opts,
            grid_occupied: 1.0,
            slot_of,
            dataset_sha256,
            anchor: None,
            last_checkpoint: None,
            notes: Vec::new(),
        })
    }
}

impl Trainer<'_> {
    /// What loading the checkpoint this run resumed from had to say.
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// The dataset frames this run draws its rays from (for `adapt`, the clip's).
    pub fn training_frames(&self) -> &[usize] {
        &self.frames
    }

    /// Steps taken.
    pub fn steps_taken(&self) -> usize {
        self.step
    }

    /// Training seconds so far (evaluation pauses excluded).
    pub fn elapsed_seconds(&self) -> f64 {
        self.elapsed
    }

    pub fn options(&self) -> &TrainOptions {
        &self.opts
    }

    /// `Some` when the perceptual term is SSIM rather than LPIPS: why.
    pub fn perceptual_note(&self) -> Option<String> {
        self.perceptual.as_ref().and_then(|p| p.fallback_reason())
    }

    /// The field as it is now, without its gradients (for evaluations during a run).
    pub fn inference_field(&self) -> TalkinField {
        self.field().valid()
    }

    /// The training fits' corrections (`None`: the run trusts its fits).
    pub fn refiner(&self) -> Option<&PoseRefiner> {
        self.refiner.as_ref()
    }

    /// The refined training fits as renders read them (`None`: the run trusts its fits).
    pub fn refined_fits(&self) -> Option<talkin_avatar::refined::RefinedFits> {
        self.refiner
            .as_ref()
            .map(|r| talkin_avatar::refined::RefinedFits::new(&r.state, &self.dataset_sha256))
    }

    /// The field's configuration.
    pub fn config(&self) -> &FieldConfig {
        &self.config
    }

    /// Every identity slot of the field, with the models of the trained subjects.
    pub fn subjects(&self) -> &[SubjectSlot] {
        &self.subjects
    }

    /// The colour the dataset's images are composited on.
    pub fn background(&self) -> [f32; 3] {
        self.dataset.background
    }

    /// The step the field sees now (virtual; see [`schedule`]).
    pub fn field_step(&self) -> usize {
        schedule::virtual_step(self.schedule_progress())
    }

    pub(crate) fn field(&self) -> &TalkinField {
        self.field
            .as_ref()
            .expect("the field is back after every step")
    }

    /// Writes a checkpoint now (the log is flushed and fsynced first), keeping the
    /// previous one as a fallback. Without a step since the last checkpoint, returns
    /// that one.
    pub fn save(&mut self) -> Result<PathBuf, TrainError> {
        self.log.sync()?;
        if let Some((step, dir)) = &self.last_checkpoint
            && *step == self.step
            && dir.is_dir()
        {
            return Ok(dir.clone());
        }
        let optimizer = self.optim.into_bytes().map_err(|e| TrainError::Resume {
            file: self.out.join(talkin_avatar::checkpoint::OPTIMIZER_FILE),
            problem: e.to_string(),
        })?;
        let state = TrainState {
            step: self.step,
            field_step: self.field_step(),
            elapsed_seconds: self.elapsed,
            rng_state: self.rng.state(),
            options: self.opts.clone(),
            data: self.dataset.root.clone(),
            dataset_sha256: Some(self.dataset_sha256.clone()),
            frames: self.frames.clone(),
            slot_of: self.slot_of.clone(),
            schedule_anchor: self.anchor,
            pose_refinement: self.refiner.as_ref().map(|r| r.state.clone()),
        };
        let state = serde_json::to_value(&state).map_err(|e| {
            CheckpointError::format(
                &talkin_avatar::checkpoint::checkpoint_root(&self.out)
                    .join(talkin_avatar::checkpoint::STATE_FILE),
                "state",
                e,
            )
        })?;
        let dir = talkin_avatar::checkpoint::save(
            &self.out,
            &CheckpointContents {
                step: self.step,
                field: self.field(),
                config: &self.config,
                optimizer: Some(optimizer.to_vec()),
                background: self.dataset.background,
                subjects: &self.subjects,
                state: &state,
                keep: self.last_checkpoint.as_ref().map(|(_, dir)| dir.as_path()),
            },
        )?;
        // Checkpoint time counts as training time, not the schedule's.
        self.since_checkpoint = 0.0;
        self.last_checkpoint = Some((self.step, dir.clone()));
        Ok(dir)
    }

    /// Checkpoints when `checkpoint_every_s` of training passed since the last one.
    pub fn maybe_save(&mut self) -> Result<Option<PathBuf>, TrainError> {
        if self.since_checkpoint >= self.opts.checkpoint_every_s {
            self.save().map(Some)
        } else {
            Ok(None)
        }
    }

    /// Identity slot of dataset subject `s` (`None`: not trained in this run).
    pub fn slot_of(&self, s: usize) -> Option<usize> {
        self.slot_of.get(s).copied().flatten()
    }

    /// Trains until the budget is spent, checkpointing on the way and at the end.
    pub fn run(self, progress: &mut dyn FnMut(&StepLog)) -> Result<TrainReport, TrainError> {
        self.run_until(&AtomicBool::new(false), progress)
    }

    /// [`Trainer::run`], but `stop` is polled between steps: once it is set, the step in
    /// progress finishes, a checkpoint is written (the log flushed with it) and the report
    /// says `interrupted` (a signal handler sets it: Ctrl-C or SIGTERM).
    pub fn run_until(
        mut self,
        stop: &AtomicBool,
        progress: &mut dyn FnMut(&StepLog),
    ) -> Result<TrainReport, TrainError> {
        let start = self.elapsed;
        let mut logs = Vec::new();
        let mut interrupted = false;
        while !self.done() {
            if stop.load(Ordering::SeqCst) {
                interrupted = true;
                break;
            }
            let entry = self.step()?;
            progress(&entry);
            logs.push(entry);
            self.maybe_save()?;
        }
        let checkpoint = self.save()?;
        Ok(TrainReport {
            logs,
            checkpoint,
            steps: self.step,
            interrupted,
            notes: self.notes.clone(),
            log_file: self.out.join(LOG_FILE),
            seconds: self.elapsed - start,
            perceptual_note: self.perceptual_note(),
        })
    }
}

/// Trains a fresh run of `opts` on `dataset` into `out` (see [`Trainer`]).
pub fn train(
    dataset: &Dataset,
    out: &Path,
    opts: &TrainOptions,
    progress: &mut dyn FnMut(&StepLog),
) -> Result<TrainReport, TrainError> {
    Trainer::new(dataset, out, opts)?.run(progress)
}

/// Whether `dataset` came from `talkin import` (its report sits beside `dataset.json`):
/// its fits are an estimator's, worth refining.
pub fn is_imported(dataset: &Dataset) -> bool {
    dataset
        .root
        .join(talkin_data::import::IMPORT_REPORT)
        .is_file()
}

/// Whether `a` and `b` name the same existing directory.
fn same_dir(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Adam with the preset's settings, fused into one pass per parameter ([`FusedAdam`]).
fn optimizer(preset: Preset) -> ModuleOptimizer {
    let a = preset.adam();
    ModuleOptimizer::from(FusedAdam::new(a.beta_1, a.beta_2, a.epsilon))
}

/// `on`, opened for training (with autodiff).
fn open_device(on: ComputeDevice) -> Result<Device, TrainError> {
    Ok(on.open()?.autodiff())
}

/// Draws every lazily initialised parameter of `field` now.
fn materialize(field: &TalkinField) {
    struct Touch;
    impl burn::module::ModuleVisitor for Touch {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            let _ = param.val();
        }
    }
    field.visit(&mut Touch);
}
