//! Resuming a run exactly from its newest good checkpoint.

use std::path::Path;

use burn::tensor::Bytes;
use talkin_avatar::checkpoint::{Checkpoint, dataset_sha256};
use talkin_data::dataset::Dataset;
use talkin_nets::ComputeDevice;

use crate::error::TrainError;
use crate::recipe::TrainOptions;
use crate::recipe::record;
use crate::refine::RefineMode;
use crate::step_log::{LOG_FILE, TrainLog};

use super::construct::{Parts, open_device, optimizer};
use super::{RunWriter, StepMode, TrainState, Trainer};

impl<'a> Trainer<'a> {
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
        Trainer::resume_as(dataset, run, on, RunWriter::Writes)
    }

    /// [`Trainer::resume_on`]; with [`RunWriter::ReadsOnly`] (a peer other than 0) the run
    /// is read, never written.
    pub fn resume_as(
        dataset: &'a Dataset,
        run: &Path,
        on: ComputeDevice,
        writes: RunWriter,
    ) -> Result<Self, TrainError> {
        let Recorded {
            checkpoint,
            state,
            options,
            state_file,
            notes,
        } = Recorded::load(dataset, run)?;
        let refine_on = options.refine.refine_poses == RefineMode::On;
        match &state.pose_refinement {
            Some(recorded) if refine_on && recorded.frames == state.progress.frames => {}
            None if !refine_on => {}
            _ => {
                return Err(TrainError::Resume {
                    file: state_file,
                    problem: "`pose_refinement` does not match the recorded options and \
                              training frames"
                        .into(),
                });
            }
        }
        let device = open_device(on)?;
        let field = checkpoint.field(&device)?;
        let optim_bytes = checkpoint
            .optimizer_bytes()
            .ok_or_else(|| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: "missing: an inference-only checkpoint cannot be resumed".into(),
            })?
            .to_vec();
        let optim = optimizer(options.preset)
            .from_bytes(Bytes::from_bytes_vec(optim_bytes))
            .map_err(|e| TrainError::Resume {
                file: checkpoint.optimizer_file(),
                problem: e.to_string(),
            })?;
        let log = match writes {
            RunWriter::Writes => TrainLog::open(&run.join(LOG_FILE), Some(state.progress.step))?,
            RunWriter::ReadsOnly => TrainLog::sink(&run.join(LOG_FILE)),
        };
        Trainer::assemble(
            dataset,
            run,
            Parts {
                opts: TrainOptions {
                    device: on,
                    ..options
                },
                config: checkpoint.config.clone(),
                field,
                optim: Some(optim),
                subjects: checkpoint.subjects.clone(),
                resumed_from: Some((state.progress.step, checkpoint.dir.clone())),
                progress: state.progress,
                pose_refinement: state.pose_refinement,
                log,
                notes,
                mode: StepMode::Train,
                writes,
            },
        )
    }
}

/// A run's newest usable checkpoint with its training state and options, checked to
/// belong to the dataset given (what resuming and fitting poses to a run both start from).
pub(super) struct Recorded {
    pub checkpoint: Checkpoint,
    pub state: TrainState,
    pub options: TrainOptions,
    /// The checkpoint's `state.json` (for messages).
    pub state_file: std::path::PathBuf,
    /// What loading it had to say.
    pub notes: Vec<String>,
}

impl Recorded {
    pub fn load(dataset: &Dataset, run: &Path) -> Result<Recorded, TrainError> {
        let checkpoint = Checkpoint::load(run)?;
        let mut notes = checkpoint.notes.clone();
        let state_file = checkpoint.dir.join(talkin_avatar::checkpoint::STATE_FILE);
        let state: TrainState =
            serde_json::from_value(checkpoint.state.clone()).map_err(|e| TrainError::Resume {
                file: state_file.clone(),
                problem: format!("not a training state: {e}"),
            })?;
        if let Some(note) = check_same_dataset(dataset, run, &state, &state_file)? {
            notes.push(note);
        }
        let options =
            record::from_json(state.options.clone()).map_err(|problem| TrainError::Resume {
                file: state_file.clone(),
                problem: format!("`options`: {problem}"),
            })?;
        Ok(Recorded {
            checkpoint,
            state,
            options,
            state_file,
            notes,
        })
    }
}

/// Refuses a resume on another dataset than the run's (by its fingerprint) or on one
/// that lacks the run's training frames; a run from a build without fingerprints gives
/// a note instead.
fn check_same_dataset(
    dataset: &Dataset,
    run: &Path,
    state: &TrainState,
    state_file: &Path,
) -> Result<Option<String>, TrainError> {
    let given_sha256 = dataset_sha256(dataset)?;
    let note = match &state.dataset_sha256 {
        Some(trained) if *trained != given_sha256 => {
            return Err(TrainError::OtherDataset {
                run: run.to_path_buf(),
                trained_on: state.data.clone(),
                trained_sha256: trained.clone(),
                given: dataset.root.join(talkin_data::dataset::INDEX_FILE),
                given_sha256,
            });
        }
        Some(_) => None,
        None => {
            let note = format!(
                "{}: no dataset fingerprint (a run from an older build): cannot \
                 check that {} is the dataset it was trained on",
                state_file.display(),
                dataset.root.display()
            );
            tracing::warn!("{note}");
            Some(note)
        }
    };
    if let Some(&bad) = state
        .progress
        .frames
        .iter()
        .find(|&&i| i >= dataset.frames.len())
    {
        return Err(TrainError::Resume {
            file: state_file.to_path_buf(),
            problem: format!(
                "frame {bad} is not in {} ({} frames): resume with the dataset the run \
                 was trained on ({})",
                dataset.root.display(),
                dataset.frames.len(),
                state.data.display()
            ),
        });
    }
    Ok(note)
}
