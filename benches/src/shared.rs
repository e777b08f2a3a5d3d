//! What the training benchmarks (speed-vs-error, ablations, novel identity) share:
//! training a run to the end of its budget, the avatar of a run in progress, the scores a
//! table row reports, evenly spaced evaluation frames, and writing a report's JSON and
//! Markdown.

use std::path::Path;

use serde::Serialize;

use crate::error::BenchError;
use talkin_avatar::Avatar;
use talkin_data::dataset::Dataset;
use talkin_render::eval::EvalReport;
use talkin_train::{TrainOptions, Trainer};

/// The field of a run in progress as it is now, ready to render (the benchmarks'
/// evaluations during a run): the avatar a checkpoint of it would load.
pub fn avatar_of(trainer: &Trainer) -> Avatar {
    Avatar {
        field: trainer.inference_field(),
        config: trainer.config().clone(),
        background: trainer.background(),
        subjects: trainer.subjects().to_vec(),
        sampler: trainer.options().sampler,
        field_step: trainer.field_step(),
        refined: trainer.refined_fits(),
    }
}

/// Trains `opts` to the end of its budget and saves the final checkpoint.
pub fn train_to_end<'a>(
    dataset: &'a Dataset,
    run: &Path,
    opts: &TrainOptions,
) -> Result<Trainer<'a>, BenchError> {
    finish(Trainer::new(dataset, run, opts)?)
}

/// Steps `trainer` to the end of its budget and saves the final checkpoint.
pub fn finish(mut trainer: Trainer<'_>) -> Result<Trainer<'_>, BenchError> {
    while !trainer.done() {
        trainer.step()?;
    }
    trainer.save()?;
    Ok(trainer)
}

/// The averages a row reports.
#[derive(Clone, Debug, Serialize)]
pub struct Scores {
    pub psnr: f64,
    pub ssim: f64,
    /// x1000.
    pub lpips: Option<f64>,
    pub psnr_person: Option<f64>,
    pub psnr_face: Option<f64>,
    pub psnr_hands: Option<f64>,
}

impl Scores {
    pub fn of(r: &EvalReport) -> Scores {
        Scores {
            psnr: r.psnr,
            ssim: r.ssim,
            lpips: r.lpips,
            psnr_person: r.psnr_person,
            psnr_face: r.psnr_face,
            psnr_hands: r.psnr_hands,
        }
    }
}

/// `count` of `frames`, evenly spaced (all when `count` is 0 or too large).
pub fn thin(frames: &[usize], count: usize) -> Vec<usize> {
    if count == 0 || count >= frames.len() {
        return frames.to_vec();
    }
    (0..count)
        .map(|k| frames[k * frames.len() / count])
        .collect()
}

/// Writes a benchmark's `out/<name>.json` and `out/<name>.md`, each atomically.
pub fn write_report(out: &Path, name: &str, json: &[u8], table: &str) -> Result<(), BenchError> {
    std::fs::create_dir_all(out).map_err(|source| BenchError::Io {
        file: out.to_path_buf(),
        source,
    })?;
    for (ext, bytes) in [("json", json), ("md", table.as_bytes())] {
        let file = out.join(format!("{name}.{ext}"));
        talkin_data::atomic::write_atomic(&file, bytes)
            .map_err(|source| BenchError::Io { file, source })?;
    }
    Ok(())
}
