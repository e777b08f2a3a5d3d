//! Saving a run: checkpoints every few minutes and at the end. [`Checkpoints`] owns when
//! the next is due and which one the next keeps as its fallback.

use std::path::{Path, PathBuf};

use talkin_avatar::checkpoint::{CheckpointContents, CheckpointError};

use crate::error::TrainError;
use crate::recipe::record;

use super::{TrainState, Trainer};

/// When a run checkpoints, and what it wrote or resumed from last.
pub(super) struct Checkpoints {
    /// Training seconds between two checkpoints (`--checkpoint-every`).
    every_s: f64,
    /// Training seconds since the last checkpoint (or the start).
    since_last_s: f64,
    /// The checkpoint written or resumed from last (kept as the fallback by the next
    /// save) and its step.
    last: Option<(usize, PathBuf)>,
}

impl Checkpoints {
    pub fn new(every_s: f64) -> Self {
        Checkpoints {
            every_s,
            since_last_s: 0.0,
            last: None,
        }
    }

    /// A run resumed from checkpoint `dir` of step `step`.
    pub fn resumed_from(&mut self, step: usize, dir: PathBuf) {
        self.last = Some((step, dir));
    }

    /// `secs` more of training.
    pub fn count(&mut self, secs: f64) {
        self.since_last_s += secs;
    }

    pub fn due(&self) -> bool {
        self.since_last_s >= self.every_s
    }

    /// The checkpoint already written at step `step`, if it is still there.
    fn written_at(&self, step: usize) -> Option<&PathBuf> {
        self.last
            .as_ref()
            .filter(|(at, dir)| *at == step && dir.is_dir())
            .map(|(_, dir)| dir)
    }

    /// The checkpoint a new one keeps as its fallback.
    fn fallback(&self) -> Option<&Path> {
        self.last.as_ref().map(|(_, dir)| dir.as_path())
    }

    /// Checkpoint `dir` was written at step `step`: the clock starts again.
    fn written(&mut self, step: usize, dir: PathBuf) {
        self.since_last_s = 0.0;
        self.last = Some((step, dir));
    }
}

impl Trainer<'_> {
    /// Writes a checkpoint now (the log is flushed and fsynced first), keeping the
    /// previous one as a fallback. Without a step since the last checkpoint, returns
    /// that one.
    pub fn save(&mut self) -> Result<PathBuf, TrainError> {
        if !self.writes() {
            // A peer other than 0: peer 0 writes the run's checkpoints.
            return Ok(talkin_avatar::checkpoint::checkpoint_root(&self.out));
        }
        // The log reaches the checkpoint's step: the losses still on the device first
        // (their entries go to the next `step` or `settle`).
        let waited = self.journal.sync()?;
        self.spend(waited);
        if let Some(dir) = self.checkpoints.written_at(self.progress.step) {
            return Ok(dir.clone());
        }
        let optimizer = self.optim.into_bytes().map_err(|e| TrainError::Resume {
            file: self.out.join(talkin_avatar::checkpoint::OPTIMIZER_FILE),
            problem: e.to_string(),
        })?;
        let state_file = talkin_avatar::checkpoint::checkpoint_root(&self.out)
            .join(talkin_avatar::checkpoint::STATE_FILE);
        let options = record::to_json(&self.opts)
            .map_err(|e| CheckpointError::format(&state_file, "options", e))?;
        let state = TrainState {
            progress: self.progress.clone(),
            field_step: self.field_step(),
            options,
            data: self.dataset.root.clone(),
            dataset_sha256: Some(self.dataset_sha256.clone()),
            pose_refinement: self.refiner.as_ref().map(|r| r.state.clone()),
        };
        let state = serde_json::to_value(&state)
            .map_err(|e| CheckpointError::format(&state_file, "state", e))?;
        let dir = talkin_avatar::checkpoint::save(
            &self.out,
            &CheckpointContents {
                step: self.progress.step,
                field: self.field(),
                config: &self.config,
                optimizer: Some(optimizer.to_vec()),
                background: self.dataset.background,
                subjects: &self.subjects,
                state: &state,
                keep: self.checkpoints.fallback(),
            },
        )?;
        // Checkpoint time counts as training time, not the schedule's.
        self.checkpoints.written(self.progress.step, dir.clone());
        Ok(dir)
    }

    /// Checkpoints when `checkpoint_every_s` of training passed since the last one.
    pub fn maybe_save(&mut self) -> Result<Option<PathBuf>, TrainError> {
        if self.writes() && self.checkpoints.due() {
            self.save().map(Some)
        } else {
            Ok(None)
        }
    }
}
