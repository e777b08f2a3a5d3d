//! Resuming a run exactly from its newest good checkpoint.

use std::path::Path;

use burn::tensor::Bytes;
use talkin_avatar::checkpoint::{Checkpoint, dataset_sha256};
use talkin_data::dataset::Dataset;
use talkin_nets::ComputeDevice;

use crate::error::TrainError;
use crate::recipe::TrainOptions;
use crate::recipe::record;
use crate::refine::PoseRefiner;
use crate::step_log::{LOG_FILE, TrainLog};
use talkin_grids::SplitMix64;

use super::construct::{open_device, optimizer};
use super::{TrainState, Trainer};

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
        let device = open_device(on)?;
        let field = checkpoint.field(&device)?;
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
                ..options
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
        t.checkpoints
            .resumed_from(state.step, checkpoint.dir.clone());
        t.notes = notes;
        Ok(t)
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
    if let Some(&bad) = state.frames.iter().find(|&&i| i >= dataset.frames.len()) {
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
