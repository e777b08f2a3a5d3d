use std::path::PathBuf;

use anyhow::Context;
use talkin_engine::dataset::Dataset;
use talkin_engine::sampling;

use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub which: BenchCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Dense (128 stratified samples in the posed box) against accelerated (capsule BVH +
    /// canonical occupancy grid) sampling over every frame: samples per foreground ray,
    /// rays per second, and surface points the accelerated samples miss.
    Sampling(SamplingArgs),
    /// Accelerated against dense training for the same wall-clock budgets in one run:
    /// PSNR/SSIM/LPIPS on test_same at every budget, a CSV, a plot and
    /// `speedup_to_dense_final_psnr`.
    SpeedVsError(SpeedVsErrorArgs),
    /// The paper's ablations (w/o D_hands, w/o background, w/o jaw in e, single- vs
    /// multi-identity), each trained for the same budget and scored on held-out frames.
    Ablations(AblationArgs),
}

#[derive(clap::Args, Debug)]
pub struct AblationArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: ablations.md, ablations.json, runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// Training minutes per model.
    #[arg(long = "minutes-each", default_value_t = 3.0)]
    pub minutes_each: f64,
    /// Frames per evaluated split, evenly spaced (0: all).
    #[arg(long, default_value_t = 6)]
    pub eval_frames: usize,
    #[command(flatten)]
    pub recipe: super::train::RecipeArgs,
}

#[derive(clap::Args, Debug)]
pub struct SpeedVsErrorArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: speed_vs_error.csv, speed_vs_error.png, summary.json, runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// Training budgets in seconds, ascending.
    #[arg(long, default_value = "30,60,120,240", value_delimiter = ',')]
    pub budgets: Vec<f64>,
    /// test_same frames evaluated at every mark, evenly spaced (0: all).
    #[arg(long, default_value_t = 6)]
    pub eval_frames: usize,
    #[command(flatten)]
    pub recipe: super::train::RecipeArgs,
}

#[derive(clap::Args, Debug)]
pub struct SamplingArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Also write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.which {
        BenchCommand::Sampling(a) => sampling_bench(a),
        BenchCommand::SpeedVsError(a) => speed_vs_error_bench(a),
        BenchCommand::Ablations(a) => ablations_bench(a),
    }
}

fn sampling_bench(args: SamplingArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)?;
    let mut progress: Option<Progress> = None;
    let report = sampling::bench_sampling(&dataset, &mut |done, total| {
        progress
            .get_or_insert_with(|| Progress::new("sampling frames", total))
            .update(done, "")
    })?;
    println!("{}", sampling::format_report(&report));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("report: {}", path.display());
    }
    Ok(())
}

fn speed_vs_error_bench(args: SpeedVsErrorArgs) -> anyhow::Result<()> {
    use talkin_engine::speed_vs_error::{SpeedVsErrorOptions, format_summary, speed_vs_error};
    let dataset = Dataset::load(&args.data)?;
    let train = args.recipe.options()?;
    let lpips_dir = Some(args.recipe.lpips_dir.clone());
    let opts = SpeedVsErrorOptions {
        budgets: args.budgets.clone(),
        eval_frames: args.eval_frames,
        train,
        lpips_dir,
    };
    let summary = speed_vs_error(&dataset, &args.out, &opts, &mut |msg| eprintln!("{msg}"))
        .with_context(|| format!("speed-vs-error benchmark on {}", args.data.display()))?;
    println!("{}", format_summary(&summary));
    println!(
        "report: {}/{{speed_vs_error.csv, speed_vs_error.png, summary.json}}",
        args.out.display()
    );
    Ok(())
}

fn ablations_bench(args: AblationArgs) -> anyhow::Result<()> {
    use talkin_engine::ablations::{AblationOptions, ablations, format_table};
    let dataset = Dataset::load(&args.data)?;
    let opts = AblationOptions {
        budget_s: args.minutes_each * 60.0,
        eval_frames: args.eval_frames,
        train: args.recipe.options()?,
        lpips_dir: Some(args.recipe.lpips_dir.clone()),
    };
    let rows = ablations(&dataset, &args.out, &opts, &mut |msg| eprintln!("{msg}"))
        .with_context(|| format!("ablations on {}", args.data.display()))?;
    println!("{}", format_table(&rows));
    println!("report: {}/ablations.md", args.out.display());
    Ok(())
}
