//! InstantAvatar's processed PeopleSnapshot (tijiang13/InstantAvatar,
//! `scripts/peoplesnapshot/preprocess_PeopleSnapshot.py`, `instant_avatar/datasets/
//! peoplesnapshot.py`): `cameras.npz` (`intrinsic` (3, 3), `extrinsic` (4, 4) world to
//! camera, `height`, `width`), `images/image_XXXX.png` (already undistorted), `masks/
//! mask_XXXX.npy` (uint8 0/1) and per split `poses/anim_nerf_{train,val,test}.npz`
//! (`betas` (1, 10), `global_orient` (N, 3), `body_pose` (N, 69), `transl` (N, 3); SMPL).
//!
//! Row i of a split's poses belongs to image `sorted(images)[start:end + 1:skip][i]` with
//! the split's range from InstantAvatar's `confs/dataset/peoplesnapshot/<subject>.yaml`
//! ([`known_ranges`]; `end` is inclusive). For a folder whose name is not one of those
//! subjects the splits are taken as consecutive runs of frames: train, then val, then test.
//! train becomes `train`, val and test become `test_same`. Without `anim_nerf_*` files,
//! `poses.npz` (`thetas` (N, 72), `transl`, `betas`) gives every frame.

use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{
    ImportError, ImportOptions, MaskFile, Skipped, Source, SourceFrame, load_model, mask_for, mat3,
    mat4, params_from_smpl,
};
use crate::array::Dim;
use crate::dataset::Split;
use crate::npz::Npz;

/// A split's frames: `sorted(images)[start..=end]` every `skip`th.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Range {
    pub start: usize,
    pub end: usize,
    pub skip: usize,
}

impl Range {
    pub fn indices(self) -> impl Iterator<Item = usize> {
        (self.start..=self.end).step_by(self.skip.max(1))
    }
}

/// InstantAvatar's train, val and test ranges of the PeopleSnapshot subjects.
pub fn known_ranges(subject: &str) -> Option<[Range; 3]> {
    let r = |start, end, skip| Range { start, end, skip };
    Some(match subject {
        "male-3-casual" => [r(0, 455, 4), r(456, 456, 4), r(456, 675, 4)],
        "male-4-casual" => [r(0, 659, 6), r(660, 660, 6), r(660, 872, 6)],
        "female-3-casual" => [r(0, 445, 4), r(446, 446, 4), r(446, 647, 4)],
        "female-4-casual" => [r(0, 335, 4), r(335, 335, 4), r(335, 523, 4)],
        "male-2-casual" | "male-2-sport" => [r(1, 455, 4), r(455, 455, 8), r(1, 455, 20)],
        "male-3-sport" => [r(1, 230, 2), r(230, 230, 6), r(230, 460, 6)],
        "female-4-sport" => [r(1, 336, 4), r(336, 336, 8), r(336, 524, 4)],
        _ => return None,
    })
}

struct Poses {
    file: PathBuf,
    betas: Vec<f64>,
    /// (N, 72): root then body.
    poses: Vec<Vec<f64>>,
    transl: Vec<DVec3>,
}

fn read_poses(file: &Path) -> Result<Poses, ImportError> {
    let mut npz = Npz::open(file)?;
    let has_thetas = npz.contains("thetas");
    let mut get = |key: &str, dims: &[Dim]| super::error::npz_f64(&mut npz, key, dims);
    let (betas, _) = match npz_shape(file, "betas")? {
        Some(s) if s.len() == 1 => get("betas", &[Dim::Is(10)])?,
        _ => get("betas", &[Dim::Is(1), Dim::Is(10)])?,
    };
    let (transl, shape) = get("transl", &[Dim::Any("N"), Dim::Is(3)])?;
    let n = shape[0];
    let poses = if has_thetas {
        let (t, _) = get("thetas", &[Dim::Is(n), Dim::Is(72)])?;
        t.chunks_exact(72).map(<[f64]>::to_vec).collect()
    } else {
        let (g, _) = get("global_orient", &[Dim::Is(n), Dim::Is(3)])?;
        let (b, _) = get("body_pose", &[Dim::Is(n), Dim::Is(69)])?;
        (0..n)
            .map(|i| [&g[3 * i..3 * i + 3], &b[69 * i..69 * i + 69]].concat())
            .collect()
    };
    Ok(Poses {
        file: file.to_path_buf(),
        betas,
        poses,
        transl: transl
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect(),
    })
}

/// The shape of array `key` of `file`, if present.
fn npz_shape(file: &Path, key: &str) -> Result<Option<Vec<usize>>, ImportError> {
    Ok(Npz::open(file)?.get(key)?.map(|a| a.shape().to_vec()))
}

