use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ExportPosesArgs {
    /// The run (trained with `--refine-poses`; its newest checkpoint is read).
    #[arg(long)]
    pub run: PathBuf,
    /// Where the refined fits go: a `dataset.json` with the training frames' parameters
    /// refined (also a poses file for `talkin render --poses`).
    #[arg(long)]
    pub out: PathBuf,
    /// The dataset the run trained on (default: the directory the run recorded).
    #[arg(long)]
    pub data: Option<PathBuf>,
}

pub fn run(args: ExportPosesArgs) -> anyhow::Result<()> {
    let summary = talkin_train::refine::export_poses(&args.run, args.data.as_deref(), &args.out)?;
    println!(
        "wrote {}: {} training frames refined, {} as fitted (from {})",
        args.out.display(),
        summary.refined_frames,
        summary.fitted_frames,
        summary.data.display()
    );
    Ok(())
}
