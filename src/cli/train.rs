use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::Context;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::parser::ValueSource;
use clap::{ArgMatches, FromArgMatches};
pub use talkin_train::DEFAULT_LPIPS_DIR;
use talkin_train::plan::Plan;
use talkin_train::{
    Budget, DEVICE_ARG, RunLock, RunWriter, StepLog, TrainOptions, Trainer, existing_run,
};

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Dataset directory (with dataset.json).
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory: recipe.json, train_log.csv and checkpoint/ are written there. One
    /// that already holds a run is refused without --resume or --force.
    #[arg(long, default_value = "out/train")]
    pub out: PathBuf,
    /// Continue the run in --out from its newest good checkpoint, with its own options and
    /// dataset. --steps or --minutes give it a new total budget (--steps 80 after 40
    /// steps trains 40 more); without them it keeps its budget.
    #[arg(long, conflicts_with = "force")]
    pub resume: bool,
    /// Start a new run in an --out that holds one: its checkpoints are deleted and its
    /// log and recipe replaced.
    #[arg(long)]
    pub force: bool,
    /// Plan the run from a census of its training frames (`on`): which networks, inputs,
    /// finger bones and hash-grid levels it builds, each decision printed with its reason
    /// and recorded in recipe.json; every flag named here overrides its decision. `off`:
    /// everything the options say, as given.
    #[arg(long, value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set)]
    pub plan: bool,
    #[command(flatten)]
    pub peers: super::peers::PeerArgs,
    /// Read before `recipe`, whose parser takes its values out of the matches.
    #[command(flatten)]
    pub given: GivenFlags,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

/// Which of the recipe's options the command line named: clap fills every other one with
/// its default, and `--resume` must tell "no budget given" from the default budget.
#[derive(Debug, Clone, Default)]
pub struct GivenFlags {
    /// `--steps` or `--minutes`.
    pub budget: bool,
    /// Any other recipe option (ignored by `--resume`, which keeps the run's).
    pub other: bool,
    /// The ids of every recipe option the command line named.
    pub named: Vec<String>,
}

impl FromArgMatches for GivenFlags {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        // The command's own flags (`train`'s, and `adapt`'s `--run` and `--subject`).
        let own = [
            "data",
            "out",
            "resume",
            "force",
            "plan",
            "run",
            "subject",
            "nodes",
            "node_rank",
            "peer_timeout",
            DEVICE_ARG,
        ];
        let given = |id: &str| m.value_source(id) == Some(ValueSource::CommandLine);
        let named: Vec<String> = m
            .ids()
            .map(|id| id.as_str())
            .filter(|id| !own.contains(id) && given(id))
            .map(str::to_string)
            .collect();
        Ok(GivenFlags {
            budget: Budget::ARGS.into_iter().any(given),
            other: named.iter().any(|id| !Budget::ARGS.contains(&id.as_str())),
            named,
        })
    }

    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        *self = GivenFlags::from_arg_matches(m)?;
        Ok(())
    }
}

impl clap::Args for GivenFlags {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        cmd
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        cmd
    }
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    // Before any work: a signal from here on ends the run with a checkpoint.
    let signals = StopSignals::install()?;
    // Which peer this is (alone unless an MPI launcher started several), and the link to
    // the others; peer 0 alone writes the run.
    let peers = super::peers::join(&args.peers)?;
    let rank = peers.as_ref().map_or(0, |p| p.rank());
    let writes = if rank == 0 {
        RunWriter::Writes
    } else {
        RunWriter::ReadsOnly
    };
    // One writer per run, taken before anything reads or clears it (`--force` included). A
    // --resume of a directory that is not there takes none: resuming fails on its own.
    let _lock = if writes == RunWriter::ReadsOnly || (args.resume && !args.out.is_dir()) {
        None
    } else {
        Some(RunLock::take(&args.out)?)
    };
    if !args.resume && writes == RunWriter::Writes {
        refuse_existing_run(&args.out, args.force)?;
    }
    let dataset = super::load_dataset(&args.data)?;
    let mut trainer = if args.resume {
        if args.given.other {
            tracing::warn!(
                "--resume continues with the run's own options (its recipe.json); only \
                 --steps, --minutes and --device given here apply"
            );
        }
        let mut trainer = Trainer::resume_as(&dataset, &args.out, args.recipe.device, writes)
            .with_context(|| format!("resuming {}", args.out.display()))?;
        if let Some(plan) = trainer.options().plan.as_ref().filter(|_| rank == 0) {
            println!("resuming with the plan the run started with:");
            print!("{}", plan.describe());
        }
        if args.given.budget {
            trainer
                .set_budget(args.recipe.budget)
                .with_context(|| format!("extending {}", args.out.display()))?;
        }
        trainer
    } else {
        let recipe = plain_recipe(&dataset, &args.data, &args.recipe, &args.given, args.plan)?;
        if let Some(plan) = recipe.plan.as_ref().filter(|_| rank == 0) {
            print!("{}", plan.describe());
        }
        Trainer::new_as(&dataset, &args.out, &recipe, writes)
            .with_context(|| format!("training on {}", args.data.display()))?
    };
    if let Some(peers) = peers {
        let size = peers.size();
        trainer
            .join_peers(peers)
            .with_context(|| format!("joining the run's {size} peers"))?;
    }
    run_trainer(trainer, &args.data, &args.out, &signals)
}

