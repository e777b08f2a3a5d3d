//! Steps whose losses are still on the device. A GPU step leaves its loss and MSE there
//! ([`LossValues::Queued`](crate::loss::LossValues)), and the trainer reads
//! [`READ_EVERY`] steps' values in one transfer: a read waits for all the work queued
//! before it, so reading each step's own loss would make the host wait for the GPU every
//! step instead of queueing the next one meanwhile.

use std::time::Instant;

use burn::prelude::*;

use crate::error::TrainError;
use crate::step_log::StepLog;

/// Steps between two reads of the queued losses on a GPU.
pub(crate) const READ_EVERY: usize = 16;

/// One queued step: its log entry (loss, MSE and PSNR still unknown), the host seconds
/// it took to queue, and its `[loss, mse]` on the device.
struct Queued {
    entry: StepLog,
    secs: f64,
    values: Tensor<1>,
}

/// The queued steps, oldest first.
#[derive(Default)]
pub(crate) struct PendingLosses {
    queued: Vec<Queued>,
}

impl PendingLosses {
    /// Queues a step that took `secs` of host time (its entry's `seconds` at its end).
    pub fn push(&mut self, entry: StepLog, secs: f64, values: Tensor<1>) {
        self.queued.push(Queued {
            entry,
            secs,
            values,
        });
    }

    pub fn len(&self) -> usize {
        self.queued.len()
    }

    /// Reads every queued step's values in one transfer and completes their entries.
    /// Each step's host time says only how long queueing its work took, so the group's
    /// time (the queueing and the wait for the read) is spread evenly over its steps.
    /// Returns the entries and the seconds the read waited; an error names the first
    /// step whose loss is not finite.
    pub fn read(&mut self) -> Result<(Vec<StepLog>, f64), TrainError> {
        if self.queued.is_empty() {
            return Ok((Vec::new(), 0.0));
        }
        let start = Instant::now();
        let queued = std::mem::take(&mut self.queued);
        let n = queued.len();
        let queued_s: f64 = queued.iter().map(|q| q.secs).sum();
        let first_start = queued[0].entry.seconds - queued[0].secs;
        let (mut entries, values): (Vec<StepLog>, Vec<Tensor<1>>) =
            queued.into_iter().map(|q| (q.entry, q.values)).unzip();
        let read = talkin_nets::read_floats(Tensor::cat(values, 0));
        let waited = start.elapsed().as_secs_f64();
        let values = match read {
            Ok(v) if v.len() == 2 * n => v,
            other => {
                return Err(TrainError::Readback {
                    first: entries[0].step,
                    last: entries[n - 1].step,
                    problem: match other {
                        Ok(v) => format!("{} values for {n} steps", v.len()),
                        Err(e) => format!("{e:?}"),
                    },
                });
            }
        };
        let per_step = ((queued_s + waited) / n as f64).max(1e-9);
        for (i, entry) in entries.iter_mut().enumerate() {
            let (loss, mse) = (values[2 * i], values[2 * i + 1]);
            if !loss.is_finite() {
                return Err(TrainError::NonFinite {
                    step: entry.step,
                    loss,
                });
            }
            entry.loss = loss;
            entry.mse = mse;
            entry.psnr = psnr(mse);
            entry.seconds = first_start + (i + 1) as f64 * per_step;
            entry.rays_per_s = entry.rays as f64 / per_step;
            entry.samples_per_s = entry.samples as f64 / per_step;
        }
        Ok((entries, waited))
    }
}

/// The batch PSNR of an MSE of colours in [0, 1].
pub(crate) fn psnr(mse: f32) -> f32 {
    -10.0 * mse.max(1e-10).log10()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Step `step`'s entry as queued: `secs` of host time ending at `seconds`.
    fn queued(step: usize, seconds: f64, secs: f64) -> StepLog {
        StepLog {
            step,
            seconds,
            loss: f32::NAN,
            mse: f32::NAN,
            psnr: f32::NAN,
            rays: 100,
            samples: 1000,
            rays_per_s: 100.0 / secs,
            samples_per_s: 1000.0 / secs,
            lr: 1e-3,
            progress: 0.5,
            grid_occupied: 1.0,
            sampling_s: 0.0,
            bones_per_sample: 3.0,
        }
    }

    fn values(loss: f32, mse: f32) -> Tensor<1> {
        Tensor::from_floats([loss, mse], &Device::flex())
    }

    #[test]
    fn a_read_completes_every_queued_step_and_spreads_their_time() {
        let mut pending = PendingLosses::default();
        // Three steps queued in 1 + 1 + 2 s of host time, from 10 s on.
        pending.push(queued(5, 11.0, 1.0), 1.0, values(0.5, 0.01));
        pending.push(queued(6, 12.0, 1.0), 1.0, values(0.4, 0.001));
        pending.push(queued(7, 14.0, 2.0), 2.0, values(0.3, 0.0001));
        let (entries, waited) = pending.read().unwrap();
        assert_eq!(pending.len(), 0);
        let steps: Vec<usize> = entries.iter().map(|e| e.step).collect();
        assert_eq!(steps, [5, 6, 7]);
        assert_eq!(
            entries.iter().map(|e| e.loss).collect::<Vec<_>>(),
            [0.5, 0.4, 0.3]
        );
        for (e, want) in entries.iter().zip([20.0f32, 30.0, 40.0]) {
            assert!((e.psnr - want).abs() < 1e-4, "{} vs {want}", e.psnr);
        }
        // 4 s of queueing (and the read's wait) over three steps, from 10 s.
        let per_step = (4.0 + waited) / 3.0;
        for (i, e) in entries.iter().enumerate() {
            assert!((e.seconds - (10.0 + (i + 1) as f64 * per_step)).abs() < 1e-9);
            assert!((e.rays_per_s - 100.0 / per_step).abs() < 1e-6);
        }
        assert!(pending.read().unwrap().0.is_empty());
    }

    #[test]
    fn a_non_finite_loss_names_its_step() {
        let mut pending = PendingLosses::default();
        pending.push(queued(1, 1.0, 1.0), 1.0, values(0.5, 0.01));
        pending.push(queued(2, 2.0, 1.0), 1.0, values(f32::NAN, 0.01));
        pending.push(queued(3, 3.0, 1.0), 1.0, values(f32::INFINITY, 0.01));
        match pending.read() {
            Err(TrainError::NonFinite { step: 2, loss }) => assert!(loss.is_nan()),
            other => panic!("{:?}", other.map(|(e, _)| e)),
        }
    }
}
