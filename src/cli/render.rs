use std::path::{Path, PathBuf};

use anyhow::Context;
use talkin_avatar::Avatar;
use talkin_data::atomic::StagedDir;
use talkin_data::dataset::{Dataset, Split};
use talkin_data::motion::{Motion, MotionLayout, Prepare};
use talkin_data::smplx_model::SmplxModel;
use talkin_human::camera::Camera;
use talkin_human::smooth::Smoothing;
use talkin_render::sequence::{
    PoseSource, PosedCamera, Shot, default_camera, motion_poses, read_pose_source, render_sequence,
    shots_from_frames, shots_from_poses, smooth_shots, split_frames,
};

use crate::progress::Progress;

#[derive(clap::Args, Debug)]
#[command(group(
    clap::ArgGroup::new("source").required(true).args(["data", "poses", "motion"])
))]
pub struct RenderArgs {
    /// The trained run (its newest checkpoint is rendered).
    #[arg(long)]
    pub run: PathBuf,
    /// Dataset whose split's poses and cameras to render (with ground truth: a contact
    /// sheet ground truth | render | error is written too).
    #[arg(long, requires = "split")]
    pub data: Option<PathBuf>,
    /// The split of --data: train, test_same, test_cross or test_ood.
    #[arg(long, requires = "data")]
    pub split: Option<String>,
    /// A poses file ({"frames": [{"params": {...}, "camera": {...}}, ...]} with
    /// dataset.json's `params` and `camera` objects), or a motion file as for --motion.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// A motion file: a BEAT2 or AMASS .npz (`poses` N x 165, ...) or a JSON list of
    /// `params` objects, seen through the subject's default camera (or --camera-from).
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// Output directory: frame_0000.png, ... (and contact_sheet.png). Written in full or
    /// not at all.
    #[arg(long)]
    pub out: PathBuf,
    /// Render every pose as this trained subject (default: each dataset frame's own
    /// subject; for --poses and --motion, the only trained subject).
    #[arg(long)]
    pub subject: Option<String>,
    /// Smooth poses and cameras over time (Gaussian, window 5, sigma 1), per subject in
    /// time order for dataset splits, in file order otherwise.
    #[arg(long)]
    pub smooth: bool,
    /// Motions: force the .npz layout instead of telling it from the keys.
    #[arg(long, value_name = "beat2|amass")]
    pub motion_layout: Option<MotionLayout>,
    /// Motions: the camera of the subject's first frame (by time) in this dataset instead
    /// of the subject's default camera.
    #[arg(long, value_name = "DATASET")]
    pub camera_from: Option<PathBuf>,
    /// Motions: frames per second to render (resampled by slerp; default the file's).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Motions: the SMPL-X model file (SMPLX_NEUTRAL.npz, ...): adds its mean hand to
    /// hand poses stored relative to it (BEAT2) and places the motion by its rest pelvis.
    #[arg(long, value_name = "MODEL")]
    pub body_model: Option<PathBuf>,
    /// Motions: keep the file's translation (turned y-up) instead of starting the motion
    /// at the subject's rest position.
    #[arg(long)]
    pub keep_trans: bool,
    /// Motions with the default camera: image height in pixels (width is 3/4 of it).
    #[arg(long, default_value_t = 192)]
    pub size: u32,
    /// Render over this colour instead of the training background: three numbers in
    /// [0, 1] (`0,0,0` is black). Whatever the field draws around the person shows over
    /// it; a contact sheet's ground truth keeps the dataset's background, so its error
    /// column shows it too.
    #[arg(long, value_name = "R,G,B")]
    pub background: Option<String>,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let motion_only = [
        (args.camera_from.is_some(), "--camera-from"),
        (args.fps.is_some(), "--fps"),
        (args.body_model.is_some(), "--body-model"),
        (args.keep_trans, "--keep-trans"),
        (args.motion_layout.is_some(), "--motion-layout"),
    ];
    if args.data.is_some()
        && let Some((_, flag)) = motion_only.iter().find(|(given, _)| *given)
    {
        anyhow::bail!("{flag} applies to --motion and --poses, not to --data");
    }
    if !(16..=4096).contains(&args.size) {
        anyhow::bail!("--size {} is not in 16..=4096 pixels", args.size);
    }
    // Read every input before the checkpoint, so that a bad file fails fast.
    let source = match args.motion.as_ref().or(args.poses.as_ref()) {
        Some(file) => Some(read_pose_source(file, args.motion_layout)?),
        None => None,
    };
    if matches!(source, Some(PoseSource::Posed(_)))
        && let Some((_, flag)) = motion_only
            .iter()
            .find(|(given, flag)| *given && *flag != "--motion-layout")
    {
        anyhow::bail!("{flag} applies to motion files; this poses file brings its own cameras");
    }
    let model = match &args.body_model {
        Some(m) => Some(SmplxModel::load(m)?),
        None => None,
    };
    let background = args
        .background
        .as_deref()
        .map(super::parse_rgb)
        .transpose()?;
    let mut avatar = args.device.load_avatar(&args.run)?;
    if let Some(rgb) = background {
        avatar.background = rgb;
    }
    let subject = args.subject.as_deref();
    let (dataset, mut shots) = match (&args.data, &args.split, source) {
        (Some(dir), Some(split), _) => {
            let split: Split = split.parse().map_err(anyhow::Error::msg)?;
            let dataset = super::load_dataset(dir)?;
            let frames = split_frames(&dataset, split)?;
            let shots = shots_from_frames(&avatar, &dataset, &frames, subject)?;
            (Some(dataset), shots)
        }
        (_, _, Some(PoseSource::Posed(poses))) => {
            (None, shots_from_poses(&avatar, &poses, subject)?)
        }
        (_, _, Some(PoseSource::Motion(motion))) => {
            (None, motion_shots(&args, &avatar, &motion, model.as_ref())?)
        }
        _ => anyhow::bail!("give --data DIR --split NAME, --poses FILE or --motion FILE"),
    };
    if args.smooth {
        smooth_shots(&mut shots, &Smoothing::PAPER)?;
    }
    let progress = Progress::new("rendering", shots.len(), "frames");
    // Rendered into a hidden directory beside --out, moved there only when complete; an
    // error (a full disk) removes it.
    let staging = StagedDir::new(&args.out).with_context(|| args.out.display().to_string())?;
    let renders = render_sequence(
        &avatar,
        &shots,
        dataset.as_ref(),
        staging.path(),
        &mut |done, _| progress.update(done, ""),
    )?;
    staging
        .publish()
        .with_context(|| args.out.display().to_string())?;
    println!(
        "rendered {} frames to {} in {:.1} s ({:.2} s a frame, {:.0} samples a frame)",
        renders.frames.len(),
        args.out.display(),
        renders.seconds,
        renders.seconds / renders.frames.len().max(1) as f64,
        renders.samples as f64 / renders.frames.len().max(1) as f64
    );
    if renders.contact_sheet.is_some() {
        println!(
            "contact sheet (ground truth | render | error): {}",
            args.out.join(talkin_render::sequence::SHEET_FILE).display()
        );
    }
    Ok(())
}

