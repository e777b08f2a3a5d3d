use std::path::PathBuf;

use anyhow::{Context, bail};
use talkin_data::dataset::Dataset;
use talkin_data::inspect;
use talkin_train::TrainOptions;
use talkin_train::plan::Plan;

use crate::progress::Progress;

#[derive(clap::Args, Debug)]
pub struct InspectArgs {
    /// Dataset directory (holding dataset.json).
    pub dir: PathBuf,
    /// Write a contact sheet (frames with segmentation overlay and projected skeleton).
    #[arg(long)]
    pub sheet: Option<PathBuf>,
    /// Most frames on the contact sheet and on the overlay.
    #[arg(long, default_value_t = 16)]
    pub sheet_frames: usize,
    /// Write the overlay check: frames (flagged ones first) with the fitted capsules'
    /// outlines and the skeleton drawn on the image, captioned with the share of body
    /// joints on the person.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Write per-frame posed 3D joints and their 2D projections as JSON.
    #[arg(long)]
    pub joints_json: Option<PathBuf>,
}

pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let dataset = Dataset::load(&args.dir)?;
    if let Some(note) = inspect::extra_expression_note(&args.dir) {
        tracing::warn!("{note}");
    }
    let progress = Progress::new("decoding", dataset.frames.len(), "frames");
    let summary = inspect::summarize(&dataset, &|done| progress.update(done, ""))?;
    println!(
        "{}: valid talkin dataset, {} frames",
        args.dir.display(),
        dataset.frames.len()
    );
    println!("{summary}");
    // What `talkin train` with no other flag would build from these frames.
    let plan = Plan::for_run(
        &dataset,
        TrainOptions::default().for_dataset(&dataset, |_| false),
        |_| false,
    )
    .map(|opts| opts.plan);
    match plan {
        Ok(Some(plan)) => print!("{}", plan.describe()),
        Ok(None) => {}
        // A dataset without training frames has nothing to plan; the problems below say so.
        Err(e) => println!("no plan: {e}"),
    }
    if let Some(path) = &args.sheet {
        let (sheet, frames) = inspect::contact_sheet(&dataset, args.sheet_frames)?;
        sheet
            .save(path)
            .with_context(|| format!("writing contact sheet {}", path.display()))?;
        println!("contact sheet: {} (frames {:?})", path.display(), frames);
    }
    if let Some(path) = &args.overlay {
        let frames = inspect::overlay_frames(&summary, args.sheet_frames);
        inspect::overlay_sheet(&dataset, &summary, &frames)?
            .save(path)
            .with_context(|| format!("writing overlay {}", path.display()))?;
        println!("overlay: {} (frames {:?})", path.display(), frames);
    }
    if let Some(path) = &args.joints_json {
        let joints: Vec<_> = (0..dataset.frames.len())
            .map(|i| inspect::frame_joints(&dataset, i))
            .collect();
        let text = serde_json::to_string(&joints)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("joints: {}", path.display());
    }
    println!(
        "projected body joints on the person, per frame (flagged below {:.0}%):",
        100.0 * inspect::FRAME_MIN_JOINTS_ON_PERSON
    );
    let problems = summary.problems();
    for p in problems.iter().filter(|p| !p.fatal) {
        println!("  flagged {}: {}", p.field, p.message);
    }
    if problems.iter().all(|p| p.fatal) {
        println!("  no frame flagged");
    }
    let fatal: Vec<_> = problems.iter().filter(|p| p.fatal).collect();
    if let Some(first) = fatal.first() {
        for p in &fatal {
            eprintln!(
                "problem: {}: field `{}`: {}",
                dataset_file(&args.dir),
                p.field,
                p.message
            );
        }
        bail!(
            "{}: {} problem(s), first: field `{}`: {}",
            dataset_file(&args.dir),
            fatal.len(),
            first.field,
            first.message
        );
    }
    Ok(())
}

fn dataset_file(dir: &std::path::Path) -> String {
    dir.join(talkin_data::dataset::INDEX_FILE)
        .display()
        .to_string()
}
