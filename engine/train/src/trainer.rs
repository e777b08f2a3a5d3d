//! Training the TalkinNeRF field: single- or multi-identity, from scratch, resumed from a
//! checkpoint, or adapted to a novel subject.
//!
//! One step: pick a training frame (seeded), draw LPIPS patches and part-aware random
//! rays ([`schedule`]), sample them (accelerated capsule BVH + occupancy grid, or the
//! dense 128-per-ray baseline), evaluate the field, render over the background, loss
//! `LPIPS + 0.2 MSE + 0.05 CE(seg)`, backward, Adam with the paper's exponential decay.
//! Every `occ_every` steps each subject's occupancy grid is updated with the field's
//! density. Checkpoints ([`crate::checkpoint`]) are written every few minutes and at the
//! end; `Trainer::resume` continues a run exactly where its checkpoint left it.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use burn::tensor::Bytes;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use talkin_grids::{GridError, OccUpdateOpts};
use talkin_nets::loss::{Backbone, LossError, PerceptualLoss};
use talkin_nets::{FieldConfig, NetsError, TalkinField};

pub use crate::batch::PATCH;
pub use crate::options::{Ablation, Budget, TrainOptions};
pub use crate::rng::SplitMix64;
pub use talkin_grids::SamplerKind;

use crate::batch::{BatchSpec, CacheError, FrameCache, draw_batch};
use crate::checkpoint::{Checkpoint, CheckpointContents, CheckpointError, SubjectSlot};
use crate::fused_adam::FusedAdam;
use crate::half_batch::{StepBatch, StepLoss, loss_and_grads};
use crate::schedule;
use crate::subject::{SubjectModel, SubjectModelError, bone_prior};
use talkin_data::dataset::{Dataset, DatasetError, Split};

/// Weight of the segmentation cross-entropy.
pub const SEG_WEIGHT: f32 = 0.05;
/// Weight of the MSE next to the perceptual term (the paper's 0.2).
pub const MSE_WEIGHT: f32 = 0.2;
/// The log file inside the run directory.
pub const LOG_FILE: &str = "train_log.csv";
/// The recipe (options and the derived schedule) inside the run directory.
pub const RECIPE_FILE: &str = "recipe.json";
const LOG_HEADER: &str =
    "step,seconds,loss,mse,psnr,rays,samples,rays_per_s,samples_per_s,lr,grid_occupied,sampling_s";

/// One row of the training log.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepLog {
    /// 1-based: the step just taken.
    pub step: usize,
    /// Training seconds so far (this step included).
    pub seconds: f64,
    pub loss: f32,
    pub mse: f32,
    /// Of the composited colour against the ground truth, over the batch.
    pub psnr: f32,
    pub rays: usize,
    pub samples: usize,
    pub rays_per_s: f64,
    pub samples_per_s: f64,
    pub lr: f64,
    /// Run progress in [0, 1].
    pub progress: f64,
    /// Occupied fraction of the canonical grid last updated (1 before any update).
    pub grid_occupied: f64,
    /// Seconds of this step spent drawing the batch's samples (the chosen sampler, with
    /// any per-frame structure it builds on first use), out of the step's wall time.
    pub sampling_s: f64,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    pub logs: Vec<StepLog>,
    pub checkpoint: PathBuf,
    pub log_file: PathBuf,
    /// Training seconds of this call.
    pub seconds: f64,
    /// `Some` when the perceptual term is SSIM rather than LPIPS: why.
    pub perceptual_note: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Subject(#[from] SubjectModelError),
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("option `{field}`: {problem}")]
    BadOption {
        field: &'static str,
        problem: String,
    },
    #[error("{}: no frame of split `train` for the chosen identities", file.display())]
    NoTrainFrames { file: PathBuf },
    #[error("{}: frames[{frame}]: sampling: {source}", file.display())]
    Grid {
        file: PathBuf,
        frame: usize,
        #[source]
        source: GridError,
    },
    #[error("subject `{subject}`: occupancy grid: {source}")]
    Occupancy {
        subject: String,
        #[source]
        source: GridError,
    },
    #[error("field: {source}")]
    Field {
        #[source]
        source: NetsError,
    },
    #[error("perceptual loss: {source}")]
    Perceptual {
        #[source]
        source: LossError,
    },
    #[error("step {step}: the loss is not finite ({loss}); lower --lr?")]
    NonFinite { step: usize, loss: f32 },
    #[error("{}: {problem}", file.display())]
    Resume { file: PathBuf, problem: String },
}

