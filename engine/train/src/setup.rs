//! What a new run is built from: its training frames (all, or a clip of each subject),
//! each trained subject's model, the field's canonical box, and a run directory cleared
//! of any run it held (the recipe file is [`crate::recipe`]'s).

use std::path::{Path, PathBuf};

use glam::Vec3;
use talkin_avatar::checkpoint::CHECKPOINT_DIR;
use talkin_avatar::subject::{SubjectModel, SubjectSlot};
use talkin_data::dataset::{Dataset, Split};
use talkin_nets::FieldConfig;

use crate::error::TrainError;
use crate::step_log::LOG_FILE;

/// What in `out` shows it holds a run (its checkpoint directory or its training log),
/// if anything: a new run there would destroy it.
pub fn existing_run(out: &Path) -> Option<PathBuf> {
    [out.join(CHECKPOINT_DIR), out.join(LOG_FILE)]
        .into_iter()
        .find(|p| p.symlink_metadata().is_ok())
}

/// Clears the run in `out` for a new one: its checkpoints go (a new run's would
/// otherwise sit beside them as fallbacks), and the log and recipe are rewritten by the
/// new run. Anything else in `out` stays.
pub(crate) fn clear_run(out: &Path) -> Result<(), TrainError> {
    let checkpoints = out.join(CHECKPOINT_DIR);
    match std::fs::remove_dir_all(&checkpoints) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(source) => Err(TrainError::Io {
            file: checkpoints,
            source,
        }),
    }
}

/// The training frames of the chosen identities (all with training frames when `None`),
/// each cut to its first `clip_seconds` of video when given.
pub(crate) fn training_frames(
    dataset: &Dataset,
    identities: Option<&[String]>,
    clip_seconds: Option<f64>,
) -> Result<Vec<usize>, TrainError> {
    let index_file = dataset.root.join(talkin_data::dataset::INDEX_FILE);
    let chosen: Vec<usize> = match identities {
        None => (0..dataset.subjects.len()).collect(),
        Some(names) => names
            .iter()
            .map(|n| {
                dataset
                    .subject_index(n)
                    .ok_or_else(|| unknown_subject(dataset, "--identities", n))
            })
            .collect::<Result<_, _>>()?,
    };
    // In dataset order, each frame once (a name may be listed twice).
    let mut frames: Vec<usize> = chosen
        .iter()
        .flat_map(|&s| clip_of(dataset, s, clip_seconds))
        .collect();
    frames.sort_unstable();
    frames.dedup();
    if frames.is_empty() {
        return Err(TrainError::NoTrainFrames { file: index_file });
    }
    Ok(frames)
}

/// Subject `s`'s training frames in time order, cut to those less than `clip_seconds`
/// after its first one (all of them for `None`): the short clip a novel identity is
/// learned from, by adaptation or from scratch.
pub(crate) fn clip_of(dataset: &Dataset, s: usize, clip_seconds: Option<f64>) -> Vec<usize> {
    let mut frames = dataset.subject_frames(s, Split::Train);
    if let Some(limit) = clip_seconds
        && let Some(&first) = frames.first()
    {
        let t0 = dataset.frames[first].time;
        frames.retain(|&i| dataset.frames[i].time - t0 < limit);
    }
    frames
}

/// `field` names a subject `name` the dataset does not have; the error lists those it has.
pub(crate) fn unknown_subject(dataset: &Dataset, flag: &'static str, name: &str) -> TrainError {
    let has: Vec<&str> = dataset.subjects.iter().map(|s| s.name.as_str()).collect();
    TrainError::BadOption {
        flag,
        problem: format!(
            "{} has no subject `{name}` (has: {})",
            dataset
                .root
                .join(talkin_data::dataset::INDEX_FILE)
                .display(),
            has.join(", ")
        ),
    }
}

/// A slot per dataset subject; a model (shells, grid) for those with training frames.
pub(crate) fn fit_subjects(
    dataset: &Dataset,
    frames: &[usize],
    grid_resolution: u32,
) -> Result<Vec<SubjectSlot>, TrainError> {
    (0..dataset.subjects.len())
        .map(|s| {
            let own: Vec<usize> = frames
                .iter()
                .copied()
                .filter(|&i| dataset.frames[i].subject == s)
                .collect();
            let model = if own.is_empty() {
                None
            } else {
                Some(SubjectModel::fit(dataset, s, &own, grid_resolution)?)
            };
            Ok(SubjectSlot {
                name: dataset.subjects[s].name.clone(),
                model,
            })
        })
        .collect()
}

/// The field's canonical box: the union of the grids (every sample the grid keeps maps
/// inside it), padded by 5 cm.
pub(crate) fn fit_field_box(config: &mut FieldConfig, subjects: &[SubjectSlot]) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for m in subjects.iter().filter_map(|s| s.model.as_ref()) {
        let (g_lo, g_hi) = m.grid.aabb();
        lo = lo.min(g_lo);
        hi = hi.max(g_hi);
    }
    if lo.is_finite() && hi.is_finite() {
        let pad = Vec3::splat(0.05);
        config.aabb_min = (lo - pad).to_array();
        config.aabb_max = (hi + pad).to_array();
    }
}
