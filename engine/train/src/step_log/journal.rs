//! The run's log as the trainer keeps it: a step whose loss was read is written to
//! `train_log.csv` at once; a GPU step's waits on the device ([`PendingLosses`]) until
//! [`READ_EVERY`] are queued or a checkpoint needs the log at its step; entries written
//! but not yet handed back by `Trainer::step` wait in `unreported`.
//!
//! Owns the log file, the queued losses and the unreported entries; the trainer hands it
//! each step's entry and counts the seconds a read waited as training time.

use burn::prelude::*;

use crate::error::TrainError;
use crate::step_log::pending::{PendingLosses, READ_EVERY};
use crate::step_log::{StepLog, TrainLog};

/// Completed log entries and the seconds a read of the device waited for them.
pub(crate) struct Completed {
    pub entries: Vec<StepLog>,
    pub waited_s: f64,
}

pub(crate) struct Journal {
    log: TrainLog,
    pending: PendingLosses,
    unreported: Vec<StepLog>,
}

impl Journal {
    pub fn new(log: TrainLog) -> Self {
        Journal {
            log,
            pending: PendingLosses::default(),
            unreported: Vec::new(),
        }
    }

    /// A step whose loss was read: written, and handed back after every entry not yet
    /// handed back.
    pub fn record(&mut self, entry: StepLog) -> Result<Vec<StepLog>, TrainError> {
        self.log.write(&entry)?;
        let mut done = std::mem::take(&mut self.unreported);
        done.push(entry);
        Ok(done)
    }

    /// A step whose `[loss, mse]` (`values`) is still on the device, after `secs` of host
    /// time: queued; once [`READ_EVERY`] are, all are read, written and handed back.
    pub fn queue(
        &mut self,
        entry: StepLog,
        secs: f64,
        values: Tensor<1>,
    ) -> Result<Completed, TrainError> {
        self.pending.push(entry, secs, values);
        let mut done = Completed {
            entries: std::mem::take(&mut self.unreported),
            waited_s: 0.0,
        };
        if self.pending.len() >= READ_EVERY {
            let read = self.read_queued()?;
            done.entries.extend(read.entries);
            done.waited_s = read.waited_s;
        }
        Ok(done)
    }

    /// Every entry not yet handed back, the queued steps' read first.
    pub fn settle(&mut self) -> Result<Completed, TrainError> {
        let mut done = self.read_queued()?;
        let mut entries = std::mem::take(&mut self.unreported);
        entries.append(&mut done.entries);
        done.entries = entries;
        Ok(done)
    }

    /// Brings the log file to the last step taken and onto the disk (before a
    /// checkpoint): the queued steps are read and written, and handed back later.
    /// Returns the seconds the read waited.
    pub fn sync(&mut self) -> Result<f64, TrainError> {
        let read = self.read_queued()?;
        self.unreported.extend(read.entries);
        self.log.sync()?;
        Ok(read.waited_s)
    }

    /// Reads and writes the queued steps' entries.
    fn read_queued(&mut self) -> Result<Completed, TrainError> {
        let (entries, waited_s) = self.pending.read()?;
        for entry in &entries {
            self.log.write(entry)?;
        }
        Ok(Completed { entries, waited_s })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::step_log::LOG_FILE;

    fn entry(step: usize) -> StepLog {
        StepLog {
            step,
            seconds: step as f64,
            loss: f32::NAN,
            mse: f32::NAN,
            psnr: f32::NAN,
            rays: 8,
            samples: 80,
            rays_per_s: 8.0,
            samples_per_s: 80.0,
            lr: 1e-2,
            progress: 0.5,
            grid_occupied: 1.0,
            sampling_s: 0.01,
            bones_per_sample: 2.5,
        }
    }

    fn values(step: usize) -> Tensor<1> {
        Tensor::from_floats([step as f32, 0.01], &Device::flex())
    }

    fn steps(entries: &[StepLog]) -> Vec<usize> {
        entries.iter().map(|e| e.step).collect()
    }

    /// The device path run on the CPU: queued steps come back, written, in order, once
    /// `READ_EVERY` are queued; a checkpoint's sync writes the rest at once and they
    /// come back with the next step; read steps come back at once, after those.
    #[test]
    fn every_step_is_written_and_handed_back_once_in_order() {
        let dir = std::env::temp_dir().join(format!("talkin_journal_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(LOG_FILE);
        let mut journal = Journal::new(TrainLog::open(&path, None).unwrap());
        let mut handed = Vec::new();
        for step in 1..READ_EVERY {
            let done = journal.queue(entry(step), 1.0, values(step)).unwrap();
            assert!(done.entries.is_empty() && done.waited_s == 0.0);
        }
        let done = journal
            .queue(entry(READ_EVERY), 1.0, values(READ_EVERY))
            .unwrap();
        assert_eq!(steps(&done.entries), (1..=READ_EVERY).collect::<Vec<_>>());
        assert_eq!(done.entries[2].loss, 3.0);
        handed.extend(done.entries);
        let next = READ_EVERY + 1;
        assert!(
            journal
                .queue(entry(next), 1.0, values(next))
                .unwrap()
                .entries
                .is_empty()
        );
        journal.sync().unwrap();
        let rows = std::fs::read_to_string(&path).unwrap().lines().count() - 1;
        assert_eq!(rows, next, "the log reaches the last step at a checkpoint");
        let mut read = entry(next + 1);
        read.loss = 0.5;
        let done = journal.record(read).unwrap();
        assert_eq!(steps(&done), [next, next + 1]);
        handed.extend(done);
        assert!(journal.settle().unwrap().entries.is_empty());
        assert_eq!(steps(&handed), (1..=next + 1).collect::<Vec<_>>());
        journal.sync().unwrap();
        let rows = std::fs::read_to_string(&path).unwrap().lines().count() - 1;
        assert_eq!(rows, next + 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