/// The options a new run on `dataset` trains with: `recipe` as the command line gave it
/// (`given` says which options it named), a camera capture's recipe for every option it
/// did not name, and with `plan` the plan from the training frames' census.
pub fn plain_recipe(
    dataset: &talkin_data::dataset::Dataset,
    data: &Path,
    recipe: &TrainOptions,
    given: &GivenFlags,
    plan: bool,
) -> anyhow::Result<TrainOptions> {
    let named = |id: &str| given.named.iter().any(|n| n == id);
    let recipe = recipe.clone().for_dataset(dataset, named);
    if !plan {
        return Ok(recipe);
    }
    Plan::for_run(dataset, recipe, named)
        .with_context(|| format!("planning a run on {}", data.display()))
}

/// Refuses an `out` that holds a run unless `force`, which says that it starts over.
pub fn refuse_existing_run(out: &Path, force: bool) -> anyhow::Result<()> {
    let Some(found) = existing_run(out) else {
        return Ok(());
    };
    if !force {
        anyhow::bail!(
            "{} already holds a run ({} exists): continue it with --resume, or start over \
             with --force (deletes its checkpoints and replaces its log)",
            out.display(),
            found.display()
        );
    }
    tracing::warn!(
        "--force: starting over in {}: its checkpoints are deleted and its train_log.csv and \
         recipe.json replaced",
        out.display()
    );
    Ok(())
}

/// SIGINT and SIGTERM while this is alive set a flag the trainer polls between steps; a
/// second signal (the flag already set) exits at once with 128 + its number. Once
/// dropped, any signal exits at once.
pub struct StopSignals {
    stop: Arc<AtomicBool>,
    signal: Arc<AtomicUsize>,
}

impl StopSignals {
    pub fn install() -> anyhow::Result<StopSignals> {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let stop = Arc::new(AtomicBool::new(false));
        let signal = Arc::new(AtomicUsize::new(0));
        for sig in [SIGINT, SIGTERM] {
            // Order matters: the exit checks the flag before this signal sets it.
            signal_hook::flag::register_conditional_shutdown(sig, 128 + sig, stop.clone())
                .and_then(|_| signal_hook::flag::register_usize(sig, signal.clone(), sig as usize))
                .and_then(|_| signal_hook::flag::register(sig, stop.clone()))
                .context("installing the SIGINT/SIGTERM handlers")?;
        }
        Ok(StopSignals { stop, signal })
    }

    /// The signal that arrived, if any.
    fn received(&self) -> Option<i32> {
        match self.signal.load(Ordering::SeqCst) {
            0 => None,
            s => Some(s as i32),
        }
    }
}

impl Drop for StopSignals {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// A run stopped by a signal, its checkpoint written: the message says how to go on, and
/// the process exits with 128 + the signal's number.
#[derive(Debug)]
pub struct Interrupted {
    pub signal: i32,
    step: usize,
    checkpoint: PathBuf,
    data: PathBuf,
    out: PathBuf,
}

impl Interrupted {
    /// The shell's convention: 130 for SIGINT, 143 for SIGTERM.
    pub fn exit_code(&self) -> u8 {
        u8::try_from(128 + self.signal).unwrap_or(1)
    }
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = match self.signal {
            signal_hook::consts::SIGINT => "SIGINT (Ctrl-C)".to_string(),
            signal_hook::consts::SIGTERM => "SIGTERM".to_string(),
            s => format!("signal {s}"),
        };
        write!(
            f,
            "interrupted by {name} after step {}: checkpoint {} written and the log flushed; \
             continue with: talkin train --data {} --out {} --resume",
            self.step,
            self.checkpoint.display(),
            self.data.display(),
            self.out.display()
        )
    }
}

impl std::error::Error for Interrupted {}

/// Runs a trainer to the end (or to a signal) with a progress line and prints a summary.
pub fn run_trainer(
    trainer: Trainer,
    data: &Path,
    out: &Path,
    signals: &StopSignals,
) -> anyhow::Result<()> {
    if let Some(note) = trainer.perceptual_note() {
        tracing::warn!("{note}");
    }
    let opts = trainer.options().clone();
    let (steps_before, budget) = (trainer.steps_taken(), opts.budget);
    // In the budget's own unit: steps, or seconds of training.
    let progress = match budget {
        talkin_train::Budget::Steps(total) => Progress::new("training", total, "steps"),
        talkin_train::Budget::Seconds(total) => {
            Progress::new("training", total.ceil() as usize, "s")
        }
    };
    let position = |log: &StepLog| match budget {
        talkin_train::Budget::Steps(_) => log.step,
        talkin_train::Budget::Seconds(total) => (log.progress * total).floor() as usize,
    };
    let report = trainer
        .run_until(&signals.stop, &mut |log: &StepLog| {
            progress.update(
                position(log),
                &format!(
                    "step {} loss {:.4} psnr {:.2} dB, {:.0} rays/s",
                    log.step, log.loss, log.psnr, log.rays_per_s
                ),
            )
        })
        .with_context(|| format!("training on {}", data.display()))?;
    let n = report.logs.len();
    if n == 0 && !report.interrupted {
        // A resumed run whose budget was already spent: no step to average.
        println!(
            "trained 0 steps: the run's budget ({}) was already spent at step {steps_before}; \
             give --resume a larger --steps or --minutes to extend it",
            match budget {
                talkin_train::Budget::Steps(s) => format!("{s} steps"),
                talkin_train::Budget::Seconds(s) => format!("{:.1} minutes", s / 60.0),
            }
        );
    } else if n > 0 {
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
    if let Some(line) = &report.peers {
        println!("{line}");
    }
    println!(
        "log: {}\ncheckpoint: {}",
        report.log_file.display(),
        report.checkpoint.display()
    );
    if report.interrupted {
        return Err(Interrupted {
            signal: signals.received().unwrap_or(signal_hook::consts::SIGTERM),
            step: report.steps,
            checkpoint: report.checkpoint,
            data: data.to_path_buf(),
            out: out.to_path_buf(),
        }
        .into());
    }
    Ok(())
}
