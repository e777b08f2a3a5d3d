use std::path::PathBuf;

use anyhow::Context;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use talkin_data::atomic::StagedDir;
use talkin_data::dataset::{Matting, Split};
use talkin_render::eval::{EvalOptions, evaluate_with_progress};
use talkin_render::sequence::split_frames;

use super::train::DEFAULT_LPIPS_DIR;
use crate::progress::Progress;

/// What a dataset composited by its masks is scored over unless told otherwise.
const OVER_BLACK: [f32; 3] = [0.0; 3];

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
    /// The colour truth and render are composited over: three numbers in [0, 1], or
    /// `declared` for the dataset's own background. Every frame's truth is its camera
    /// frame composited by its mask over the colour and the field renders over it. The
    /// default: black (`0,0,0`, Neural Body's protocol, which the systems compared with
    /// on real captures follow) for a dataset composited by its masks (`"matting":
    /// "by_mask"`, what `import` writes), the declared background for a matted one. A
    /// matted dataset is shown over another colour only if its masks are exact coverage
    /// (`"masks": "coverage"`, what `synth` writes): a matte's edge pixels keep the old
    /// colour.
    #[arg(long, value_name = "R,G,B|declared")]
    pub background: Option<String>,
    /// Also score by the anchors' protocol, so a run can be set beside HumanNeRF's and
    /// Neural Body's tables: the whole frame, SSIM as scikit-image 0.19 computed it for
    /// float images (data range 2), LPIPS with the VGG16 backbone x1000 (about 10 s a
    /// 512x512 frame on 2 cores). Default: on for a dataset composited by its masks (a
    /// capture), off otherwise.
    #[arg(long, value_name = "on|off", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"))]
    pub anchors: Option<bool>,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let split: Split = args.split.parse().map_err(anyhow::Error::msg)?;
    let device = args.device.open()?;
    let mut dataset = super::load_dataset(&args.data)?;
    let (background, note) = match args.background.as_deref() {
        Some("declared") => (None, None),
        Some(text) => (Some(super::parse_rgb(text)?), None),
        None if dataset.matting == Matting::ByMask => (
            Some(OVER_BLACK),
            Some(
                "scored over black (a dataset composited by its masks: Neural Body's protocol); \
                 --background declared scores over the dataset's own background"
                    .to_string(),
            ),
        ),
        None => (None, None),
    };
    if let Some(rgb) = background {
        dataset
            .show_over(rgb)
            .context("--background: the truth cannot be shown over another colour")?;
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
    // The renders appear complete or not at all: an error (a full disk) removes them.
    let staging = StagedDir::new(&renders).with_context(|| renders.display().to_string())?;
    let opts = EvalOptions {
        renders_dir: Some(staging.path().to_path_buf()),
        lpips_dir: Some(args.lpips_dir.clone()),
        smooth: args.smooth,
        anchors: args.anchors.unwrap_or(dataset.matting == Matting::ByMask),
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
    // Each score names its PNG where it will be, not where it was written.
    for score in &mut report.frames {
        if let Some(file) = &mut score.render
            && let Ok(name) = file.strip_prefix(staging.path())
        {
            *file = renders.join(name);
        }
    }
    report.run = Some(args.run.clone());
    report.notes.extend(note);
    if let Some(dir) = args.json.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    staging
        .publish()
        .with_context(|| renders.display().to_string())?;
    report.write_json(&args.json)?;
    print!("{}", report.table());
    println!(
        "report: {}\nrenders: {}",
        args.json.display(),
        renders.display()
    );
    Ok(())
}
