use std::path::PathBuf;

use anyhow::Context;
use talkin_data::dataset::Dataset;
pub use talkin_train::DEFAULT_LPIPS_DIR;
use talkin_train::{StepLog, TrainOptions, Trainer};

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Dataset directory (with dataset.json).
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory: recipe.json, train_log.csv and checkpoint/ are written there.
    #[arg(long, default_value = "out/train")]
    pub out: PathBuf,
    /// Continue the run in --out from its newest checkpoint (same options; the budget
    /// options given here are ignored).
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)
        .with_context(|| format!("cannot load the dataset in {}", args.data.display()))?;
    let trainer = if args.resume {
        Trainer::resume(&dataset, &args.out)
            .with_context(|| format!("resuming {}", args.out.display()))?
    } else {
        Trainer::new(&dataset, &args.out, &args.recipe)
            .with_context(|| format!("training on {}", args.data.display()))?
    };
    run_trainer(trainer, &args.data)
}

/// Runs a trainer to the end with a progress line and prints a summary.
pub fn run_trainer(trainer: Trainer, data: &std::path::Path) -> anyhow::Result<()> {
    if let Some(note) = trainer.perceptual_note() {
        eprintln!("note: {note}");
    }
    let opts = trainer.options().clone();
    let progress = Progress::new("training (per mille)", 1000);
    let report = trainer
        .run(&mut |log: &StepLog| {
            progress.update(
                (log.progress * 1000.0).floor() as usize,
                &format!(
                    "step {} loss {:.4} psnr {:.2} dB, {:.0} rays/s",
                    log.step, log.loss, log.psnr, log.rays_per_s
                ),
            )
        })
        .with_context(|| format!("training on {}", data.display()))?;
    let n = report.logs.len();
    if n == 0 {
        // A resumed run whose budget was already spent: no step to average.
        println!("trained 0 steps: the run's budget was already spent");
    } else {
        let tail = &report.logs[n.saturating_sub(20)..];
        let mean =
            |f: &dyn Fn(&StepLog) -> f64| tail.iter().map(f).sum::<f64>() / tail.len() as f64;
        let sampling_s: f64 = report.logs.iter().map(|l| l.sampling_s).sum();
        println!(
            "trained {} steps ({} sampler, {} preset) in {:.1} s: {:.2} steps/s, {:.1}% of \
             it drawing samples; last {} steps: loss {:.4}, batch psnr {:.2} dB, {:.0} \
             rays/s, {:.0} samples/s",
            n,
            opts.sampler.name(),
            opts.preset,
            report.seconds,
            n as f64 / report.seconds.max(1e-9),
            100.0 * sampling_s / report.seconds.max(1e-9),
            tail.len(),
            mean(&|l| f64::from(l.loss)),
            mean(&|l| f64::from(l.psnr)),
            mean(&|l| l.rays_per_s),
            mean(&|l| l.samples_per_s),
        );
    }
    println!(
        "log: {}\ncheckpoint: {}",
        report.log_file.display(),
        report.checkpoint.display()
    );
    Ok(())
}
