use std::path::PathBuf;

use anyhow::Context;
use talkin_data::dataset::{Dataset, Split};
use talkin_human::smooth::Smoothing;
use talkin_render::avatar::Avatar;
use talkin_render::sequence::{
    read_poses_file, render_sequence, shots_from_frames, shots_from_poses, smooth_shots,
    split_frames,
};

use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// The trained run (its newest checkpoint is rendered).
    #[arg(long)]
    pub run: PathBuf,
    /// Dataset whose split's poses and cameras to render (with ground truth: a contact
    /// sheet ground truth | render | error is written too).
    #[arg(
        long,
        requires = "split",
        conflicts_with = "poses",
        required_unless_present = "poses"
    )]
    pub data: Option<PathBuf>,
    /// The split of --data: train, test_same, test_cross or test_ood.
    #[arg(long, requires = "data")]
    pub split: Option<String>,
    /// A poses file: {"frames": [{"params": {...}, "camera": {...}}, ...]} with dataset.json's
    /// `params` and `camera` objects.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Output directory: frame_0000.png, ... (and contact_sheet.png).
    #[arg(long)]
    pub out: PathBuf,
    /// Render every pose as this trained subject (default: each dataset frame's own
    /// subject; for --poses, the only trained subject).
    #[arg(long)]
    pub subject: Option<String>,
    /// Smooth poses and cameras over time (Gaussian, window 5, sigma 1), per subject in
    /// time order for dataset splits, in file order for --poses.
    #[arg(long)]
    pub smooth: bool,
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let avatar =
        Avatar::load(&args.run).with_context(|| format!("loading run {}", args.run.display()))?;
    let subject = args.subject.as_deref();
    let (dataset, mut shots) = match (&args.data, &args.split, &args.poses) {
        (Some(dir), Some(split), _) => {
            let split: Split = split.parse().map_err(anyhow::Error::msg)?;
            let dataset = Dataset::load(dir)
                .with_context(|| format!("cannot load the dataset in {}", dir.display()))?;
            let frames = split_frames(&dataset, split)?;
            let shots = shots_from_frames(&avatar, &dataset, &frames, subject)?;
            (Some(dataset), shots)
        }
        (_, _, Some(file)) => {
            let poses = read_poses_file(file)?;
            (None, shots_from_poses(&avatar, &poses, subject)?)
        }
        _ => anyhow::bail!("give --data DIR --split NAME, or --poses FILE"),
    };
    if args.smooth {
        smooth_shots(&mut shots, &Smoothing::PAPER)?;
    }
    let progress = Progress::new("rendering frames", shots.len());
    let renders = render_sequence(
        &avatar,
        &shots,
        dataset.as_ref(),
        &args.out,
        &mut |done, _| progress.update(done, ""),
    )?;
    println!(
        "rendered {} frames to {} in {:.1} s ({:.2} s a frame, {:.0} samples a frame)",
        renders.frames.len(),
        args.out.display(),
        renders.seconds,
        renders.seconds / renders.frames.len().max(1) as f64,
        renders.samples as f64 / renders.frames.len().max(1) as f64
    );
    if let Some(sheet) = &renders.contact_sheet {
        println!(
            "contact sheet (ground truth | render | error): {}",
            sheet.display()
        );
    }
    Ok(())
}
