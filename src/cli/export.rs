use std::path::PathBuf;

use anyhow::Context;
use talkin_data::motion::{MotionLayout, Prepare};
use talkin_export::animation::{DEFAULT_FPS, keyframes};
use talkin_export::{RESOLUTIONS, SurfaceOptions, export_avatar, glb};
use talkin_render::sequence::{PoseSource, read_pose_source};

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// The trained run (its newest checkpoint is exported).
    #[arg(long)]
    pub run: PathBuf,
    /// The trained subject to export.
    #[arg(long)]
    pub subject: String,
    /// The binary glTF to write (.glb); written in full or not at all.
    #[arg(long)]
    pub out: PathBuf,
    /// Cells along the longest side of the subject's canonical box (16..=512): the
    /// surface's detail; the export's time grows with its cube.
    #[arg(long, default_value_t = talkin_export::DEFAULT_RESOLUTION)]
    pub resolution: u32,
    /// The density (1/m) whose level set is the surface.
    #[arg(long, default_value_t = talkin_export::surface::DEFAULT_LEVEL)]
    pub level: f32,
    /// A motion to add as the glTF's animation: a BEAT2 or AMASS .npz or a JSON list of
    /// `params` objects, as `render --motion` takes.
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// Motions: force the .npz layout instead of telling it from the keys.
    #[arg(long, value_name = "beat2|amass")]
    pub motion_layout: Option<MotionLayout>,
    /// Motions: frames per second (resampled by slerp; default the file's, else 30).
    #[arg(long)]
    pub fps: Option<f64>,
    #[command(flatten)]
    pub device: super::DeviceArg,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    if !RESOLUTIONS.contains(&args.resolution) {
        anyhow::bail!(
            "--resolution {} is not in {}..={} cells",
            args.resolution,
            RESOLUTIONS.start(),
            RESOLUTIONS.end()
        );
    }
    if !(args.level.is_finite() && args.level > 0.0) {
        anyhow::bail!("--level {}: expected a density > 0 (1/m)", args.level);
    }
    // Read the motion before the checkpoint, so that a bad file fails fast.
    let motion = match &args.motion {
        None => None,
        Some(file) => match read_pose_source(file, args.motion_layout)
            .with_context(|| format!("--motion {}", file.display()))?
        {
            PoseSource::Motion(m) => Some(m),
            PoseSource::Posed(_) => anyhow::bail!(
                "--motion {}: a poses file (frames with cameras), not a motion",
                file.display()
            ),
        },
    };
    let avatar = args.device.load_avatar(&args.run)?;
    let (_, model) = avatar.subject(&args.subject).context("--subject")?;
    let keys = match &motion {
        None => None,
        Some(m) => {
            let prepared = m
                .prepare(&Prepare {
                    subject: &model.skeleton,
                    model: None,
                    fps: args.fps,
                    keep_trans: false,
                })
                .with_context(|| format!("--motion {}", m.file.display()))?;
            for note in &prepared.notes {
                tracing::warn!("{note}");
            }
            let fps = prepared.fps.unwrap_or(DEFAULT_FPS);
            Some(keyframes(&model.skeleton, &prepared.frames, fps))
        }
    };
    let opts = SurfaceOptions {
        resolution: args.resolution,
        level: args.level,
        ..SurfaceOptions::default()
    };
    let exported = export_avatar(&avatar, &args.subject, &opts)?;
    let bytes = glb::to_glb(&exported, keys.as_ref())?;
    talkin_data::atomic::write_atomic(&args.out, &bytes)
        .with_context(|| format!("--out {}", args.out.display()))?;
    println!(
        "exported `{}` to {}: {} vertices, {} triangles, {:.1} MB{} in {:.1} s",
        args.subject,
        args.out.display(),
        exported.surface.positions.len(),
        exported.surface.triangles.len(),
        bytes.len() as f64 / 1e6,
        keys.as_ref().map_or(String::new(), |k| format!(
            ", {} animation keys",
            k.times.len()
        )),
        exported.seconds
    );
    Ok(())
}
