use std::path::PathBuf;

use anyhow::Context;
use talkin_data::dataset::{Matting, Split};
use talkin_render::eval::{EvalOptions, evaluate_with_progress};
use talkin_render::sequence::split_frames;

use super::train::DEFAULT_LPIPS_DIR;
use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// The trained run (its newest checkpoint is evaluated).
    #[arg(long)]
    pub run: PathBuf,
    /// Dataset with the ground truth.
    #[arg(long)]
    pub data: PathBuf,
    /// The split to evaluate: train, test_same, test_cross or test_ood.
    #[arg(long)]
    pub split: String,
    /// The report (JSON, written atomically).
    #[arg(long)]
    pub json: PathBuf,
    /// Where the scored renders go (default: `<json stem>_renders/` next to the JSON).
    #[arg(long)]
    pub renders: Option<PathBuf>,
    /// Directory of the LPIPS weights (`talkin lpips-weights`; by default the per-user cache); without them
    /// LPIPS is null in the report and a note says why.
    #[arg(long, default_value_os = DEFAULT_LPIPS_DIR.as_os_str())]
    pub lpips_dir: PathBuf,
    /// Smooth poses and cameras over time (Gaussian, window 5, sigma 1) before rendering.
    #[arg(long)]
    pub smooth: bool,
    /// Score over this colour instead of the dataset's background: three numbers in
    /// [0, 1] (`0,0,0` is black, what Neural Body's protocol scores over). Every frame's
    /// truth is its camera frame composited by its mask over the colour and the field
    /// renders over it. Only for datasets composited by their masks (`"matting":
    /// "by_mask"`, what `import` writes): a matted frame's edge keeps its old background.
    #[arg(long, value_name = "R,G,B")]
    pub background: Option<String>,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let split: Split = args.split.parse().map_err(anyhow::Error::msg)?;
    let background = args
        .background
        .as_deref()
        .map(super::parse_rgb)
        .transpose()?;
    let device = args.device.open()?;
    let mut dataset = super::load_dataset(&args.data)?;
    if let Some(rgb) = background {
        if dataset.matting == Matting::Matted {
            anyhow::bail!(
                "--background: {}: \"matting\" is \"matted\" (the frames already show the person over {:?}); \
                 its binary masks cannot take the old background out of the edge pixels, so only a \
                 dataset composited by its masks (\"by_mask\") is scored over another colour",
                args.data.join("dataset.json").display(),
                dataset.background
            );
        }
        dataset.background = rgb;
        dataset.matting = Matting::ByMask;
    }
    let mut avatar = super::load_avatar(&args.run, &device)?;
    if let Some(rgb) = background {
        avatar.background = rgb;
    }
    let frames = split_frames(&dataset, split)?;
    let renders = args.renders.clone().unwrap_or_else(|| {
        let stem = args
            .json
            .file_stem()
            .map_or_else(|| "eval".into(), |s| s.to_string_lossy().into_owned());
        args.json.with_file_name(format!("{stem}_renders"))
    });
    let opts = EvalOptions {
        renders_dir: Some(renders.clone()),
        lpips_dir: Some(args.lpips_dir.clone()),
        smooth: args.smooth,
    };
    let progress = Progress::new("evaluating", frames.len(), "frames");
    let mut report = evaluate_with_progress(&avatar, &dataset, &frames, &opts, &mut |done, _| {
        progress.update(done, "")
    })
    .with_context(|| {
        format!(
            "evaluating {} on {}",
            args.run.display(),
            args.data.display()
        )
    })?;
    report.run = Some(args.run.clone());
    if let Some(dir) = args.json.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    report.write_json(&args.json)?;
    print!("{}", report.table());
    println!(
        "report: {}\nrenders: {}",
        args.json.display(),
        renders.display()
    );
    Ok(())
}
