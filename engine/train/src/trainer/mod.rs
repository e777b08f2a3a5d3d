//! The run around the step: a trainer is built fresh ([`Trainer::new`]), adapted from
//! another run to a novel subject ([`Trainer::adapt`]) or resumed exactly from its newest
//! checkpoint ([`Trainer::resume`]), optionally to a new budget ([`Trainer::set_budget`]);
//! [`Trainer::run`] steps it ([`Trainer::step`]) until its budget is spent or it is told to
//! stop ([`Trainer::run_until`]), checkpointing every few minutes and at the end.
//!
//! This file holds the trainer's state, its accessors and the run loop; `construct`
//! builds one (fresh or adapted), `progress` is the state a checkpoint saves as it is,
//! `resume` continues a run from a checkpoint, `fit_poses` fits held-out frames' poses
//! to a frozen checkpoint, `step`
//! takes one optimizer step, `save` writes checkpoints and `budget` maps a run onto the
//! schedule.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use serde::{Deserialize, Serialize};
use talkin_avatar::checkpoint::path_json;
use talkin_avatar::refined::RefinerState;
use talkin_avatar::subject::SubjectSlot;
use talkin_data::dataset::Dataset;
use talkin_nets::loss::PerceptualLoss;
use talkin_nets::{FieldConfig, TalkinField};

use crate::error::TrainError;
use crate::grid_update::GridUpdates;
use crate::peers::PeerLink;
use crate::rays::FrameCaches;
use crate::recipe::TrainOptions;
use crate::refine::PoseRefiner;
use crate::schedule;
use crate::step_log::journal::Journal;
use crate::step_log::{LOG_FILE, StepLog};
mod budget;
mod construct;
mod fit_poses;
mod join;
mod progress;
mod resume;
mod save;
mod step;

pub use budget::ScheduleAnchor;
pub use fit_poses::{FitPosesOptions, FittedPoses, fit_held_out_poses};
use progress::RunProgress;

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
    /// Among peers: what the exchanges cost (bytes a step, the all-reduce's share).
    pub peers: Option<String>,
}

/// What `state.json` holds: the run's progress as it is, and what it was trained with
/// (recorded at each save, checked on resume).
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TrainState {
    #[serde(flatten)]
    progress: RunProgress,
    /// The step the field saw last (virtual; see [`schedule`]).
    field_step: usize,
    /// The options as [`crate::recipe::record`] writes them.
    options: serde_json::Value,
    /// The dataset directory, as given (for messages).
    #[serde(with = "path_json::serde_path")]
    data: PathBuf,
    /// SHA-256 of the dataset's `dataset.json`; with the progress's frames, the
    /// dataset's fingerprint (absent in runs from before it was recorded).
    #[serde(default)]
    dataset_sha256: Option<String>,
    /// The training frames' pose corrections and their optimizer (absent: the run
    /// trusts its fits).
    #[serde(default)]
    pose_refinement: Option<RefinerState>,
}

/// What a step moves.
#[derive(Clone, Copy, Debug, PartialEq)]
enum StepMode {
    /// The field, its occupancy grids and (when refining) the training fits' corrections.
    Train,
    /// Only the frames' pose corrections: the field and its grids stay as a checkpoint
    /// left them, seen at that checkpoint's field step, every frame with the mean frame
    /// code (a test-time fit of held-out frames' poses, `fit_poses`).
    FitPoses { field_step: usize },
}

/// A run in progress. Its parts own their state: its progress (`RunProgress`), the
/// frames' caches (`FrameCaches`), the
/// log (`Journal`), the checkpoints (`save::Checkpoints`) and the grid updates
/// (`GridUpdates`); the files of this module build it (`construct`,
/// `resume`), step it (`step`), save it (`save`) and place it on the schedule (`budget`).
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
    /// Where the run is and what it draws from: saved as it is.
    progress: RunProgress,
    /// SHA-256 of the dataset's `dataset.json` (of `dataset`), recorded in every
    /// checkpoint.
    dataset_sha256: String,
    frame_caches: FrameCaches,
    perceptual: Option<PerceptualLoss>,
    journal: Journal,
    checkpoints: save::Checkpoints,
    grids: GridUpdates,
    /// The training fits' corrections (`None`: the fits are trusted).
    refiner: Option<PoseRefiner>,
    /// What loading the checkpoint this run resumed from had to say.
    notes: Vec<String>,
    mode: StepMode,
    /// Whether this process writes the run: alone, or peer 0 of a data-parallel run
    /// (the other peers write nothing into it).
    writer: RunWriter,
    /// The other peers of a data-parallel run (`None`: alone).
    peers: Option<PeerLink>,
}

/// Who writes a run: the process training it alone (or peer 0 of several), or a peer
/// that only reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunWriter {
    Writes,
    ReadsOnly,
}

impl Trainer<'_> {
    /// What loading the checkpoint this run resumed from had to say.
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// The dataset frames this run draws its rays from (for `adapt`, the clip's).
    pub fn training_frames(&self) -> &[usize] {
        &self.progress.frames
    }

    /// Steps taken.
    pub fn steps_taken(&self) -> usize {
        self.progress.step
    }

    /// Training seconds so far (evaluation pauses excluded).
    pub fn elapsed_seconds(&self) -> f64 {
        self.progress.elapsed
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

    /// Whether this process writes the run (see [`RunWriter`]).
    fn writes(&self) -> bool {
        self.writer == RunWriter::Writes
    }

    /// `secs` more of training: on the run's clock and the checkpoints'.
    fn spend(&mut self, secs: f64) {
        self.checkpoints.count(secs);
        match &mut self.peers {
            None => self.progress.elapsed += secs,
            // The run's clock is peer 0's, set at each step's exchange.
            Some(link) => link.local_elapsed += secs,
        }
    }

    /// The colour the dataset's images are composited on.
    pub fn background(&self) -> [f32; 3] {
        self.dataset.background
    }

    /// The step the field sees now (virtual; see [`schedule`]).
    pub fn field_step(&self) -> usize {
        schedule::virtual_step(self.schedule_progress())
    }

    fn field(&self) -> &TalkinField {
        self.field
            .as_ref()
            .expect("the field is back after every step")
    }

    /// Identity slot of dataset subject `s` (`None`: not trained in this run).
    pub fn slot_of(&self, s: usize) -> Option<usize> {
        self.progress.slot_of.get(s).copied().flatten()
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
        let start = self.progress.elapsed;
        let mut logs = Vec::new();
        let mut interrupted = false;
        while !self.done() {
            match &mut self.peers {
                // Peers stop together: after the step at whose exchange any was asked.
                Some(link) => {
                    if link.stop_agreed {
                        interrupted = true;
                        break;
                    }
                    link.stop_asked = stop.load(Ordering::SeqCst);
                }
                None if stop.load(Ordering::SeqCst) => {
                    interrupted = true;
                    break;
                }
                None => {}
            }
            for entry in self.step()? {
                progress(&entry);
                logs.push(entry);
            }
            self.maybe_save()?;
        }
        for entry in self.settle()? {
            progress(&entry);
            logs.push(entry);
        }
        let checkpoint = self.save()?;
        Ok(TrainReport {
            logs,
            checkpoint,
            steps: self.progress.step,
            interrupted,
            notes: self.notes.clone(),
            log_file: self.out.join(LOG_FILE),
            seconds: self.progress.elapsed - start,
            perceptual_note: self.perceptual_note(),
            peers: self.peers.as_ref().map(PeerLink::summary),
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
        .join(talkin_data::dataset::IMPORT_REPORT)
        .is_file()
}
