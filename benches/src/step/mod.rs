//! The step's roofline: where a training step's time goes, stage by stage, what each
//! stage's work is (floating-point operations and bytes a sample, counted by the fused
//! kernels themselves) and how close it runs to this machine's own ceilings, measured in
//! the same run ([`peaks`]).
//!
//! The steps are the trainer's own (`Trainer::step`), of a trained run read without
//! writing to it (its occupancy grid and routing as trained: the samples a ray a user's
//! step takes), or of a fresh field after a warm-up. Stages are timed by
//! `talkin_nets::profile`: the stages of the whole step on the thread that runs it
//! ("wall"), and the field's work inside the batch's chunks that run at once as rayon
//! tasks ("thread" seconds: they add up to about twice the field's wall). A kernel's
//! ideal time is its work at the machine's ceilings (the slowest of compute, streamed
//! bytes and gathered rows); its efficiency is that against its time, its thread seconds
//! divided by how many threads ran field work at once.

pub mod peaks;
mod table;

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use talkin_data::dataset::Dataset;
use talkin_nets::encoding::EncodingConfig;
use talkin_nets::{ComputeDevice, FieldConfig, profile};
use talkin_train::{Budget, RunWriter, TrainOptions, Trainer};

pub use peaks::Peaks;
pub use table::table;

use crate::error::BenchError;

/// What to measure.
#[derive(Clone, Debug)]
pub struct StepBenchOptions {
    /// A trained run to step on from its newest checkpoint (read, never written); `None`:
    /// a fresh field from `train`.
    pub run: Option<PathBuf>,
    /// Untimed steps first (allocator and caches warm; a fresh field's first grid marks).
    pub warmup: usize,
    /// Timed steps.
    pub steps: usize,
    /// A fresh field's recipe (ignored with `run`: the run's own).
    pub train: TrainOptions,
}

/// A stage of the whole step, timed on the thread that runs the step.
#[derive(Clone, Debug, Serialize)]
pub struct WallRow {
    pub stage: String,
    pub ms_per_step: f64,
    /// Of the step's wall time.
    pub share: f64,
}

/// A stage of the field's work (or a kernel), with what it computes where counted.
#[derive(Clone, Debug, Serialize)]
pub struct WorkRow {
    pub stage: String,
    /// Thread seconds a step, in ms.
    pub thread_ms_per_step: f64,
    /// Of the field work's thread seconds (Adam: of the step's wall).
    pub share: f64,
    pub calls_per_step: f64,
    /// Counted work a sample (zero where the stage does not count it).
    pub flops_per_sample: f64,
    pub bytes_per_sample: f64,
    /// Of `bytes_per_sample`, read or written at random rows.
    pub gathered_per_sample: f64,
    /// Achieved over the stage's time (its thread seconds over the threads at work).
    pub gflops: f64,
    pub gbs: f64,
    /// The counted work at the machine's ceilings, ms a step (0: nothing counted).
    pub ideal_ms_per_step: f64,
    /// `ideal / time`: 1 at the roofline.
    pub efficiency: f64,
    /// Which ceiling the ideal time is set by: `compute`, `stream`, `gather`, or `-`.
    pub bound: String,
}

/// The bench's report.
#[derive(Clone, Debug, Serialize)]
pub struct StepReport {
    /// What stepped: a run and its step, or a fresh field after its warm-up.
    pub source: String,
    pub warmup: usize,
    pub steps: usize,
    pub rays_per_step: f64,
    pub samples_per_step: f64,
    pub samples_per_ray: f64,
    /// The timed steps' mean.
    pub step_ms: f64,
    pub steps_per_s: f64,
    pub samples_per_s: f64,
    /// Threads at field work at once: the chunks' thread seconds over the field's wall.
    pub field_threads: f64,
    pub peaks: Peaks,
    pub wall: Vec<WallRow>,
    pub work: Vec<WorkRow>,
    /// The counted kernels' ideal time a step against the step's time.
    pub counted_ideal_ms: f64,
}

/// Turns recording off however the timed steps end.
struct Recording;

impl Recording {
    fn start() -> Recording {
        let _ = profile::take();
        profile::set_enabled(true);
        Recording
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        profile::set_enabled(false);
    }
}

/// Steps and measures as [`StepBenchOptions`] says; a fresh field trains in `work/run`.
pub fn run(
    dataset: &Dataset,
    work: &Path,
    opts: &StepBenchOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<StepReport, BenchError> {
    if opts.steps == 0 {
        return Err(BenchError::bad("--timed-steps", "must be at least 1"));
    }
    let mut trainer = match &opts.run {
        Some(run) => Trainer::resume_as(dataset, run, ComputeDevice::Cpu, RunWriter::ReadsOnly)?,
        None => {
            let train = TrainOptions {
                budget: Budget::Steps(opts.warmup + opts.steps),
                checkpoint_every_s: f64::MAX,
                ..opts.train.clone()
            };
            let run = work.join("run");
            let _ = std::fs::remove_dir_all(&run);
            Trainer::new(dataset, &run, &train)?
        }
    };
    let source = match &opts.run {
        Some(run) => format!("{} at step {}", run.display(), trainer.steps_taken()),
        None => format!("a fresh field after {} steps", opts.warmup),
    };
    progress(&format!("{source}: {} warm-up steps", opts.warmup));
    for _ in 0..opts.warmup {
        trainer.step()?;
    }
    trainer.settle()?;
    progress(&format!("{} timed steps", opts.steps));
    let recording = Recording::start();
    let start = Instant::now();
    let mut logs = Vec::with_capacity(opts.steps);
    for _ in 0..opts.steps {
        logs.extend(trainer.step()?);
    }
    logs.extend(trainer.settle()?);
    let wall_s = start.elapsed().as_secs_f64().max(1e-12);
    drop(recording);
    let totals = profile::take();
    progress("the machine's ceilings");
    let peaks = peaks::measure(level_floats(trainer.config()));

    let steps = opts.steps as f64;
    let rays = logs.iter().map(|l| l.rays as f64).sum::<f64>() / steps;
    let samples = logs.iter().map(|l| l.samples as f64).sum::<f64>() / steps;
    Ok(report::build(
        report::Measured {
            source,
            warmup: opts.warmup,
            steps: opts.steps,
            rays_per_step: rays,
            samples_per_step: samples,
            wall_s,
        },
        &totals,
        peaks,
    ))
}

mod report;

/// Floats of one hashed level of the field's grid (a frequency encoding gathers
/// nothing: the probe then reads a 2^19-row table, instant-ngp's).
fn level_floats(config: &FieldConfig) -> usize {
    match &config.encoding {
        EncodingConfig::HashGrid(h) => (1usize << h.log2_hashmap_size) * h.n_features_per_level,
        EncodingConfig::Frequency(_) => (1 << 19) * 2,
    }
}
