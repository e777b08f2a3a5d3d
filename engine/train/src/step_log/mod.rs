//! `RUN/train_log.csv`: one row per step, readable while the run goes on.

pub(crate) mod journal;
pub(crate) mod pending;

use std::path::{Path, PathBuf};

use crate::error::TrainError;

/// The log file inside the run directory.
pub const LOG_FILE: &str = "train_log.csv";
const LOG_HEADER: &str = "step,seconds,loss,mse,psnr,rays,samples,rays_per_s,samples_per_s,lr,grid_occupied,sampling_s,\
     bones_per_sample";

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
    /// Mean body bones inverse skinning evaluates per sample (its candidates; 22 for a
    /// dense sample).
    pub bones_per_sample: f64,
}

/// The open log of a run (`None`: a peer that writes nothing, peer 0 writing the log).
pub(crate) struct TrainLog {
    path: PathBuf,
    writer: Option<csv::Writer<std::fs::File>>,
}

impl TrainLog {
    /// Opens the log: fresh with a header, or (resuming at `step`) keeping the header
    /// and the rows of steps up to `step` (a killed run may have logged steps past its
    /// last checkpoint). Rows of a log written before a column was added get it empty.
    /// The kept rows replace the file atomically before any new row is appended.
    pub fn open(path: &Path, resume_at: Option<usize>) -> Result<TrainLog, TrainError> {
        let columns = LOG_HEADER.split(',').count();
        let mut kept = csv::Writer::from_writer(Vec::new());
        kept.write_record(LOG_HEADER.split(','))
            .map_err(|source| log_error(path, source))?;
        if let Some(step) = resume_at {
            // Steps rise row by row; a row that does not rise is a row cut short by a
            // kill or a full disk ("13" of "130,...") and goes.
            let mut last = 0;
            for row in read_rows(path)? {
                let row_step = std::str::from_utf8(row.get(0).unwrap_or_default())
                    .ok()
                    .and_then(|s| s.trim().parse::<usize>().ok());
                if let Some(row_step) = row_step.filter(|&s| s > last && s <= step) {
                    last = row_step;
                    let mut fields: Vec<&[u8]> = row.iter().take(columns).collect();
                    fields.resize(columns, b"");
                    kept.write_record(&fields)
                        .map_err(|source| log_error(path, source))?;
                }
            }
        }
        let bytes = kept
            .into_inner()
            .map_err(|e| log_error(path, e.into_error().into()))?;
        let io = |source| TrainError::Io {
            file: path.to_path_buf(),
            source,
        };
        talkin_data::atomic::write_atomic(path, &bytes).map_err(io)?;
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .map_err(io)?;
        Ok(TrainLog {
            path: path.to_path_buf(),
            writer: Some(
                csv::WriterBuilder::new()
                    .has_headers(false)
                    .from_writer(file),
            ),
        })
    }

    /// A log that writes nothing (a peer other than 0: peer 0 writes the run's log).
    pub fn sink(path: &Path) -> TrainLog {
        TrainLog {
            path: path.to_path_buf(),
            writer: None,
        }
    }

    /// Appends `entry`; flushes every 25 steps, so `tail -f` follows the run without a
    /// syscall per step (and always at a checkpoint, see [`TrainLog::sync`]).
    pub fn write(&mut self, entry: &StepLog) -> Result<(), TrainError> {
        let row = [
            entry.step.to_string(),
            format!("{:.3}", entry.seconds),
            entry.loss.to_string(),
            entry.mse.to_string(),
            entry.psnr.to_string(),
            entry.rays.to_string(),
            entry.samples.to_string(),
            format!("{:.1}", entry.rays_per_s),
            format!("{:.1}", entry.samples_per_s),
            format!("{:e}", entry.lr),
            format!("{:.4}", entry.grid_occupied),
            format!("{:.6}", entry.sampling_s),
            format!("{:.3}", entry.bones_per_sample),
        ];
        if let Some(writer) = &mut self.writer {
            writer
                .write_record(&row)
                .map_err(|source| log_error(&self.path, source))?;
        }
        if entry.step.is_multiple_of(25) {
            self.flush()?;
        }
        Ok(())
    }

    /// Hands the buffered rows to the OS.
    pub fn flush(&mut self) -> Result<(), TrainError> {
        match &mut self.writer {
            Some(w) => w.flush().map_err(|source| TrainError::Io {
                file: self.path.clone(),
                source,
            }),
            None => Ok(()),
        }
    }

