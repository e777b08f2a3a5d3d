use std::path::PathBuf;

use anyhow::{Context, bail};
use talkin_data::dataset::Dataset;
use talkin_data::inspect;

use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct InspectArgs {
    /// Dataset directory (holding dataset.json).
    pub dir: PathBuf,
    /// Write a contact sheet (frames with segmentation overlay and projected skeleton).
    #[arg(long)]
    pub sheet: Option<PathBuf>,
    /// Most frames on the contact sheet.
    #[arg(long, default_value_t = 16)]
    pub sheet_frames: usize,
    /// Write per-frame posed 3D joints and their 2D projections as JSON.
    #[arg(long)]
    pub joints_json: Option<PathBuf>,
}

/// Below this fraction of projected body joints on the person, poses or cameras are off.
const MIN_JOINTS_ON_PERSON: f64 = 0.8;

pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.dir)?;
    let progress = Progress::new("decoding frames", dataset.frames.len());
    let summary = inspect::summarize(&dataset, &|done| progress.update(done, ""))?;
    println!(
        "{}: valid talkin dataset, {} frames",
        args.dir.display(),
        dataset.frames.len()
    );
    println!("{summary}");
    if let Some(path) = &args.sheet {
        let (sheet, frames) = inspect::contact_sheet(&dataset, args.sheet_frames)?;
        sheet
            .save(path)
            .with_context(|| format!("writing contact sheet {}", path.display()))?;
        println!("contact sheet: {} (frames {:?})", path.display(), frames);
    }
    if let Some(path) = &args.joints_json {
        let joints: Vec<_> = (0..dataset.frames.len())
            .map(|i| inspect::frame_joints(&dataset, i))
            .collect();
        let text = serde_json::to_string(&joints)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("joints: {}", path.display());
    }
    if summary.mask_seg_disagreement > 0.05 {
        bail!(
            "mask and segmentation disagree on {:.1}% of pixels: they should mark the same person",
            100.0 * summary.mask_seg_disagreement
        );
    }
    if summary.joints_on_person < MIN_JOINTS_ON_PERSON {
        bail!(
            "only {:.0}% of projected body joints land on the person mask: poses or cameras do not line up with the images (check extrinsics are world-to-camera, OpenCV axes; look at the contact sheet)",
            100.0 * summary.joints_on_person
        );
    }
    Ok(())
}
