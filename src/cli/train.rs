use std::path::PathBuf;

use anyhow::Context;
use talkin_engine::dataset::Dataset;
use talkin_engine::train::{self, SamplerKind, TrainOptions};

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Dataset directory (with dataset.json).
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory: train_log.csv and checkpoint/ are written there.
    #[arg(long, default_value = "out/train")]
    pub out: PathBuf,
    /// Field preset: `fast` (hash grid, small MLPs) or `paper` (8x256 MLPs).
    #[arg(long, default_value = "fast", value_parser = ["fast", "paper"])]
    pub preset: String,
    /// Sampler: `accelerated` (capsule BVH + occupancy grid) or `dense` (128 per ray).
    #[arg(long, default_value = "accelerated", value_parser = ["accelerated", "dense"])]
    pub sampler: String,
    /// Optimizer steps.
    #[arg(long, default_value_t = TrainOptions::default().steps)]
    pub steps: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Random pixel rays per step.
    #[arg(long, default_value_t = TrainOptions::default().batch_rays)]
    pub batch: usize,
    /// Add the perceptual loss on a 32x32 patch per step (weight 1, MSE weight 0.2):
    /// LPIPS with the AlexNet weights in this directory, 1 - SSIM when they are absent.
    #[arg(long)]
    pub perceptual: Option<PathBuf>,
    /// Initial Adam learning rate (decays to 0.1x of it over the run).
    #[arg(long, default_value_t = TrainOptions::default().lr)]
    pub lr: f64,
    /// Occupancy-grid update period in steps (0: never; accelerated sampler only).
    #[arg(long, default_value_t = TrainOptions::default().occ_every)]
    pub occ_every: u32,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)
        .with_context(|| format!("cannot load the dataset in {}", args.data.display()))?;
    let opts = TrainOptions {
        preset: args.preset.clone(),
        sampler: args
            .sampler
            .parse::<SamplerKind>()
            .with_context(|| format!("unknown sampler `{}`", args.sampler))?,
        steps: args.steps,
        seed: args.seed,
        batch_rays: args.batch,
        occ_every: args.occ_every,
        lr: args.lr,
        perceptual: args.perceptual.clone(),
        ..TrainOptions::default()
    };
    let progress = Progress::new("train steps", opts.steps);
    let report = train::train(&dataset, &args.out, &opts, &mut |log, _total| {
        progress.update(
            log.step,
            &format!(
                "loss {:.4} psnr {:.2} dB, {:.0} rays/s, {:.0} samples/s",
                log.loss, log.psnr, log.rays_per_s, log.samples_per_s
            ),
        )
    })
    .with_context(|| format!("training on {}", args.data.display()))?;
    if let Some(note) = &report.perceptual_note {
        eprintln!("note: {note}");
    }
    let n = report.logs.len();
    let tail = &report.logs[n.saturating_sub(10)..];
    let mean = |f: &dyn Fn(&train::StepLog) -> f64| {
        tail.iter().map(f).sum::<f64>() / tail.len().max(1) as f64
    };
    println!(
        "trained {} steps ({} sampler, {} preset) in {:.1} s: {:.2} steps/s; last {} steps: \
         loss {:.4}, psnr {:.2} dB, {:.0} rays/s, {:.0} samples/s",
        n,
        opts.sampler.name(),
        opts.preset,
        report.seconds,
        n as f64 / report.seconds.max(1e-9),
        tail.len(),
        mean(&|l| f64::from(l.loss)),
        mean(&|l| f64::from(l.psnr)),
        mean(&|l| l.rays_per_s),
        mean(&|l| l.samples_per_s),
    );
    println!(
        "log: {}\ncheckpoint: {}",
        report.log_file.display(),
        report.checkpoint.dir.display()
    );
    Ok(())
}
