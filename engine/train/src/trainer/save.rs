//! Saving a run: checkpoints every few minutes and at the end.

use std::path::PathBuf;

use talkin_avatar::checkpoint::{CheckpointContents, CheckpointError};

use crate::error::TrainError;

use super::{TrainState, Trainer};

impl Trainer<'_> {
    /// Writes a checkpoint now (the log is flushed and fsynced first), keeping the
    /// previous one as a fallback. Without a step since the last checkpoint, returns
    /// that one.
    pub fn save(&mut self) -> Result<PathBuf, TrainError> {
        // The log reaches the checkpoint's step: the losses still on the device first
        // (their entries go to the next `step` or `settle`).
        let read = self.read_losses()?;
        self.unreported.extend(read);
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
}
