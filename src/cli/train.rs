use std::path::PathBuf;

use anyhow::Context;
use talkin_data::dataset::Dataset;
use talkin_train::{Budget, SamplerKind, StepLog, TrainOptions, Trainer};

use crate::progress::Progress;

/// Where `scripts/lpips_weights.py` puts the converted LPIPS weights.
pub const DEFAULT_LPIPS_DIR: &str = "assets/lpips";

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
    /// Train on each subject's first S seconds of training frames only (a short clip: the
    /// novel-identity experiment's from-scratch baseline).
    #[arg(long)]
    pub seconds_of_video: Option<f64>,
    #[command(flatten)]
    pub recipe: RecipeArgs,
}

/// The options shared by `train` and `adapt`.
#[derive(clap::Args, Debug, Clone)]
pub struct RecipeArgs {
    /// Field preset: `fast` (hash grid, small MLPs) or `paper` (8x256 MLPs).
    #[arg(long, default_value = "fast", value_parser = ["fast", "paper"])]
    pub preset: String,
    /// Sampler: `accelerated` (capsule BVH + occupancy grid) or `dense` (128 per ray).
    #[arg(long, default_value = "accelerated", value_parser = ["accelerated", "dense"])]
    pub sampler: String,
    /// Optimizer steps (default 1000 unless --minutes is given).
    #[arg(long, conflicts_with = "minutes")]
    pub steps: Option<usize>,
    /// Train for this many minutes of wall-clock time instead of a step count.
    #[arg(long)]
    pub minutes: Option<f64>,
    /// Subjects to train on: `all` or a comma-separated list of names.
    #[arg(long, default_value = "all")]
    pub identities: String,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Random pixel rays per step (besides the LPIPS patches).
    #[arg(long, default_value_t = TrainOptions::default().batch_rays)]
    pub batch: usize,
    /// 32x32 LPIPS patches per step (the paper: 6; 0 turns the perceptual term off).
    #[arg(long, default_value_t = TrainOptions::default().patches)]
    pub patches: usize,
    /// Directory of the converted LPIPS weights (`python3 scripts/lpips_weights.py`);
    /// without them the perceptual term is 1 - SSIM, and the run says so.
    #[arg(long, default_value = DEFAULT_LPIPS_DIR)]
    pub lpips_dir: PathBuf,
    /// Initial Adam learning rate (default: the preset's; decays x0.1 per 500k of the
    /// paper's iterations, onto which every run is mapped).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Weight of the silhouette term (rendered opacity against the mask, mean squared
    /// error); 0: off, the paper's loss.
    #[arg(long, default_value_t = TrainOptions::default().mask_weight)]
    pub mask_weight: f32,
    /// Occupancy-grid update period in steps (0: never; accelerated sampler only).
    #[arg(long, default_value_t = TrainOptions::default().occ_every)]
    pub occ_every: u32,
    /// Checkpoint every this many seconds (and at the end).
    #[arg(long, default_value_t = TrainOptions::default().checkpoint_every_s)]
    pub checkpoint_every: f64,
}

impl RecipeArgs {
    pub fn options(&self) -> anyhow::Result<TrainOptions> {
        let budget = match (self.steps, self.minutes) {
            (_, Some(m)) => Budget::Seconds(m * 60.0),
            (Some(s), None) => Budget::Steps(s),
            (None, None) => TrainOptions::default().budget,
        };
        let identities = match self.identities.trim() {
            "all" => None,
            list => Some(
                list.split(',')
                    .map(|s| s.trim().to_string())
                    .filter(|s| !s.is_empty())
                    .collect(),
            ),
        };
        Ok(TrainOptions {
            preset: self.preset.clone(),
            sampler: self
                .sampler
                .parse::<SamplerKind>()
                .with_context(|| format!("unknown sampler `{}`", self.sampler))?,
            budget,
            seed: self.seed,
            identities,
            batch_rays: self.batch,
            patches: self.patches,
            lr: self.lr,
            occ_every: self.occ_every,
            mask_weight: self.mask_weight,
            perceptual: (self.patches > 0).then(|| self.lpips_dir.clone()),
            checkpoint_every_s: self.checkpoint_every,
            ..TrainOptions::default()
        })
    }
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)
        .with_context(|| format!("cannot load the dataset in {}", args.data.display()))?;
    let trainer = if args.resume {
        Trainer::resume(&dataset, &args.out)
            .with_context(|| format!("resuming {}", args.out.display()))?
    } else {
        let opts = TrainOptions {
            clip_seconds: args.seconds_of_video,
            ..args.recipe.options()?
        };
        Trainer::new(&dataset, &args.out, &opts)
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
