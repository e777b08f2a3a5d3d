use std::path::PathBuf;

use anyhow::Context;
use talkin_data::dataset::Dataset;
use talkin_train::{Identities, TrainOptions, Trainer};

use super::train::run_trainer;

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
    /// The adapted run's directory.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub recipe: TrainOptions,
}

pub fn run(args: AdaptArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)
        .with_context(|| format!("cannot load the dataset in {}", args.data.display()))?;
    let mut opts = args.recipe;
    if opts.lr.is_none() {
        opts.lr = Some(opts.initial_lr() * opts.preset.adapt_lr_ratio());
    }
    opts.identities = Identities::Named(vec![args.subject.clone()]);
    let trainer = Trainer::adapt(&dataset, &args.run, &args.subject, &args.out, &opts)
        .with_context(|| format!("adapting {} to `{}`", args.run.display(), args.subject))?;
    run_trainer(trainer, &args.data)
}
