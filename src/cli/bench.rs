use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::builder::TypedValueParser;
use talkin_benches::sampling;
use talkin_data::dataset::Dataset;
use talkin_serve::{Server, bench};
use talkin_train::TrainOptions;

use super::serve::LimitArgs;
use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub which: BenchCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Dense (128 stratified samples in the posed box) against accelerated (exact capsule
    /// intervals + canonical occupancy grid) sampling over every frame: samples per foreground ray,
    /// rays per second, and surface points the accelerated samples miss.
    Sampling(SamplingArgs),
    /// Time to quality: for target PSNRs on test_same, the training seconds and steps the
    /// accelerated and the dense sampler (HumanNeRF's, at its own best learning rate) each
    /// need to reach each target, the speed-up at each and where it comes from.
    SpeedVsError(SpeedVsErrorArgs),
    /// The paper's ablations (w/o D_hands, w/o background, w/o jaw in e, single- vs
    /// multi-identity), each trained for the same budget and scored on held-out frames.
    Ablations(AblationArgs),
    /// The paper's novel-identity experiment: a multi-identity model trained without one
    /// subject, adapted to it from the first 1, 3, 10 and 30 s of its video, each scored on
    /// the same held-out frames of that subject.
    NovelIdentity(NovelIdentityArgs),
    /// The render server under load: an in-process server on a free port (`--run`) or any
    /// running endpoint (`--target`, e.g. a load balancer), closed-loop clients posting one
    /// frame each; throughput and p50/p99 latency per client count.
    Serve(ServeBenchArgs),
    /// Per device and preset, in one run: training steps/s and samples/s (and the host
    /// sampler's share of a step), render fps at 540x540, and peak memory.
    Device(DeviceBenchArgs),
    /// Pose refinement against noisy fits: per noise level, seeded noise on the training
    /// fits, training with and without `--refine-poses` for the same budget, test_same
    /// scores and the fits' joint error before and after refinement.
    NoisyFits(NoisyFitsArgs),
    /// Quality against budget: the plain recipe (as `talkin train` would build it on the
    /// dataset, flags given here included) trained once per budget and seed, each run
    /// scored on its held-out and training frames by the anchors' protocol and by how
    /// thick the person renders; a table and a plot.
    Convergence(ConvergenceArgs),
    /// The step's roofline: each stage of a training step timed (rays, sampling, the
    /// field's forward and its parts, render, loss, backward, Adam, the grid update), the
    /// fused kernels' FLOPs and bytes a sample, and how close each runs to this machine's
    /// matrix-product, gather and memory ceilings, measured in the same run.
    Step(StepBenchArgs),
}

