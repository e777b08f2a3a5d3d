//! Pose sequences to render: the frames of a dataset split (ground truth attached) or of a
//! poses file, each bound to an identity of the avatar by subject name, optionally
//! smoothed over time ([`talkin_human::smooth`]), rendered to numbered PNGs with a ground truth |
//! render | error contact sheet where ground truth exists.

mod camera;
mod frames;
mod poses_file;
mod sheet;

use std::path::PathBuf;

pub use camera::{DEFAULT_CAMERA_DISTANCE, default_camera};
pub use frames::{
    SHEET_FILE, SHEET_MAX_FRAMES, SequenceRenders, encode_png, render_sequence, write_png,
};
pub use poses_file::{
    PoseSource, PoseSourceError, PosedCamera, motion_poses, parse_poses, read_pose_source,
    read_poses_file,
};
pub use sheet::{HEAT_FULL_SCALE, SheetRow, comparison_sheet, error_heat, outline};

use talkin_avatar::{Avatar, AvatarError};

use talkin_data::dataset::{Dataset, DatasetError, Split};
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;
use talkin_human::smooth::{SmoothError, Smoothing, smooth_cameras, smooth_params};

/// One frame to render.
#[derive(Clone, Debug)]
pub struct Shot {
    /// The avatar's identity index the frame is rendered as.
    pub identity: usize,
    pub params: FrameParams,
    pub camera: Camera,
    /// Smoothing runs within a track (a subject's clip), in time order.
    pub track: usize,
    /// Seconds (dataset frames) or the frame number (poses files): the order in a track.
    pub time: f64,
    /// The dataset frame whose image is the ground truth, if any.
    pub ground_truth: Option<usize>,
}

/// Why a sequence could not be built or rendered.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Avatar(#[from] AvatarError),
    #[error("smoothing track {track}: {source}")]
    Smooth {
        track: usize,
        #[source]
        source: SmoothError,
    },
    #[error("{}: split `{split}` has no frames", dir.display())]
    EmptySplit { dir: PathBuf, split: Split },
    #[error("{}: frame index {index} out of range (the dataset has {len} frames)", dir.display())]
    FrameIndex {
        dir: PathBuf,
        index: usize,
        len: usize,
    },
    #[error("the avatar has {count} trained subjects ({names}): name one to render as")]
    WhichSubject { count: usize, names: String },
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot encode PNG: {problem}", file.display())]
    Png { file: PathBuf, problem: String },
}

/// The identity `name` of the avatar, or the frame's own subject's.
fn identity(avatar: &Avatar, name: &str) -> Result<usize, SequenceError> {
    Ok(avatar.subject(name)?.0)
}

/// Shots of dataset frames `frames` (in that order), each rendered as its own subject
/// (matched by name: an adapted run may order identities differently) or as `as_subject`.
/// The track is the dataset subject.
pub fn shots_from_frames(
    avatar: &Avatar,
    dataset: &Dataset,
    frames: &[usize],
    as_subject: Option<&str>,
) -> Result<Vec<Shot>, SequenceError> {
    // Training frames of a refining run are posed as refined (held-out frames have no
    // correction: they use their fits as given).
    let fingerprint = match &avatar.refined {
        Some(_) => talkin_avatar::checkpoint::dataset_sha256(dataset).ok(),
        None => None,
    };
    let params_of = |i: usize| {
        avatar
            .refined
            .as_ref()
            .zip(fingerprint.as_deref())
            .and_then(|(r, sha)| r.params(dataset, sha, i))
            .unwrap_or_else(|| dataset.frames[i].params.clone())
    };
    frames
        .iter()
        .map(|&i| {
            let f = dataset
                .frames
                .get(i)
                .ok_or_else(|| SequenceError::FrameIndex {
                    dir: dataset.root.clone(),
                    index: i,
                    len: dataset.frames.len(),
                })?;
            let name = as_subject.unwrap_or(&dataset.subjects[f.subject].name);
            Ok(Shot {
                identity: identity(avatar, name)?,
                params: params_of(i),
                camera: f.camera,
                track: f.subject,
                time: f.time,
                ground_truth: Some(i),
            })
        })
        .collect()
}

/// The frames of `split`, subject by subject, each subject's in time order.
pub fn split_frames(dataset: &Dataset, split: Split) -> Result<Vec<usize>, SequenceError> {
    let mut frames = dataset.split_indices(split);
    if frames.is_empty() {
        return Err(SequenceError::EmptySplit {
            dir: dataset.root.clone(),
            split,
        });
    }
    frames.sort_by(|&a, &b| {
        let (fa, fb) = (&dataset.frames[a], &dataset.frames[b]);
        (fa.subject, fa.time, a)
            .partial_cmp(&(fb.subject, fb.time, b))
            .expect("times are finite")
    });
    Ok(frames)
}

/// Shots of a poses file's frames, in file order, as `as_subject` (needed unless the
/// avatar has exactly one trained subject). One track.
pub fn shots_from_poses(
    avatar: &Avatar,
    poses: &[PosedCamera],
    as_subject: Option<&str>,
) -> Result<Vec<Shot>, SequenceError> {
    let identity = match as_subject {
        Some(name) => identity(avatar, name)?,
        None => {
            let trained = avatar.trained_subjects();
            if trained.len() != 1 {
                return Err(SequenceError::WhichSubject {
                    count: trained.len(),
                    names: trained.join(", "),
                });
            }
            identity(avatar, trained[0])?
        }
    };
    Ok(poses
        .iter()
        .enumerate()
        .map(|(k, p)| Shot {
            identity,
            params: p.params.clone(),
            camera: p.camera,
            track: 0,
            time: k as f64,
            ground_truth: None,
        })
        .collect())
}

/// Smooths every track's pose and camera in time order, in place (the slice's order is
/// kept).
pub fn smooth_shots(shots: &mut [Shot], filter: &Smoothing) -> Result<(), SequenceError> {
    let mut tracks: Vec<usize> = shots.iter().map(|s| s.track).collect();
    tracks.sort_unstable();
    tracks.dedup();
    for track in tracks {
        let mut members: Vec<usize> = (0..shots.len())
            .filter(|&i| shots[i].track == track)
            .collect();
        members.sort_by(|&a, &b| shots[a].time.total_cmp(&shots[b].time).then(a.cmp(&b)));
        let err = |source| SequenceError::Smooth { track, source };
        let params: Vec<FrameParams> = members.iter().map(|&i| shots[i].params.clone()).collect();
        let cameras: Vec<Camera> = members.iter().map(|&i| shots[i].camera).collect();
        let params = smooth_params(&params, filter).map_err(err)?;
        let cameras = smooth_cameras(&cameras, filter).map_err(err)?;
        for ((&i, p), c) in members.iter().zip(params).zip(cameras) {
            shots[i].params = p;
            shots[i].camera = c;
        }
    }
    Ok(())
}
