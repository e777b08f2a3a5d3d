use std::path::PathBuf;

use anyhow::Context;
use talkin_import::{self as import, Format, ImportOptions};

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct ImportArgs {
    /// The tool that wrote SRC: smplerx, humannerf or peoplesnapshot.
    pub format: Format,
    /// The tool's output folder (SMPLer-X's results folder, HumanNeRF's subject folder,
    /// InstantAvatar's PeopleSnapshot subject folder).
    pub src: PathBuf,
    /// The dataset directory to create (must be absent or empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Your SMPL-X model file (SMPLX_NEUTRAL.npz, from smpl-x.is.tue.mpg.de): rest joints
    /// from betas and the mean hand pose. Required for smplerx, peoplesnapshot and
    /// humannerf's metadata.json.
    #[arg(long)]
    pub body_model: Option<PathBuf>,
    /// The frames the fitter ran on (smplerx: the `%06d.jpg` folder; others: SRC/images).
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// One 8-bit PNG mask per frame with the frame's stem (from a matting tool); overrides
    /// the format's masks. Required for smplerx.
    #[arg(long)]
    pub masks: Option<PathBuf>,
    /// The subject's name (default: SRC's folder name).
    #[arg(long)]
    pub subject: Option<String>,
    /// Frame rate of the source frames (default 30).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Keep every Nth frame.
    #[arg(long, default_value_t = 1)]
    pub every: usize,
    /// Hold out every Nth kept frame as test_same (0: none). Default: the format's splits
    /// (peoplesnapshot), else 5.
    #[arg(long)]
    pub test_every: Option<usize>,
    /// Downscale so the longer side is at most PX pixels (intrinsics scaled with it).
    #[arg(long, value_name = "PX")]
    pub max_size: Option<u32>,
    /// smplerx: focal length in pixels of the one camera for the whole video (default
    /// 0.72 x the longer image side, a phone's main camera).
    #[arg(long, value_name = "PX")]
    pub focal: Option<f64>,
    /// peoplesnapshot: InstantAvatar's yaml of the subject
    /// (confs/dataset/peoplesnapshot/<subject>.yaml), whose train, val and test ranges
    /// place the rows of poses/anim_nerf_*.npz. Needed when SRC's folder is not named after
    /// the subject and those rows are not rows of SRC/poses.npz.
    #[arg(long, value_name = "FILE.yaml")]
    pub splits: Option<PathBuf>,
}

pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    let opts = ImportOptions {
        format: args.format,
        src: args.src.clone(),
        out: args.out.clone(),
        body_model: args.body_model,
        images: args.images,
        masks: args.masks,
        subject: args.subject,
        fps: args.fps,
        every: args.every,
        test_every: args.test_every,
        max_size: args.max_size,
        focal: args.focal,
        splits: args.splits,
    };
    let mut progress: Option<Progress> = None;
    let report = import::import(&opts, &mut |done, total| {
        progress
            .get_or_insert_with(|| Progress::new("importing", total, "frames"))
            .update(done, "")
    })
    .with_context(|| {
        format!(
            "cannot import {} as {}",
            args.src.display(),
            args.format.name()
        )
    })?;
    println!("body shape: {}", report.body_shape);
    for s in &report.skipped {
        println!("note: skipped frame {}: {}", s.frame, s.reason);
    }
    for n in &report.notes {
        println!("note: {n}");
    }
    println!(
        "wrote {} frames ({} train, {} test_same) of subject {} to {}; report in import.json",
        report.frames_written,
        report.train,
        report.test_same,
        report.subject,
        args.out.display()
    );
    Ok(())
}

/// What to do when a command was pointed at a fitter's output instead of a dataset: the
/// `talkin import` command that converts it, if `e` is a missing `dataset.json` in a folder
/// whose files give a format away.
pub fn convert_hint(e: &anyhow::Error) -> Option<String> {
    use talkin_data::dataset::{DatasetError, INDEX_FILE};
    e.chain()
        .find_map(|cause| match cause.downcast_ref::<DatasetError>()? {
            DatasetError::Io { file, source }
                if source.kind() == std::io::ErrorKind::NotFound
                    && file.file_name() == Some(INDEX_FILE.as_ref()) =>
            {
                let root = file.parent()?;
                let (format, what) = import::detect_layout(root)?;
                Some(format!(
                    "{} holds {what}, not a dataset: convert it with `talkin import {} {} --out \
                 DATASET` (see docs/bring-your-own-video.md)",
                    root.display(),
                    format.name(),
                    root.display()
                ))
            }
            _ => None,
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fitters_folder_gets_the_import_command() {
        let dir = tempfile::tempdir().unwrap();
        let e = |dir: &std::path::Path| {
            anyhow::Error::new(talkin_data::dataset::Dataset::load(dir).unwrap_err())
                .context("cannot load the dataset")
        };
        assert_eq!(convert_hint(&e(dir.path())), None, "an empty folder");
        for file in ["cameras.pkl", "mesh_infos.pkl"] {
            std::fs::write(dir.path().join(file), b"").unwrap();
        }
        let hint = convert_hint(&e(dir.path())).expect("a hint");
        assert!(hint.contains("talkin import humannerf"), "{hint}");
        assert!(hint.contains("HumanNeRF's prepared layout"), "{hint}");
    }
}