/// What `state.json` holds: enough to continue exactly.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TrainState {
    step: usize,
    /// The step the field saw last (virtual; see [`schedule`]).
    field_step: usize,
    elapsed_seconds: f64,
    rng_state: u64,
    options: TrainOptions,
    data: PathBuf,
    /// Dataset frames trained on.
    frames: Vec<usize>,
    /// Per dataset subject: its identity code and subject slot.
    slot_of: Vec<Option<usize>>,
}

/// A run in progress.
pub struct Trainer<'a> {
    dataset: &'a Dataset,
    out: PathBuf,
    opts: TrainOptions,
    config: FieldConfig,
    /// Always `Some` between steps; the optimizer step takes it out so that no other
    /// handle shares the parameters' buffers and Adam updates them in place.
    field: Option<TalkinField>,
    optim: ModuleOptimizer,
    subjects: Vec<SubjectSlot>,
    frames: Vec<usize>,
    rng: SplitMix64,
    cache: HashMap<usize, FrameCache>,
    perceptual: Option<PerceptualLoss>,
    step: usize,
    elapsed: f64,
    since_checkpoint: f64,
    log: std::io::BufWriter<std::fs::File>,
    occ_opts: OccUpdateOpts,
    /// Occupied fraction of the grid last updated, for the log.
    grid_occupied: f64,
    /// Per dataset subject: its identity code and subject slot.
    slot_of: Vec<Option<usize>>,
}

impl<'a> Trainer<'a> {
    /// A fresh run of `opts` on `dataset`, writing into `out` (created).
    pub fn new(dataset: &'a Dataset, out: &Path, opts: &TrainOptions) -> Result<Self, TrainError> {
        opts.check()?;
        let frames = training_frames(dataset, opts.identities.as_deref(), opts.clip_seconds)?;
        let n_subjects = dataset.subjects.len();
        let mut config =
            FieldConfig::preset(&opts.preset, n_subjects).ok_or_else(|| TrainError::BadOption {
                field: "preset",
                problem: format!("unknown preset `{}` (fast or paper)", opts.preset),
            })?;
        config.use_d_hands = opts.ablation.use_d_hands;
        config.hand_background = opts.ablation.hand_background;
        config.face_uses_jaw = opts.ablation.face_uses_jaw;
        let subjects = fit_subjects(dataset, &frames, opts.grid_resolution)?;
        fit_field_box(&mut config, &subjects);
        let device = Device::flex().autodiff();
        let skeletons = subjects
            .iter()
            .filter_map(|s| s.model.as_ref().map(|m| &m.skeleton));
        let field = {
            // The device's RNG is process-wide: seeding and drawing the initial weights
            // must not interleave with another trainer's (tests, benches in threads), or
            // the same seed gives different weights.
            let _guard = crate::checkpoint::DEVICE_RNG
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            device.seed(opts.seed);
            config
                .init(&bone_prior(skeletons), &device)
                .map_err(|source| TrainError::Field { source })?
        };
        let slot_of = (0..n_subjects).map(Some).collect();
        Trainer::start(dataset, out, opts, config, field, subjects, frames, slot_of)
    }

