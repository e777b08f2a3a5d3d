use std::path::PathBuf;

use anyhow::bail;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use talkin_data::dataset::Dataset;
use talkin_data::motion;
use talkin_synth as synth;

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct SynthArgs {
    /// Output directory (created; an existing dataset there is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of identities (subjects).
    #[arg(long, default_value_t = synth::SynthConfig::default().identities)]
    pub identities: usize,
    /// Training frames per identity.
    #[arg(long, default_value_t = synth::SynthConfig::default().frames)]
    pub frames: usize,
    /// Image height in pixels (width is 3/4 of it).
    #[arg(long, default_value_t = synth::SynthConfig::default().size)]
    pub size: u32,
    /// Seed of every random choice: the same arguments give byte-identical output.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Render ground truth for this motion instead of the built-in one: a JSON list of
    /// `params` objects, or a BEAT2 or AMASS .npz (`poses` N x 165, ...; see
    /// docs/dataset-format.md), its frames as stored.
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// The capture-like scene instead of the talking one: the person turns a full circle
    /// while punching and kicking, seen whole by one camera, with the flaws a camera and a
    /// fitter bring, each set by its own flag below (docs/design.md, "Real captures"). With
    /// biased fits, the true poses go to true_fits.json beside dataset.json.
    #[arg(long)]
    pub capture: bool,
    /// With --capture: the width (metres) over which skin bends at every joint (0: rigid,
    /// bone by bone, as the talking scene).
    #[arg(long, value_name = "M", requires = "capture", default_value_t = synth::CaptureConfig::default().smooth_skin_m)]
    pub smooth_skin: f32,
    /// With --capture: the fits' smooth offset, the RMS degrees of every joint's rotation
    /// and the RMS metres of the translation (`0,0`: exact fits).
    #[arg(
        long,
        value_name = "DEG,M",
        requires = "capture",
        default_value = "3,0.01"
    )]
    pub fit_bias: String,
    /// With --capture: write masks only, no depth and no segmentation labels (`on`), as a
    /// matting tool gives, or all four (`off`).
    #[arg(long, value_name = "on|off", requires = "capture", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set)]
    pub masks_only: bool,
    /// What the camera frames: `waist` (from mid-thigh up, both hands kept inside: the
    /// talking scene's), `full-body` (the capture-like scene's), `chest` (head and
    /// shoulders; the hands show only when raised) or `head` (from the collarbones up).
    /// Default: the scene's own.
    #[arg(long, value_name = "waist|full-body|chest|head", value_parser = PossibleValuesParser::new(["waist", "full-body", "chest", "head"]).map(|s| match s.as_str() {
        "full-body" => synth::Framing::FullBody,
        "chest" => synth::Framing::Chest,
        "head" => synth::Framing::Head,
        _ => synth::Framing::Waist,
    }))]
    pub framing: Option<synth::Framing>,
}

/// The capture-like scene's settings from the flags (checked).
fn capture_config(args: &SynthArgs) -> anyhow::Result<Option<synth::CaptureConfig>> {
    if !args.capture {
        return Ok(None);
    }
    if !(args.smooth_skin.is_finite() && (0.0..=0.2).contains(&args.smooth_skin)) {
        bail!(
            "--smooth-skin: {} is not a width in [0, 0.2] metres",
            args.smooth_skin
        );
    }
    let parts: Vec<&str> = args.fit_bias.split(',').map(str::trim).collect();
    let numbers: Option<Vec<f64>> = parts.iter().map(|p| p.parse().ok()).collect();
    let (deg, m) = match numbers.as_deref() {
        Some(&[d, m])
            if d.is_finite()
                && m.is_finite()
                && (0.0..=30.0).contains(&d)
                && (0.0..=0.2).contains(&m) =>
        {
            (d, m)
        }
        _ => bail!(
            "--fit-bias: expected DEG,M (degrees in [0, 30], metres in [0, 0.2]), got `{}`",
            args.fit_bias
        ),
    };
    Ok(Some(synth::CaptureConfig {
        smooth_skin_m: args.smooth_skin,
        fit_bias_deg: deg,
        fit_bias_m: m,
        masks_only: args.masks_only,
    }))
}

pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let dataset = generate(&args)?;
    println!(
        "wrote {} frames of {} subjects to {}",
        dataset.frames.len(),
        dataset.subjects.len(),
        args.out.display()
    );
    Ok(())
}

/// Generates the dataset `args` describe, showing progress.
pub fn generate(args: &SynthArgs) -> anyhow::Result<Dataset> {
    let motion = args.motion.as_ref().map(motion::load_motion).transpose()?;
    let cfg = synth::SynthConfig {
        identities: args.identities,
        frames: args.frames,
        size: args.size,
        seed: args.seed,
        motion,
        capture: capture_config(args)?,
        framing: args.framing,
    };
    let mut progress: Option<Progress> = None;
    let dataset = synth::generate(&cfg, &args.out, &mut |done, total| {
        progress
            .get_or_insert_with(|| Progress::new("synth", total, "frames"))
            .update(done, "")
    })?;
    Ok(dataset)
}
