//! `talkin export-poses`: a run's refined training fits, written in the dataset's own
//! layout (a `dataset.json` whose training frames carry the refined parameters: a poses
//! file for `talkin render --poses`, and an index the dataset can be retrained from).

use std::path::{Path, PathBuf};

use talkin_avatar::checkpoint::{Checkpoint, STATE_FILE, dataset_sha256, path_json};
use talkin_avatar::refined::RefinedFits;
use talkin_data::dataset::{Dataset, write_atomic};

use crate::error::TrainError;

/// What an export wrote.
#[derive(Clone, Debug)]
pub struct ExportSummary {
    /// The dataset the fits were read from.
    pub data: PathBuf,
    /// Frames written with refined parameters.
    pub refined_frames: usize,
    /// Frames written as fitted (held-out frames, untrained subjects).
    pub fitted_frames: usize,
}

/// Writes `run`'s refined training fits to `out` (atomically), reading the fits from
/// `data`, or from the dataset the run recorded when `None`.
pub fn export_poses(
    run: &Path,
    data: Option<&Path>,
    out: &Path,
) -> Result<ExportSummary, TrainError> {
    let checkpoint = Checkpoint::load(run)?;
    let state_file = checkpoint.dir.join(STATE_FILE);
    let resume_error = |problem: String| TrainError::Resume {
        file: state_file.clone(),
        problem,
    };
    let refined = RefinedFits::from_state_json(&checkpoint.state)
        .map_err(resume_error)?
        .ok_or_else(|| {
            resume_error(
                "no `pose_refinement`: the run trusted its fits (train with \
                 `--refine-poses` to refine them)"
                    .into(),
            )
        })?;
    let data = match data {
        Some(d) => d.to_path_buf(),
        None => checkpoint
            .state
            .get("data")
            .ok_or_else(|| resume_error("`data`: missing".into()))
            .and_then(|v| {
                path_json::from_json(v).map_err(|e| resume_error(format!("`data`: {e}")))
            })?,
    };
    let mut dataset = Dataset::load(&data)?;
    let sha = dataset_sha256(&dataset)?;
    if sha != refined.dataset_sha256 {
        return Err(TrainError::Resume {
            file: data.join(talkin_data::dataset::INDEX_FILE),
            problem: format!(
                "not the dataset {} was trained on (SHA-256 {} against the run's {})",
                run.display(),
                sha,
                refined.dataset_sha256
            ),
        });
    }
    let mut refined_frames = 0;
    for i in 0..dataset.frames.len() {
        if let Some(p) = refined.params(&dataset, &sha, i) {
            dataset.frames[i].params = p;
            refined_frames += 1;
        }
    }
    let text =
        serde_json::to_string_pretty(&dataset.to_json()).map_err(|e| TrainError::Resume {
            file: out.to_path_buf(),
            problem: format!("cannot serialise: {e}"),
        })?;
    write_atomic(out, text.as_bytes())?;
    Ok(ExportSummary {
        refined_frames,
        fitted_frames: dataset.frames.len() - refined_frames,
        data,
    })
}