    /// Adapts the run in `base` to the subject `subject` of `dataset` (a novel identity:
    /// a new identity code initialised to the mean of the others), training every
    /// parameter on that subject's first `clip_seconds` of training frames with `opts`
    /// (the paper: lr 1e-5, a few iterations). Writes a new run into `out`.
    pub fn adapt(
        dataset: &'a Dataset,
        base: &Path,
        subject: &str,
        clip_seconds: Option<f64>,
        out: &Path,
        opts: &TrainOptions,
    ) -> Result<Self, TrainError> {
        // The recipe records the clip.
        let opts = &TrainOptions {
            clip_seconds,
            ..opts.clone()
        };
        opts.check()?;
        let index_file = dataset.root.join(talkin_data::dataset::INDEX_FILE);
        let s = dataset
            .subject_index(subject)
            .ok_or_else(|| unknown_subject(dataset, "subject", subject))?;
        let frames = clip_of(dataset, s, clip_seconds);
        if frames.is_empty() {
            return Err(TrainError::NoTrainFrames { file: index_file });
        }
        let checkpoint = Checkpoint::load(base)?;
        let device = Device::flex().autodiff();
        {
            let _guard = crate::checkpoint::DEVICE_RNG
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            device.seed(opts.seed);
        }
        // Not under the guard above: `Checkpoint::field` takes DEVICE_RNG itself, and a
        // std Mutex is not re-entrant (holding it here deadlocked every adaptation). The
        // field's initial draw is overwritten by the checkpoint's record, so another
        // thread drawing in between changes nothing.
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
                    field: "subject",
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

    /// Continues the run in `run` from its newest checkpoint, with the same options.
    pub fn resume(dataset: &'a Dataset, run: &Path) -> Result<Self, TrainError> {
        let checkpoint = Checkpoint::load(run)?;
        let state_file = checkpoint.dir.join(crate::checkpoint::STATE_FILE);
        let state: TrainState =
            serde_json::from_value(checkpoint.state.clone()).map_err(|e| TrainError::Resume {
                file: state_file.clone(),
                problem: format!("not a training state: {e}"),
            })?;
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
        let device = Device::flex().autodiff();
        let field = checkpoint.field(&device)?;
        let optim_bytes = checkpoint
            .optimizer_bytes()
            .ok_or_else(|| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: "missing: an inference-only checkpoint cannot be resumed".into(),
            })?
            .to_vec();
        let log = open_log(&run.join(LOG_FILE), Some(state.step))?;
        let mut t = Trainer::assemble(
            dataset,
            run,
            state.options.clone(),
            checkpoint.config.clone(),
            field,
            checkpoint.subjects.clone(),
            state.frames.clone(),
            state.slot_of.clone(),
            log,
        )?;
        t.optim = optimizer(&t.opts)
            .from_bytes(Bytes::from_bytes_vec(optim_bytes))
            .map_err(|e| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: e.to_string(),
            })?;
        t.step = state.step;
        t.elapsed = state.elapsed_seconds;
        t.rng = SplitMix64::from_state(state.rng_state);
        Ok(t)
    }

    /// A new run directory: creates it, writes the recipe and a fresh log.
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
        write_recipe(out, opts, &config)?;
        let log = open_log(&out.join(LOG_FILE), None)?;
        Trainer::assemble(
            dataset,
            out,
            opts.clone(),
            config,
            field,
            subjects,
            frames,
            slot_of,
            log,
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
        log: std::io::BufWriter<std::fs::File>,
    ) -> Result<Self, TrainError> {
        let device = field.identity.val().device();
        let perceptual = match &opts.perceptual {
            Some(dir) if opts.patches > 0 => Some(
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
        let optim = optimizer(&opts);
        Ok(Trainer {
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
        })
    }
}

impl Trainer<'_> {
    /// Run progress in [0, 1] (steps or training seconds against the budget).
    pub fn progress(&self) -> f64 {
        match self.opts.budget {
            Budget::Steps(n) => self.step as f64 / n as f64,
            Budget::Seconds(s) => self.elapsed / s,
        }
        .clamp(0.0, 1.0)
    }

    /// Whether the budget is spent.
    pub fn done(&self) -> bool {
        self.progress() >= 1.0
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
        schedule::virtual_step(self.progress())
    }

    fn field(&self) -> &TalkinField {
        self.field
            .as_ref()
            .expect("the field is back after every step")
    }

    /// One optimizer step (and, when due, an occupancy-grid update).
    pub fn step(&mut self) -> Result<StepLog, TrainError> {
        let t0 = Instant::now();
        // Only errors name the index file: no path allocated on the step's happy path.
        let index_file = || self.dataset.root.join(talkin_data::dataset::INDEX_FILE);
        let vstep = self.field_step();
        let lr = schedule::learning_rate(self.opts.initial_lr(), vstep);
        let i = self.frames[self.rng.below(self.frames.len() as u64) as usize];
        let subject = self.dataset.frames[i].subject;
        let slot = self.slot_of[subject].expect("training frames belong to trained subjects");
        let model = self.subjects[slot]
            .model
            .as_ref()
            .expect("a trained subject has a model");
        if let std::collections::hash_map::Entry::Vacant(entry) = self.cache.entry(i) {
            let fc = FrameCache::new(self.dataset, i, slot, model).map_err(|e| match e {
                CacheError::Dataset(e) => TrainError::Dataset(e),
                CacheError::Grid(source) => TrainError::Grid {
                    file: index_file(),
                    frame: i,
                    source,
                },
            })?;
            entry.insert(fc);
        }
        let fc = &self.cache[&i];
        let grid_err = |source| TrainError::Grid {
            file: index_file(),
            frame: i,
            source,
        };
        let spec = BatchSpec {
            patches: if self.perceptual.is_some() {
                self.opts.patches
            } else {
                0
            },
            random_rays: self.opts.batch_rays,
            bbox_fraction: self.opts.bbox_fraction,
            parts: schedule::part_fractions(vstep),
        };
        let batch = draw_batch(self.dataset, i, fc, &spec, &mut self.rng).map_err(grid_err)?;
        let jitter_seed = self
            .opts
            .seed
            .wrapping_mul(0x9E37_79B9)
            .wrapping_add(self.step as u64);
        let sampling_start = Instant::now();
        let samples = fc
            .sampler
            .sample(
                self.opts.sampler,
                &batch.rays,
                &model.grid,
                Some(jitter_seed),
            )
            .map_err(grid_err)?;
        let sampling_s = sampling_start.elapsed().as_secs_f64();
        let n_rays = batch.rays.len();
        let n_samples = samples.num_samples();
        let StepLoss {
            loss: loss_value,
            mse: mse_value,
            grads,
        } = loss_and_grads(
            self.field(),
            self.perceptual.as_ref(),
            StepBatch {
                rays: &batch.rays,
                samples,
                rgb: &batch.rgb,
                labels: &batch.labels,
                patches: batch.patches,
                patch_side: PATCH as usize,
                frame: &fc.conditions,
                step: vstep,
                background: self.dataset.background,
                mask_weight: self.opts.mask_weight,
            },
        )
        .map_err(|source| TrainError::Field { source })?;
        if !loss_value.is_finite() {
            return Err(TrainError::NonFinite {
                step: self.step + 1,
                loss: loss_value,
            });
        }
        let field = self
            .field
            .take()
            .expect("the field is back after every step");
        self.field = Some(self.optim.step(lr, field, grads));
        self.step += 1;

        // Checked here, before `valid()` builds the gradient-free view of the field: an
        // update is due one step in `occ_every`.
        if self.opts.sampler == SamplerKind::Accelerated
            && self.opts.occ_every > 0
            && self.step.is_multiple_of(self.opts.occ_every as usize)
        {
            let face_dim = talkin_nets::field::EXPRESSION_DIM
                + if self.config.face_uses_jaw {
                    talkin_nets::field::JAW_DIM
                } else {
                    0
                };
            let virtual_per_step = self.field_step() as f64 / self.step as f64;
            if let Some(occupied) = crate::grid_update::update_grids(
                &self.field().valid(),
                &mut self.subjects,
                self.step as u32,
                virtual_per_step,
                &self.occ_opts,
                face_dim,
            )? {
                self.grid_occupied = occupied;
            }
        }

        let secs = t0.elapsed().as_secs_f64().max(1e-9);
        self.elapsed += secs;
        self.since_checkpoint += secs;
        let entry = StepLog {
            step: self.step,
            seconds: self.elapsed,
            loss: loss_value,
            mse: mse_value,
            psnr: -10.0 * mse_value.max(1e-10).log10(),
            rays: n_rays,
            samples: n_samples,
            rays_per_s: n_rays as f64 / secs,
            samples_per_s: n_samples as f64 / secs,
            lr,
            progress: self.progress(),
            grid_occupied: self.grid_occupied,
            sampling_s,
        };
        // Only errors name the log file: no path allocated on the step's happy path.
        let log_file = || self.out.join(LOG_FILE);
        writeln!(
            self.log,
            "{},{:.3},{},{},{},{},{},{:.1},{:.1},{:e},{:.4},{:.6}",
            entry.step,
            entry.seconds,
            entry.loss,
            entry.mse,
            entry.psnr,
            entry.rays,
            entry.samples,
            entry.rays_per_s,
            entry.samples_per_s,
            entry.lr,
            entry.grid_occupied,
            entry.sampling_s
        )
        .map_err(|source| TrainError::Io {
            file: log_file(),
            source,
        })?;
        // Readable while it runs (`tail -f`), without a syscall per step.
        if self.step.is_multiple_of(25) {
            self.log.flush().map_err(|source| TrainError::Io {
                file: log_file(),
                source,
            })?;
        }
        Ok(entry)
    }

    /// Writes a checkpoint now (the log is flushed first).
    pub fn save(&mut self) -> Result<PathBuf, TrainError> {
        let t0 = Instant::now();
        let log_file = self.out.join(LOG_FILE);
        self.log.flush().map_err(|source| TrainError::Io {
            file: log_file,
            source,
        })?;
        let optimizer = self.optim.into_bytes().map_err(|e| TrainError::Resume {
            file: self.out.join(crate::checkpoint::OPTIMIZER_FILE),
            problem: e.to_string(),
        })?;
        let state = TrainState {
            step: self.step,
            field_step: self.field_step(),
            elapsed_seconds: self.elapsed,
            rng_state: self.rng.state(),
            options: self.opts.clone(),
            data: self.dataset.root.clone(),
            frames: self.frames.clone(),
            slot_of: self.slot_of.clone(),
        };
        let state = serde_json::to_value(&state).expect("plain data serialises");
        let dir = crate::checkpoint::save(
            &self.out,
            &CheckpointContents {
                step: self.step,
                field: self.field(),
                config: &self.config,
                optimizer: Some(optimizer.to_vec()),
                background: self.dataset.background,
                subjects: &self.subjects,
                state: &state,
            },
        )?;
        // Checkpoint time counts as training time, not the schedule's.
        self.since_checkpoint = 0.0;
        let _ = t0;
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
    pub fn run(mut self, progress: &mut dyn FnMut(&StepLog)) -> Result<TrainReport, TrainError> {
        let start = self.elapsed;
        let mut logs = Vec::new();
        while !self.done() {
            let entry = self.step()?;
            progress(&entry);
            logs.push(entry);
            self.maybe_save()?;
        }
        let checkpoint = self.save()?;
        Ok(TrainReport {
            logs,
            checkpoint,
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

/// The training frames of the chosen identities (all with training frames when `None`),
/// each cut to its first `clip_seconds` of video when given.
fn training_frames(
    dataset: &Dataset,
    identities: Option<&[String]>,
    clip_seconds: Option<f64>,
) -> Result<Vec<usize>, TrainError> {
    let index_file = dataset.root.join(talkin_data::dataset::INDEX_FILE);
    let chosen: Vec<usize> = match identities {
        None => (0..dataset.subjects.len()).collect(),
        Some(names) => names
            .iter()
            .map(|n| {
                dataset
                    .subject_index(n)
                    .ok_or_else(|| unknown_subject(dataset, "identities", n))
            })
            .collect::<Result<_, _>>()?,
    };
    // In dataset order, each frame once (a name may be listed twice).
    let mut frames: Vec<usize> = chosen
        .iter()
        .flat_map(|&s| clip_of(dataset, s, clip_seconds))
        .collect();
    frames.sort_unstable();
    frames.dedup();
    if frames.is_empty() {
        return Err(TrainError::NoTrainFrames { file: index_file });
    }
    Ok(frames)
}

/// Subject `s`'s training frames in time order, cut to those less than `clip_seconds`
/// after its first one (all of them for `None`): the short clip a novel identity is
/// learned from, by adaptation or from scratch.
fn clip_of(dataset: &Dataset, s: usize, clip_seconds: Option<f64>) -> Vec<usize> {
    let mut frames = dataset.subject_frames(s, Split::Train);
    if let Some(limit) = clip_seconds
        && let Some(&first) = frames.first()
    {
        let t0 = dataset.frames[first].time;
        frames.retain(|&i| dataset.frames[i].time - t0 < limit);
    }
    frames
}

/// `field` names a subject `name` the dataset does not have; the error lists those it has.
fn unknown_subject(dataset: &Dataset, field: &'static str, name: &str) -> TrainError {
    let has: Vec<&str> = dataset.subjects.iter().map(|s| s.name.as_str()).collect();
    TrainError::BadOption {
        field,
        problem: format!(
            "{} has no subject `{name}` (has: {})",
            dataset
                .root
                .join(talkin_data::dataset::INDEX_FILE)
                .display(),
            has.join(", ")
        ),
    }
}

/// A slot per dataset subject; a model (shells, grid) for those with training frames.
fn fit_subjects(
    dataset: &Dataset,
    frames: &[usize],
    grid_resolution: u32,
) -> Result<Vec<SubjectSlot>, TrainError> {
    (0..dataset.subjects.len())
        .map(|s| {
            let own: Vec<usize> = frames
                .iter()
                .copied()
                .filter(|&i| dataset.frames[i].subject == s)
                .collect();
            let model = if own.is_empty() {
                None
            } else {
                Some(SubjectModel::fit(dataset, s, &own, grid_resolution)?)
            };
            Ok(SubjectSlot {
                name: dataset.subjects[s].name.clone(),
                model,
            })
        })
        .collect()
}

/// The field's canonical box: the union of the grids (every sample the grid keeps maps
/// inside it), padded by 5 cm.
fn fit_field_box(config: &mut FieldConfig, subjects: &[SubjectSlot]) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for m in subjects.iter().filter_map(|s| s.model.as_ref()) {
        let (g_lo, g_hi) = m.grid.aabb();
        lo = lo.min(g_lo);
        hi = hi.max(g_hi);
    }
    if lo.is_finite() && hi.is_finite() {
        let pad = Vec3::splat(0.05);
        config.aabb_min = (lo - pad).to_array();
        config.aabb_max = (hi + pad).to_array();
    }
}

/// `RUN/recipe.json`: the options, the field config and the schedule they imply.
fn write_recipe(out: &Path, opts: &TrainOptions, config: &FieldConfig) -> Result<(), TrainError> {
    let recipe = serde_json::json!({
        "options": opts,
        "initial_lr": opts.initial_lr(),
        "loss": format!(
            "{}{}",
            if opts.perceptual.is_some() && opts.patches > 0 {
                format!("perceptual (LPIPS alex, else 1 - SSIM) on {} patch(es) of {PATCH}x{PATCH} + {MSE_WEIGHT} MSE + {SEG_WEIGHT} CE", opts.patches)
            } else {
                format!("MSE + {SEG_WEIGHT} CE (no perceptual term)")
            },
            if opts.mask_weight > 0.0 {
                format!(" + {} MSE(opacity, mask)", opts.mask_weight)
            } else {
                String::new()
            }
        ),
        "schedule": {
            "virtual_iterations": schedule::PAPER_ITERATIONS,
            "lr_decay": format!("x0.1 per {} virtual iterations", schedule::LR_DECAY_ITERATIONS),
            "part_aware_rays": "virtual 0-20k: 20% hands; 20-40k: 20% hands + 60% arms; 40-60k: 40/40; 60-80k: 80/20; then 20% hands (of the in-box rays)",
            "non_rigid_start_step": config.non_rigid_start_step,
        },
        "field": config,
    });
    let path = out.join(RECIPE_FILE);
    talkin_data::atomic::write_atomic(
        &path,
        serde_json::to_string_pretty(&recipe)
            .expect("JSON serialises")
            .as_bytes(),
    )
    .map_err(|source| TrainError::Io { file: path, source })
}

/// Opens the log: fresh with a header, or (resuming at `step`) keeping the header and
/// the rows of steps up to `step` (a killed run may have logged steps past its last
/// checkpoint). Rows of a log written before a column was added get it empty.
fn open_log(
    path: &Path,
    resume_at: Option<usize>,
) -> Result<std::io::BufWriter<std::fs::File>, TrainError> {
    let io = |source| TrainError::Io {
        file: path.to_path_buf(),
        source,
    };
    let mut kept = String::from(LOG_HEADER);
    kept.push('\n');
    if let Some(step) = resume_at {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        for line in text.lines().skip(1) {
            match line.split(',').next().and_then(|s| s.parse::<usize>().ok()) {
                Some(s) if s <= step => {
                    kept.push_str(line);
                    for _ in line.split(',').count()..LOG_HEADER.split(',').count() {
                        kept.push(',');
                    }
                    kept.push('\n');
                }
                _ => {}
            }
        }
    }
    let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    file.write_all(kept.as_bytes()).map_err(io)?;
    Ok(file)
}

/// Adam as the recipe says: the paper's defaults (betas 0.9, 0.999, eps 1e-8) for the
/// `paper` preset; instant-ngp's (0.9, 0.99, 1e-15) for the hash-grid `fast` preset,
/// whose sparse, tiny table gradients an eps of 1e-5 (burn's default) all but freezes.
/// Fused into one pass per parameter ([`fused_adam`]).
fn optimizer(opts: &TrainOptions) -> ModuleOptimizer {
    let (beta_2, epsilon) = if opts.preset == "paper" {
        (0.999, 1e-8)
    } else {
        (0.99, 1e-15)
    };
    ModuleOptimizer::from(FusedAdam::new(0.9, beta_2, epsilon))
}

/// Reads a one-element tensor.
pub(crate) fn scalar(t: &Tensor<1>) -> f32 {
    t.clone()
        .try_to_vec_as::<f32>()
        .ok()
        .and_then(|v| v.first().copied())
        .unwrap_or(f32::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Resuming keeps the rows up to the checkpoint's step, and rows of a log written
    /// before the last column was added get it empty, so every row has the header's
    /// columns.
    #[test]
    fn resumed_log_keeps_rows_up_to_the_step_with_every_column() {
        let dir = std::env::temp_dir().join(format!("talkin_open_log_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(LOG_FILE);
        let old_header = LOG_HEADER.rsplit_once(',').unwrap().0;
        std::fs::write(
            &path,
            format!(
                "{old_header}\n1,0.1,1,1,1,8,8,1,1,1e-2,1\n2,0.2,1,1,1,8,8,1,1,1e-2,1\n\
                 3,0.3,1,1,1,8,8,1,1,1e-2,1\n"
            ),
        )
        .unwrap();
        drop(open_log(&path, Some(2)).unwrap());
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let columns = LOG_HEADER.split(',').count();
        assert_eq!(lines[0], LOG_HEADER);
        assert_eq!(lines.len(), 3, "{text}");
        assert!(
            lines.iter().all(|l| l.split(',').count() == columns),
            "{text}"
        );
        assert_eq!(lines[2], "2,0.2,1,1,1,8,8,1,1,1e-2,1,");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
