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