    /// Flushes and fsyncs: every row written so far survives a crash (at a checkpoint,
    /// whose step the rows must reach).
    pub fn sync(&mut self) -> Result<(), TrainError> {
        self.flush()?;
        match &self.writer {
            Some(w) => w.get_ref().sync_data().map_err(|source| self.io(source)),
            None => Ok(()),
        }
    }

    fn io(&self, source: std::io::Error) -> TrainError {
        TrainError::Io {
            file: self.path.clone(),
            source,
        }
    }
}

/// The rows of the log at `path` (none if it does not exist), header skipped; rows may
/// have fewer columns than the header (older logs).
fn read_rows(path: &Path) -> Result<Vec<csv::ByteRecord>, TrainError> {
    let mut reader = match csv::ReaderBuilder::new().flexible(true).from_path(path) {
        Ok(reader) => reader,
        Err(e) if matches!(e.kind(), csv::ErrorKind::Io(io) if io.kind() == std::io::ErrorKind::NotFound) =>
        {
            return Ok(Vec::new());
        }
        Err(source) => return Err(log_error(path, source)),
    };
    reader
        .byte_records()
        .collect::<Result<_, _>>()
        .map_err(|source| log_error(path, source))
}

fn log_error(path: &Path, source: csv::Error) -> TrainError {
    TrainError::Log {
        file: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("talkin_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn entry(step: usize) -> StepLog {
        StepLog {
            step,
            seconds: step as f64 * 0.1,
            loss: 0.5,
            mse: 0.25,
            psnr: 6.0,
            rays: 8,
            samples: 80,
            rays_per_s: 80.0,
            samples_per_s: 800.0,
            lr: 1e-2,
            progress: 0.5,
            grid_occupied: 1.0,
            sampling_s: 0.01,
            bones_per_sample: 2.5,
        }
    }

    /// Resuming keeps the rows up to the checkpoint's step, and rows of a log written
    /// before the last column was added get it empty, so every row has the header's
    /// columns. A row cut off by a kill mid-write (past the checkpoint) goes too, even
    /// when what is left of it reads as an earlier step ("1" of "12,...").
    #[test]
    fn resumed_log_keeps_rows_up_to_the_step_with_every_column() {
        let dir = temp("open_log");
        let path = dir.join(LOG_FILE);
        let old_header = LOG_HEADER.rsplit_once(',').unwrap().0;
        std::fs::write(
            &path,
            format!(
                "{old_header}\n1,0.1,1,1,1,8,8,1,1,1e-2,1\n2,0.2,1,1,1,8,8,1,1,1e-2,1\n\
                 3,0.3,1,1,1,8,8,1,1,1e-2,1\n4,0.4,1\n1"
            ),
        )
        .unwrap();
        drop(TrainLog::open(&path, Some(2)).unwrap());
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let columns = LOG_HEADER.split(',').count();
        assert_eq!(lines[0], LOG_HEADER);
        assert_eq!(lines.len(), 3, "{text}");
        assert!(
            lines.iter().all(|l| l.split(',').count() == columns),
            "{text}"
        );
        // The row had 11 values; every later column is left empty.
        let padding = ",".repeat(columns - 11);
        assert_eq!(lines[2], format!("2,0.2,1,1,1,8,8,1,1,1e-2,1{padding}"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Rows written, synced and read back by a resume: the same text, one row per step,
    /// and new rows append after the kept ones. A missing log resumes as a fresh one.
    #[test]
    fn rows_round_trip_through_a_resume() {
        let dir = temp("log_round_trip");
        let path = dir.join(LOG_FILE);
        let mut log = TrainLog::open(&path, None).unwrap();
        for step in 1..=3 {
            log.write(&entry(step)).unwrap();
        }
        log.sync().unwrap();
        let written = std::fs::read_to_string(&path).unwrap();
        assert_eq!(written.lines().count(), 4, "{written}");
        assert_eq!(
            written.lines().nth(1).unwrap(),
            "1,0.100,0.5,0.25,6,8,80,80.0,800.0,1e-2,1.0000,0.010000,2.500"
        );
        drop(log);
        let mut log = TrainLog::open(&path, Some(2)).unwrap();
        log.write(&entry(3)).unwrap();
        log.flush().unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), written);
        std::fs::remove_file(&path).unwrap();
        drop(TrainLog::open(&path, Some(2)).unwrap());
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            format!("{LOG_HEADER}\n")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