#[derive(clap::Args, Debug)]
pub struct StepBenchArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: step.json and step.md (and a fresh field's scratch run).
    #[arg(long)]
    pub out: PathBuf,
    /// A trained run (on `--data`) to step on from its newest checkpoint, read and never
    /// written: its grid and routing as trained, the samples a ray its steps take. Without
    /// it, a fresh field as `talkin train` builds it (flags below).
    #[arg(long, value_name = "RUN")]
    pub run: Option<PathBuf>,
    /// Untimed steps first. A frame's first visit decodes its images and builds its
    /// sampler: give enough for the run's frames to be visited (a few times their count).
    #[arg(long, default_value_t = 100)]
    pub warmup: usize,
    /// Timed steps.
    #[arg(long = "timed-steps", value_name = "N", default_value_t = 100)]
    pub timed_steps: usize,
    /// Read before `recipe`, whose parser takes its values out of the matches.
    #[command(flatten)]
    pub given: super::train::GivenFlags,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct ConvergenceArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: convergence.json, convergence.md, convergence.png, runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// Training steps of each run, comma-separated (each run has its own schedule).
    #[arg(long, value_delimiter = ',', default_value = "3000,9000,36000")]
    pub budgets: Vec<usize>,
    /// Seeds, comma-separated: every budget trains once per seed.
    #[arg(long, value_delimiter = ',', default_value = "0")]
    pub seeds: Vec<u64>,
    /// Training frames scored, evenly spaced (0: all); every held-out frame is scored.
    #[arg(long = "train-frames", default_value_t = 18)]
    pub train_frames: usize,
    /// Score by the anchors' protocol too (LPIPS-VGG: about 10 s a 512x512 frame).
    /// Default: on for a dataset composited by its masks (a capture), off otherwise.
    #[arg(long, value_name = "on|off", value_parser = clap::builder::PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"))]
    pub anchors: Option<bool>,
    /// The plan from the training frames' census, as `talkin train`'s `--plan`.
    #[arg(long, value_name = "on|off", default_value = "on", value_parser = clap::builder::PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set)]
    pub plan: bool,
    /// The colour truth and render are composited over when scored, as `talkin eval`'s
    /// `--background`: three numbers in [0, 1], or `declared`. Default: black for a
    /// dataset composited by its masks (a capture), the declared background otherwise.
    #[arg(long, value_name = "R,G,B|declared")]
    pub background: Option<String>,
    /// Read before `recipe`, whose parser takes its values out of the matches.
    #[command(flatten)]
    pub given: super::train::GivenFlags,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct NoisyFitsArgs {
    /// Dataset directory (its fits are taken as the truth).
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: summary.json, noisy_fits.md, noisy_fits.png, data/, runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// Noise levels, degrees RMS per joint (translation 2 cm RMS at 6, scaled alike).
    #[arg(long = "noise-deg", default_value = "0,3,6,10", value_delimiter = ',')]
    pub noise_deg: Vec<f64>,
    /// Training minutes per run (two runs per level).
    #[arg(long = "minutes-each", default_value_t = 5.0)]
    pub minutes_each: f64,
    /// test_same frames scored, evenly spaced (0: all).
    #[arg(long, default_value_t = 8)]
    pub eval_frames: usize,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct DeviceBenchArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: device.json and device.md (and the rows' scratch runs).
    #[arg(long)]
    pub out: PathBuf,
    /// Devices to compare, comma-separated (`cpu`, `wgpu`, `wgpu:N`).
    #[arg(long, default_value = "cpu", value_delimiter = ',')]
    pub devices: Vec<talkin_nets::ComputeDevice>,
    /// Presets to compare, comma-separated.
    #[arg(long, default_value = "fast,paper", value_delimiter = ',', value_enum)]
    pub presets: Vec<talkin_train::Preset>,
    /// Untimed steps before the timed ones (kernel compilation, allocator warm-up).
    #[arg(long, default_value_t = 3)]
    pub warmup: usize,
    /// Timed steps per row (the median is reported).
    #[arg(long, default_value_t = 10)]
    pub steps: usize,
    /// Timed renders per row (after one untimed).
    #[arg(long, default_value_t = 3)]
    pub renders: usize,
    /// The renders' side in pixels (square; InstantAvatar's 540 by default).
    #[arg(long, value_name = "PX", default_value_t = talkin_benches::device::RENDER_SIDE)]
    pub render_size: u32,
    /// A trained run whose avatar (newest checkpoint) each device also renders, the same
    /// shot timed the same way: a fresh field's frame is not an avatar's (its grid keeps
    /// its initial marks and nothing is routed to the face and hand nets).
    #[arg(long, value_name = "RUN")]
    pub avatar: Option<PathBuf>,
    /// Random pixel rays per step (the paper: 32768 for its preset).
    #[arg(long = "batch", value_name = "N", default_value_t = TrainOptions::default().batch_rays)]
    pub batch_rays: usize,
    /// 32x32 LPIPS patches per step.
    #[arg(long, default_value_t = 0)]
    pub patches: usize,
    /// Seed of the fields and the ray choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Off the CPU, the fused MLP op (`on`) or burn's composed ops (`off`), to measure
    /// one against the other.
    #[arg(long = "mlp-fused", value_name = "on|off", default_value = "on", value_parser = clap::builder::PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set)]
    pub mlp_fused: bool,
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
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct NovelIdentityArgs {
    /// Dataset directory; the held-out subject needs a video longer than the longest clip
    /// (`talkin synth --frames 800`: 40 s a subject).
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: novel_identity.md, novel_identity.json, runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// The held-out subject (default: the dataset's last).
    #[arg(long)]
    pub subject: Option<String>,
    /// Clip lengths in seconds, from the start of the subject's video.
    #[arg(long, default_value = "1,3,10,30", value_delimiter = ',')]
    pub clips: Vec<f64>,
    /// Training minutes of the multi-identity model.
    #[arg(long, default_value_t = 6.0, conflicts_with = "base_steps")]
    pub base_minutes: f64,
    /// Optimizer steps of the multi-identity model instead of minutes (reproducible to
    /// the bit, whatever else the machine runs).
    #[arg(long)]
    pub base_steps: Option<usize>,
    /// Adapt this trained run instead of training the multi-identity model (it must not
    /// have trained the held-out subject).
    #[arg(long, conflicts_with_all = ["base_minutes", "base_steps"])]
    pub base_run: Option<PathBuf>,
    /// The adaptations' learning rate over the recipe's (default: `adapt`'s, 1 for the
    /// `fast` preset, the paper's 1/50 for `paper`).
    #[arg(long)]
    pub adapt_lr_ratio: Option<f64>,
    /// Training minutes of each adaptation (and of each from-scratch baseline).
    #[arg(long, default_value_t = 2.0, conflicts_with = "adapt_steps")]
    pub adapt_minutes: f64,
    /// Optimizer steps of each adaptation instead of minutes.
    #[arg(long)]
    pub adapt_steps: Option<usize>,
    /// Skip the baseline: a fresh single-identity model trained on each clip with the
    /// adaptation's budget (the paper's HumanNeRF comparison).
    #[arg(long)]
    pub no_scratch: bool,
    /// Frames per evaluated split, evenly spaced (0: all).
    #[arg(long, default_value_t = 6)]
    pub eval_frames: usize,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct SpeedVsErrorArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory: report.md, summary.json, speed_vs_error.csv, speed_vs_error.png,
    /// runs/.
    #[arg(long)]
    pub out: PathBuf,
    /// Target PSNRs on test_same (dB), ascending.
    #[arg(long, default_value = "18,20,22,24,26", value_delimiter = ',')]
    pub targets: Vec<f64>,
    /// Training minutes of the accelerated run (it stops early once it reaches the highest
    /// target).
    #[arg(long, default_value_t = 10.0)]
    pub accelerated_minutes: f64,
    /// Training minutes of the dense run at most (it stops once it reaches the highest
    /// target the accelerated run reached).
    #[arg(long, default_value_t = 60.0)]
    pub dense_minutes: f64,
    /// test_same frames scored at every evaluation, evenly spaced (0: all); each run is
    /// rendered by its own sampler (dense: tens of seconds a 144x192 frame on 2 cores).
    #[arg(long, default_value_t = 3)]
    pub eval_frames: usize,
    /// Training seconds between evaluations (default: 25% of the time trained so far, at
    /// least 5 s); a run skips an evaluation due sooner than its last one took.
    #[arg(long, value_name = "S")]
    pub eval_every_s: Option<f64>,
    /// The dense run's candidate learning rates; with more than one, a sweep picks the
    /// best (default: half, once and twice the recipe's rate).
    #[arg(long, value_delimiter = ',')]
    pub dense_lrs: Option<Vec<f64>>,
    /// Training minutes of each run of the dense learning-rate sweep.
    #[arg(long, default_value_t = 3.0)]
    pub dense_sweep_minutes: f64,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

#[derive(clap::Args, Debug)]
pub struct ServeBenchArgs {
    /// Run directory to serve from an in-process server.
    #[arg(long, required_unless_present = "target", conflicts_with = "target")]
    pub run: Option<PathBuf>,
    /// Bench a running server or load balancer at this URL (http://HOST:PORT) instead; it
    /// is asked for its first subject (GET /subjects). The server options below are then
    /// unused, but for `--timeout` (a client waits 4x as long for each answer).
    #[arg(long, value_name = "URL")]
    pub target: Option<String>,
    /// Concurrent client counts to measure, comma-separated.
    #[arg(long, default_value = "1,4,16", value_delimiter = ',')]
    pub clients: Vec<usize>,
    /// Requests per client count.
    #[arg(long, default_value_t = 32)]
    pub requests: usize,
    /// Image size of each request (WIDTHxHEIGHT; default: the server's --size).
    #[arg(long)]
    pub image: Option<String>,
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Also write the reports as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

#[derive(clap::Args, Debug)]
pub struct SamplingArgs {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Also write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Cull with this run's canonical grids (after its occupancy updates) instead of the
    /// initial ones; the run must have been trained on `--data`.
    #[arg(long)]
    pub run: Option<PathBuf>,
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.which {
        BenchCommand::Sampling(a) => sampling_bench(a),
        BenchCommand::SpeedVsError(a) => speed_vs_error_bench(a),
        BenchCommand::Ablations(a) => ablations_bench(a),
        BenchCommand::NovelIdentity(a) => novel_identity_bench(a),
        BenchCommand::Serve(a) => serve_bench(a),
        BenchCommand::Device(a) => device_bench(a),
        BenchCommand::NoisyFits(a) => noisy_fits_bench(a),
        BenchCommand::Convergence(a) => convergence_bench(a),
        BenchCommand::Step(a) => step_bench(a),
    }
}

fn device_bench(args: DeviceBenchArgs) -> anyhow::Result<()> {
    use talkin_benches::device::{DeviceBenchOptions, run, table};
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let dataset = super::load_dataset(&args.data)?;
    let opts = DeviceBenchOptions {
        devices: args.devices.clone(),
        presets: args.presets.clone(),
        warmup: args.warmup,
        steps: args.steps,
        renders: args.renders,
        render_side: args.render_size,
        avatar: args.avatar.clone(),
        train: TrainOptions {
            batch_rays: args.batch_rays,
            patches: args.patches,
            seed: args.seed,
            mlp_fused: args.mlp_fused,
            ..TrainOptions::default()
        },
    };
    let report = run(&dataset, &args.out.join("runs"), &opts, &mut |row| {
        tracing::info!("{row}")
    })
    .with_context(|| format!("device benchmark on {}", args.data.display()))?;
    let md = table(&report);
    talkin_benches::shared::write_report(
        &args.out,
        "device",
        serde_json::to_string_pretty(&report)?.as_bytes(),
        &md,
    )?;
    println!("{md}");
    println!("report: {}/{{device.json, device.md}}", args.out.display());
    Ok(())
}

fn serve_bench(args: ServeBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        !args.clients.is_empty() && args.clients.iter().all(|&c| c > 0),
        "--clients: expected positive client counts, found {:?}",
        args.clients
    );
    anyhow::ensure!(
        args.requests > 0,
        "--requests: expected at least 1, found 0"
    );
    let mut config = args.limits.config()?;
    // Every client's request waits and every client connects instead of being refused:
    // the bench measures latency under load, not the 503 paths.
    let most_clients = args.clients.iter().copied().max().unwrap_or(1);
    config.queue = config.queue.max(most_clients);
    config.max_connections = config.max_connections.max(most_clients);
    let image = args.image.clone();
    let parse_size = |text: &str| {
        text.split_once('x')
            .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
            .ok_or_else(|| anyhow::anyhow!("--image: expected WIDTHxHEIGHT, found {text}"))
    };
    let timeout = config.render_timeout * 4;
    let (workers, queue) = (config.workers, config.queue);
    // The server benched: one started here, or the target's address.
    let (server, addr, what) = match (&args.run, &args.target) {
        (Some(run), _) => {
            let avatar = args.device.load_avatar(run)?;
            let server = Server::start(Arc::new(avatar), "127.0.0.1:0", config)?;
            let addr = server.addr();
            let what = format!(
                "{} in process ({workers} render threads, queue {queue})",
                run.display()
            );
            (Some(server), addr, what)
        }
        (None, Some(url)) => {
            let addr = talkin_serve::client::parse_http_url(url)
                .map_err(|e| anyhow::anyhow!("--target: {e}"))?;
            (None, addr, url.clone())
        }
        (None, None) => anyhow::bail!("give --run or --target"),
    };
    let size = image.as_deref().map(parse_size).transpose()?;
    let measured = bench::bench_render(addr, &what, size, &args.clients, args.requests, timeout);
    if let Some(server) = server {
        server.shutdown()?;
    }
    let measured = measured?;
    println!(
        "bench serve: {what}, subject `{}`, {}x{} PNG frames, {} requests per client count",
        measured.subject, measured.width, measured.height, args.requests
    );
    let reports = measured.reports;
    print!("{}", bench::format_report(&reports));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&reports)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("report: {}", path.display());
    }
    Ok(())
}

fn sampling_bench(args: SamplingArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)?;
    let trained = match &args.run {
        None => None,
        Some(run) => Some(sampling::trained_grids(run, &dataset)?),
    };
    let mut progress: Option<Progress> = None;
    let report = sampling::bench_sampling(&dataset, trained.as_deref(), &mut |done, total| {
        progress
            .get_or_insert_with(|| Progress::new("sampling", total, "frames"))
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
    use talkin_benches::speed_vs_error::{SpeedVsErrorOptions, format_summary, speed_vs_error};
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let lr = args.recipe.initial_lr();
    let opts = SpeedVsErrorOptions {
        targets_db: args.targets.clone(),
        accelerated_s: args.accelerated_minutes * 60.0,
        dense_s: args.dense_minutes * 60.0,
        eval_frames: args.eval_frames,
        eval_every_s: args.eval_every_s,
        dense_lrs: args
            .dense_lrs
            .clone()
            .unwrap_or_else(|| vec![lr / 2.0, lr, 2.0 * lr]),
        dense_sweep_s: args.dense_sweep_minutes * 60.0,
        train: args.recipe.clone(),
        lpips_dir: args.recipe.perceptual.clone(),
    };
    let dataset = Dataset::load(&args.data)?;
    let summary = speed_vs_error(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("speed-vs-error benchmark on {}", args.data.display()))?;
    println!("{}", format_summary(&summary));
    println!(
        "report: {}/{{report.md, summary.json, speed_vs_error.csv, speed_vs_error.png}}",
        args.out.display()
    );
    Ok(())
}

fn ablations_bench(args: AblationArgs) -> anyhow::Result<()> {
    use talkin_benches::ablations::{AblationOptions, ablations, format_table};
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let dataset = Dataset::load(&args.data)?;
    let opts = AblationOptions {
        budget_s: args.minutes_each * 60.0,
        eval_frames: args.eval_frames,
        train: args.recipe.clone(),
        lpips_dir: args.recipe.perceptual.clone(),
    };
    let rows = ablations(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("ablations on {}", args.data.display()))?;
    println!("{}", format_table(&rows));
    println!("report: {}/ablations.md", args.out.display());
    Ok(())
}

fn noisy_fits_bench(args: NoisyFitsArgs) -> anyhow::Result<()> {
    use talkin_benches::noisy_fits::{NoisyFitsOptions, noisy_fits, table};
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let dataset = Dataset::load(&args.data)?;
    let opts = NoisyFitsOptions {
        levels_deg: args.noise_deg.clone(),
        budget_s: args.minutes_each * 60.0,
        eval_frames: args.eval_frames,
        train: args.recipe.clone(),
        lpips_dir: args.recipe.perceptual.clone(),
    };
    let summary = noisy_fits(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("noisy fits on {}", args.data.display()))?;
    println!("{}", table(&summary));
    println!("report: {}/noisy_fits.md", args.out.display());
    Ok(())
}

fn convergence_bench(args: ConvergenceArgs) -> anyhow::Result<()> {
    use talkin_benches::convergence::{ConvergenceOptions, convergence, table};
    use talkin_data::dataset::Matting;
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let dataset = Dataset::load(&args.data)?;
    let train =
        super::train::plain_recipe(&dataset, &args.data, &args.recipe, &args.given, args.plan)?;
    if let Some(plan) = &train.plan {
        print!("{}", plan.describe());
    }
    let opts = ConvergenceOptions {
        budgets: args.budgets.clone(),
        seeds: args.seeds.clone(),
        train_frames: args.train_frames,
        lpips_dir: train.perceptual.clone(),
        anchors: args.anchors.unwrap_or(dataset.matting == Matting::ByMask),
        // Scored as `talkin eval` scores by default: a capture over black.
        score_over: match args.background.as_deref() {
            Some("declared") => None,
            Some(text) => Some(super::parse_rgb(text)?),
            None => (dataset.matting == Matting::ByMask).then_some([0.0; 3]),
        },
        train,
    };
    let summary = convergence(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("convergence on {}", args.data.display()))?;
    println!("{}", table(&summary));
    println!("report: {}/convergence.md", args.out.display());
    Ok(())
}

fn step_bench(args: StepBenchArgs) -> anyhow::Result<()> {
    use talkin_benches::shared::write_report;
    use talkin_benches::step::{StepBenchOptions, run, table};
    // A fresh field's run is written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let dataset = Dataset::load(&args.data)?;
    // A run steps with its own recipe; a fresh field with the plain recipe and its plan.
    let train = match &args.run {
        Some(_) => args.recipe.clone(),
        None => super::train::plain_recipe(&dataset, &args.data, &args.recipe, &args.given, true)?,
    };
    let opts = StepBenchOptions {
        run: args.run.clone(),
        warmup: args.warmup,
        steps: args.timed_steps,
        train,
    };
    let report = run(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("step bench on {}", args.data.display()))?;
    let md = table(&report);
    let json = serde_json::to_vec_pretty(&report)?;
    write_report(&args.out, "step", &json, &md)?;
    println!("{md}");
    println!("report: {}/step.md", args.out.display());
    Ok(())
}

fn novel_identity_bench(args: NovelIdentityArgs) -> anyhow::Result<()> {
    use talkin_benches::novel_identity::{NovelIdentityOptions, format_table, novel_identity};
    use talkin_train::Budget;
    // The runs it trains are written under --out: one writer at a time.
    let _lock = talkin_train::RunLock::take(&args.out)?;
    let budget = |flag: &str, minutes: f64, steps: Option<usize>| match steps {
        Some(0) => anyhow::bail!("{flag}-steps: expected a positive number of steps"),
        Some(n) => Ok(Budget::Steps(n)),
        None if minutes.is_finite() && minutes > 0.0 => Ok(Budget::Seconds(minutes * 60.0)),
        None => anyhow::bail!("{flag}-minutes: expected a positive number, found {minutes}"),
    };
    let base = budget("--base", args.base_minutes, args.base_steps)?;
    let adapt = budget("--adapt", args.adapt_minutes, args.adapt_steps)?;
    let dataset = Dataset::load(&args.data)?;
    let opts = NovelIdentityOptions {
        subject: args.subject.clone(),
        clips_s: args.clips.clone(),
        base,
        base_run: args.base_run.clone(),
        adapt_lr_ratio: args
            .adapt_lr_ratio
            .unwrap_or_else(|| args.recipe.preset.adapt_lr_ratio()),
        adapt,
        scratch: !args.no_scratch,
        eval_frames: args.eval_frames,
        train: args.recipe.clone(),
        lpips_dir: args.recipe.perceptual.clone(),
    };
    let rows = novel_identity(&dataset, &args.out, &opts, &mut |msg| {
        tracing::info!("{msg}")
    })
    .with_context(|| format!("novel-identity benchmark on {}", args.data.display()))?;
    println!("{}", format_table(&rows));
    println!("report: {}/novel_identity.md", args.out.display());
    Ok(())
}
