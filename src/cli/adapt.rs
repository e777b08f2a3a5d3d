use std::path::PathBuf;

use anyhow::Context;
use talkin_benches::novel_identity::adapt_lr_ratio;
use talkin_data::dataset::Dataset;
use talkin_train::Trainer;

use super::train::{RecipeArgs, run_trainer};

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
    /// Use only the first S seconds of the subject's training frames (the paper: 1, 3,
    /// 10 or 30 s).
    #[arg(long)]
    pub seconds_of_video: Option<f64>,
    #[command(flatten)]
    pub recipe: RecipeArgs,
}

pub fn run(args: AdaptArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.data)
        .with_context(|| format!("cannot load the dataset in {}", args.data.display()))?;
    let mut opts = args.recipe.options()?;
    if opts.lr.is_none() {
        opts.lr = Some(opts.initial_lr() * adapt_lr_ratio(&opts.preset));
    }
    opts.identities = Some(vec![args.subject.clone()]);
    let trainer = Trainer::adapt(
        &dataset,
        &args.run,
        &args.subject,
        args.seconds_of_video,
        &args.out,
        &opts,
    )
    .with_context(|| format!("adapting {} to `{}`", args.run.display(), args.subject))?;
    run_trainer(trainer, &args.data)
}