fn sorted_files(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, ImportError> {
    if !dir.is_dir() {
        return Err(ImportError::file(dir, "missing"));
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).map_err(ImportError::io(dir))? {
        let path = e.map_err(ImportError::io(dir))?.path();
        if path.extension().is_some_and(|e| e == ext) {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

/// A frame to import: (image index, split, pose set, row in the set).
type Row = (usize, Option<Split>, usize, usize);

/// What [`split_rows`] finds.
struct SplitRows {
    sets: Vec<Poses>,
    rows: Vec<Row>,
    notes: Vec<String>,
    skipped: Vec<Skipped>,
}

/// The pose sets and which image each row belongs to: InstantAvatar's train, val and
/// test files with its ranges (or consecutive), else a single `poses.npz`; sorted by
/// image. Also the notes and the frames skipped.
fn split_rows(opts: &ImportOptions) -> Result<SplitRows, ImportError> {
    let poses_dir = opts.src.join("poses");
    let split_files: Vec<(Split, PathBuf)> = [
        (Split::Train, "train"),
        (Split::TestSame, "val"),
        (Split::TestSame, "test"),
    ]
    .into_iter()
    .map(|(s, name)| (s, poses_dir.join(format!("anim_nerf_{name}.npz"))))
    .collect();
    let mut notes = Vec::new();
    let mut skipped = Vec::new();
    // (image index, split, poses row).
    let mut rows: Vec<Row> = Vec::new();
    let mut sets: Vec<Poses> = Vec::new();
    if split_files.iter().all(|(_, f)| f.is_file()) {
        for (_, f) in &split_files {
            sets.push(read_poses(f)?);
        }
        let folder = super::subject_name(&ImportOptions {
            subject: None,
            ..opts.clone()
        });
        let ranges: Vec<Vec<usize>> = match known_ranges(&folder) {
            Some(r) => {
                notes.push(format!("splits: InstantAvatar's ranges for {folder}"));
                r.iter().map(|r| r.indices().collect()).collect()
            }
            None => {
                notes.push(format!(
                    "splits: {folder} is not a PeopleSnapshot subject InstantAvatar names; train, val and test taken as consecutive frames"
                ));
                let mut start = 0;
                sets.iter()
                    .map(|s| {
                        let r = (start..start + s.poses.len()).collect();
                        start += s.poses.len();
                        r
                    })
                    .collect()
            }
        };
        let mut used = std::collections::HashSet::new();
        for (set, ((split, _), idx)) in split_files.iter().zip(&ranges).enumerate() {
            if idx.len() != sets[set].poses.len() {
                return Err(ImportError::field(
                    &sets[set].file,
                    "global_orient",
                    format!(
                        "expected ({}, 3): one row per frame of the split's range, found {} rows",
                        idx.len(),
                        sets[set].poses.len()
                    ),
                ));
            }
            for (row, &i) in idx.iter().enumerate() {
                if used.insert(i) {
                    rows.push((i, Some(*split), set, row));
                } else {
                    skipped.push(Skipped {
                        frame: format!("{i}"),
                        reason: "in two splits: kept in the first".into(),
                    });
                }
            }
        }
    } else {
        let f = opts.src.join("poses.npz");
        if !f.is_file() {
            return Err(ImportError::file(
                &poses_dir,
                "missing: expected poses/anim_nerf_{train,val,test}.npz or poses.npz",
            ));
        }
        let set = read_poses(&f)?;
        rows = (0..set.poses.len()).map(|i| (i, None, 0, i)).collect();
        sets.push(set);
    }
    rows.sort_by_key(|r| r.0);
    Ok(SplitRows {
        sets,
        rows,
        notes,
        skipped,
    })
}

pub fn read(opts: &ImportOptions) -> Result<Source, ImportError> {
    let model = load_model(opts)?.ok_or_else(|| {
        ImportError::Usage(
            "peoplesnapshot gives betas, not joints: --body-model SMPLX_NEUTRAL.npz is required to build the rest joints".into(),
        )
    })?;
    let cam_file = opts.src.join("cameras.npz");
    let mut cams = Npz::open(&cam_file)?;
    let mut cam = |key: &str, dims: &[Dim]| -> Result<Vec<f64>, ImportError> {
        Ok(super::error::npz_f64(&mut cams, key, dims)?.0)
    };
    let k = mat3(&cam("intrinsic", &[Dim::Is(3), Dim::Is(3)])?);
    let e = mat4(&cam("extrinsic", &[Dim::Is(4), Dim::Is(4)])?);
    let images = sorted_files(
        &opts.images.clone().unwrap_or(opts.src.join("images")),
        "png",
    )?;
    let masks = match opts.masks {
        Some(_) => Vec::new(),
        None => sorted_files(&opts.src.join("masks"), "npy")?,
    };
    let SplitRows {
        sets,
        rows,
        mut notes,
        skipped,
    } = split_rows(opts)?;
    let betas = &sets[0].betas;
    let rest_joints = model.rest_joints(betas)?;
    let fps = opts.fps();
    let mut frames = Vec::new();
    for (i, split, set, row) in rows {
        let image = images.get(i).ok_or_else(|| {
            ImportError::file(
                &opts.src.join("images"),
                format!("has {} frames, the poses need frame {i}", images.len()),
            )
        })?;
        let stem = image
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let default = masks.get(i).cloned().map(MaskFile::Npy);
        if opts.masks.is_none() && default.is_none() {
            return Err(ImportError::file(
                &opts.src.join("masks"),
                format!(
                    "has {} masks, frame {i} needs one (masks are required)",
                    masks.len()
                ),
            ));
        }
        let mask = mask_for(opts, &stem, default)?;
        let s = &sets[set];
        frames.push(SourceFrame {
            name: stem,
            time: i as f64 / fps,
            split,
            image: image.clone(),
            mask,
            intrinsics: k,
            extrinsics: e,
            distortion: None,
            params: params_from_smpl(&s.poses[row], s.transl[row]),
        });
    }
    notes
        .push("SMPL poses: joints 0..21 as given; hands, jaw, eyes and expression are zero".into());
    Ok(Source {
        rest_joints,
        body_shape: format!(
            "{} with the betas of {} (SMPL betas read as SMPL-X's first 10)",
            model.file().display(),
            sets[0].file.display()
        ),
        frames,
        skipped,
        notes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_ranges_give_instantavatars_counts() {
        let count = |s: &str| known_ranges(s).unwrap().map(|r| r.indices().count());
        assert_eq!(count("male-3-casual"), [114, 1, 55]);
        assert_eq!(count("male-4-casual"), [110, 1, 36]);
        assert_eq!(count("female-3-casual"), [112, 1, 51]);
        assert_eq!(count("female-4-casual"), [84, 1, 48]);
        assert!(known_ranges("someone-else").is_none());
    }
}