/// The shots of a motion file: prepared for the subject's skeleton, seen through its
/// default camera or its first camera in --camera-from.
fn motion_shots(
    args: &RenderArgs,
    avatar: &Avatar,
    motion: &Motion,
    model: Option<&SmplxModel>,
) -> anyhow::Result<Vec<Shot>> {
    let name = match args.subject.as_deref() {
        Some(n) => n.to_string(),
        None => match avatar.trained_subjects().as_slice() {
            [only] => only.to_string(),
            names => anyhow::bail!(
                "the avatar has {} trained subjects ({}): name one with --subject",
                names.len(),
                names.join(", ")
            ),
        },
    };
    let (_, subject) = avatar.subject(&name)?;
    let prepared = motion.prepare(&Prepare {
        subject: &subject.skeleton,
        model,
        fps: args.fps,
        keep_trans: args.keep_trans,
    })?;
    for note in &prepared.notes {
        tracing::warn!("{note}");
    }
    let camera = match &args.camera_from {
        Some(dir) => first_camera(dir, &name)?,
        None => default_camera(&subject.skeleton, args.size * 3 / 4, args.size)
            .context("the subject's default camera")?,
    };
    tracing::info!(
        "{} motion {}: {} frames{} as `{name}`",
        motion.layout,
        motion.file.display(),
        prepared.frames.len(),
        prepared
            .fps
            .map_or(String::new(), |f| format!(" at {f} fps"))
    );
    let poses: Vec<PosedCamera> = motion_poses(&prepared.frames, camera);
    Ok(shots_from_poses(avatar, &poses, Some(&name))?)
}

/// The camera of subject `name`'s earliest frame in the dataset `dir`.
fn first_camera(dir: &Path, name: &str) -> anyhow::Result<Camera> {
    let dataset = Dataset::load(dir)
        .with_context(|| format!("cannot load the dataset in {}", dir.display()))?;
    let s = dataset
        .subjects
        .iter()
        .position(|s| s.name == name)
        .with_context(|| {
            format!(
                "{}: no subject `{name}` (it has {})",
                dir.display(),
                dataset
                    .subjects
                    .iter()
                    .map(|s| s.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?;
    dataset
        .frames
        .iter()
        .filter(|f| f.subject == s)
        .min_by(|a, b| a.time.total_cmp(&b.time))
        .map(|f| f.camera)
        .with_context(|| format!("{}: subject `{name}` has no frames", dir.display()))
}
