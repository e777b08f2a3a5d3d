use std::path::PathBuf;

use anyhow::Context;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use talkin_avatar::refined::RefinedFits;
use talkin_data::atomic::StagedDir;
use talkin_data::dataset::{Dataset, Matting, Split};
use talkin_render::eval::{EvalOptions, PoseFitScore, evaluate_with_progress};
use talkin_render::sequence::split_frames;
use talkin_train::{FitPosesOptions, FittedPoses, fit_held_out_poses};

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
    /// Render with this sampler instead of the one the run trained with: `dense` checks
    /// that the accelerated sampler's samples lose nothing the field holds.
    #[arg(long)]
    pub sampler: Option<talkin_grids::SamplerKind>,
    /// Also score the frames after a test-time fit of their poses with the model frozen
    /// (InstantAvatar's evaluation of novel poses): STEPS steps of the training loss per
    /// frame move each frame's correction alone, on the CPU, from the fit as given (on
    /// training frames, in place of the run's refinement); reported beside the plain
    /// score (JSON `pose_fit`), never instead of it. 0: no fit.
    #[arg(long, value_name = "STEPS", default_value_t = 0)]
    pub pose_fit: usize,
    /// The pose fit's Adam rate (radians a step; translation at 0.2x, metres).
    #[arg(long, default_value_t = FitPosesOptions::default().lr)]
    pub pose_fit_lr: f64,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let split: Split = args.split.parse().map_err(anyhow::Error::msg)?;
    let device = args.device.open()?;
    let mut dataset = super::load_dataset(&args.data)?;
    let frames = split_frames(&dataset, split)?;
    // The fit sees the frames as training did (before they are shown over the scoring
    // background).
    let fitted = (args.pose_fit > 0)
        .then(|| fit_poses(&args, &dataset, &frames))
        .transpose()?;
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
    if let Some(kind) = args.sampler {
        avatar.sampler = kind;
    }
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
    if let Some((fit, fit_opts)) = fitted {
        let mut refined = avatar.refined.take().unwrap_or_else(|| RefinedFits {
            dataset_sha256: fit.fits.dataset_sha256.clone(),
            delta: Default::default(),
        });
        refined
            .delta
            .extend(fit.fits.delta.iter().map(|(&i, d)| (i, d.clone())));
        avatar.refined = Some(refined);
        let fit_renders = staging.path().join("pose_fit");
        let opts = EvalOptions {
            renders_dir: Some(fit_renders),
            ..opts
        };
        let progress = Progress::new("evaluating the fitted poses", frames.len(), "frames");
        let after = evaluate_with_progress(&avatar, &dataset, &frames, &opts, &mut |done, _| {
            progress.update(done, "")
        })
        .context("evaluating the fitted poses")?;
        report.pose_fit = Some(PoseFitScore {
            steps_per_frame: fit_opts.steps_per_frame,
            lr: fit_opts.lr,
            seconds: fit.seconds,
            rotation_rms_deg: fit.rotation_rms_deg,
            translation_mean_m: fit.translation_mean_m,
            corrections: fit.fits.delta.into_iter().collect(),
            report: Box::new(after),
        });
    }
    // Each score names its PNG where it will be, not where it was written.
    let fit_frames = report
        .pose_fit
        .iter_mut()
        .flat_map(|f| &mut f.report.frames);
    for score in report.frames.iter_mut().chain(fit_frames) {
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

/// The test-time fit of `frames`' poses to the run (its log in a scratch directory that
/// is removed after).
fn fit_poses(
    args: &EvalArgs,
    dataset: &Dataset,
    frames: &[usize],
) -> anyhow::Result<(FittedPoses, FitPosesOptions)> {
    let opts = FitPosesOptions {
        steps_per_frame: args.pose_fit,
        lr: args.pose_fit_lr,
    };
    let scratch = tempfile::tempdir().context("a scratch directory for the pose fit")?;
    let progress = Progress::new(
        "fitting poses",
        opts.steps_per_frame * frames.len(),
        "steps",
    );
    let fitted = fit_held_out_poses(
        dataset,
        &args.run,
        frames,
        &opts,
        scratch.path(),
        &mut |done, _| progress.update(done, ""),
    )
    .with_context(|| {
        format!(
            "fitting the poses of {} to {}",
            args.data.display(),
            args.run.display()
        )
    })?;
    Ok((fitted, opts))
}
