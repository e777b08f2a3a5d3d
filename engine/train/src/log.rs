//! `RUN/train_log.csv`: one row per step, readable while the run goes on.

use std::io::Write;
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

/// The open log of a run.
pub(crate) struct TrainLog {
    path: PathBuf,
    file: std::io::BufWriter<std::fs::File>,
}

impl TrainLog {
    /// Opens the log: fresh with a header, or (resuming at `step`) keeping the header
    /// and the rows of steps up to `step` (a killed run may have logged steps past its
    /// last checkpoint). Rows of a log written before a column was added get it empty.
    pub fn open(path: &Path, resume_at: Option<usize>) -> Result<TrainLog, TrainError> {
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
        Ok(TrainLog {
            path: path.to_path_buf(),
            file,
        })
    }

    /// Appends `entry`; flushes every 25 steps, so `tail -f` follows the run without a
    /// syscall per step.
    pub fn write(&mut self, entry: &StepLog) -> Result<(), TrainError> {
        writeln!(
            self.file,
            "{},{:.3},{},{},{},{},{},{:.1},{:.1},{:e},{:.4},{:.6},{:.3}",
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
            entry.sampling_s,
            entry.bones_per_sample
        )
        .map_err(|source| self.io(source))?;
        if entry.step.is_multiple_of(25) {
            self.flush()?;
        }
        Ok(())
    }

    pub fn flush(&mut self) -> Result<(), TrainError> {
        self.file.flush().map_err(|source| self.io(source))
    }

    fn io(&self, source: std::io::Error) -> TrainError {
        TrainError::Io {
            file: self.path.clone(),
            source,
        }
    }
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
}
