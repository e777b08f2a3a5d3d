use std::path::PathBuf;

use anyhow::Context;
use talkin_train::{Identities, RunLock, TrainOptions, Trainer};

use super::train::{GivenFlags, StopSignals, refuse_existing_run, run_trainer};

#[derive(clap::Args, Debug, Clone)]
pub struct AdaptArgs {
    /// The trained multi-identity run to adapt.
    #[arg(long)]
    pub run: PathBuf,
    /// Dataset holding the novel subject's clip.
    #[arg(long)]
    pub data: PathBuf,
    /// The novel subject's name in that dataset.
    #[arg(long)]
    pub subject: String,
    /// The adapted run's directory. One that already holds a run is refused without
    /// --force; continue an adapted run with `talkin train --resume`.
    #[arg(long)]
    pub out: PathBuf,
    /// Start over in an --out that holds a run: its checkpoints are deleted and its log
    /// and recipe replaced.
    #[arg(long)]
    pub force: bool,
    /// Read before `recipe`, whose parser takes its values out of the matches.
    #[command(flatten)]
    pub given: GivenFlags,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

pub fn run(args: AdaptArgs) -> anyhow::Result<()> {
    // Before any work: a signal from here on ends the run with a checkpoint.
    let signals = StopSignals::install()?;
    // One writer per run, taken before anything reads or clears --out (`--force` included).
    let _lock = RunLock::take(&args.out)?;
    refuse_existing_run(&args.out, args.force)?;
    let dataset = super::load_dataset(&args.data)?;
    // A clip from a camera takes the capture recipe where nothing is named (the field's
    // own architecture, frame codes included, comes from the base run).
    let mut opts = args
        .recipe
        .for_dataset(&dataset, |id| args.given.named.iter().any(|n| n == id));
    if opts.lr.is_none() {
        opts.lr = Some(opts.initial_lr() * opts.preset.adapt_lr_ratio());
    }
    opts.identities = Identities::Named(vec![args.subject.clone()]);
    let trainer = Trainer::adapt(&dataset, &args.run, &args.subject, &args.out, &opts)
        .with_context(|| format!("adapting {} to `{}`", args.run.display(), args.subject))?;
    run_trainer(trainer, &args.data, &args.out, &signals)
}
