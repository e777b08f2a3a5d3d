//! The run's log as the trainer keeps it: a step whose loss was read is written to
//! `train_log.csv` at once; a GPU step's waits on the device ([`PendingLosses`]) until
//! [`READ_EVERY`] are queued or a checkpoint needs the log at its step; entries written
//! but not yet handed back by `Trainer::step` wait in `unreported`.
//!
//! Owns the log file, the queued losses and the unreported entries; the trainer hands it
//! each step's entry and counts the seconds a read waited as training time.

use burn::prelude::*;

use crate::error::TrainError;
use crate::log::{StepLog, TrainLog};
use crate::pending::{PendingLosses, READ_EVERY};

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
