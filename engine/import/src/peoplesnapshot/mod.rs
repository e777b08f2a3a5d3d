//! InstantAvatar's processed PeopleSnapshot (tijiang13/InstantAvatar,
//! `scripts/peoplesnapshot/preprocess_PeopleSnapshot.py`, `instant_avatar/datasets/
//! peoplesnapshot.py`): `cameras.npz` (`intrinsic` (3, 3), `extrinsic` (4, 4) world to
//! camera, `height`, `width`), `images/image_XXXX.png` (already undistorted), `masks/
//! mask_XXXX.npy` (uint8 0/1), `poses.npz` (every frame: `thetas` (N, 72), `transl`
//! (N, 3), `betas` (10,)) and, where InstantAvatar ships them, per split
//! `poses/anim_nerf_{train,val,test}.npz` (`betas` (1, 10), `global_orient` (N, 3),
//! `body_pose` (N, 69), `transl` (N, 3)); all SMPL.
//!
//! Row i of a split's file belongs to image `sorted(images)[start:end + 1:skip][i]`, the
//! split's range from InstantAvatar's `confs/dataset/peoplesnapshot/<subject>.yaml` (`end`
//! inclusive). The ranges are not consecutive runs: in six of the eight files val's single
//! frame is also test's first, male-2's test frames are all train frames, and some ranges
//! start at 1. They come from, in order: `--splits FILE.yaml` ([`parse_splits_yaml`]); the
//! folder's name when it is one of the eight subjects ([`known_ranges`]); otherwise every
//! row must equal exactly one row of `poses.npz` (pose and translation), whose index is its
//! frame. The split files InstantAvatar ships are fits of their own (train's betas differ
//! from test's), so a renamed copy of one of those subjects needs `--splits`; when nothing
//! places the rows the import stops and says so. train becomes `train`, val and test
//! `test_same`; a frame in two splits is kept once, in the first.
//!
//! Without `anim_nerf_*` files `poses.npz` gives every frame, with no splits of its own;
//! with `--splits` its rows in the yaml's ranges instead, with their splits (what
//! InstantAvatar does when a split has no file).

use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{
    ImportError, ImportOptions, MaskFile, Skipped, Source, SourceFrame, load_model, mask_for, mat3,
    mat4, params_from_smpl,
};
use talkin_data::array::Dim;
use talkin_data::dataset::Split;
use talkin_data::npz::Npz;

mod splits;
#[cfg(test)]
mod tests;

use splits::{KNOWN_SUBJECTS, SPLITS, read_splits_yaml};
pub use splits::{Range, known_ranges, parse_splits_yaml};

struct Poses {
    file: PathBuf,
    betas: Vec<f64>,
    /// (N, 72): root then body.
    poses: Vec<Vec<f64>>,
    transl: Vec<DVec3>,
}

impl Poses {
    /// Rows `a` of `self` and `b` of `other` hold the same pose and translation, up to the
    /// rounding of f32 files.
    fn same_row(&self, a: usize, other: &Poses, b: usize) -> bool {
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * (1.0 + x.abs().max(y.abs()));
        let (ta, tb) = (self.transl[a].to_array(), other.transl[b].to_array());
        self.poses[a]
            .iter()
            .zip(&other.poses[b])
            .chain(ta.iter().zip(&tb))
            .all(|(&x, &y)| close(x, y))
    }
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

/// The pose sets and which of the `n_images` images each row belongs to: InstantAvatar's
/// train, val and test files placed by the first rule that applies (see the module
/// docs), else a single `poses.npz`; sorted by image. Also the notes and the frames
/// skipped.
fn split_rows(opts: &ImportOptions, n_images: usize) -> Result<SplitRows, ImportError> {
    let poses_dir = opts.src.join("poses");
    let full_file = opts.src.join("poses.npz");
    let split_files: Vec<PathBuf> = SPLITS
        .iter()
        .map(|(name, _)| poses_dir.join(format!("anim_nerf_{name}.npz")))
        .collect();
    let given = match &opts.splits {
        Some(f) => Some((read_splits_yaml(f)?, f)),
        None => None,
    };
    let mut notes = Vec::new();
    if !split_files.iter().all(|f| f.is_file()) {
        if !full_file.is_file() {
            return Err(ImportError::file(
                &poses_dir,
                "missing: expected poses/anim_nerf_{train,val,test}.npz or poses.npz",
            ));
        }
        let set = read_poses(&full_file)?;
        let n = set.poses.len();
        let placed: Placed = match given {
            Some((ranges, f)) => {
                notes.push(format!(
                    "splits: the ranges of {} pick rows of poses.npz, as InstantAvatar does without poses/anim_nerf_*.npz",
                    f.display()
                ));
                SPLITS
                    .iter()
                    .zip(ranges)
                    .map(|((_, split), r)| {
                        let frames = r.frames(n_images.min(n));
                        (Some(*split), 0, frames.iter().map(|&i| (i, i)).collect())
                    })
                    .collect()
            }
            None => vec![(None, 0, (0..n).map(|i| (i, i)).collect())],
        };
        return Ok(assign(vec![set], placed, notes));
    }
    let sets = split_files
        .iter()
        .map(|f| read_poses(f))
        .collect::<Result<Vec<_>, _>>()?;
    let folder = super::subject_name(&ImportOptions {
        subject: None,
        ..opts.clone()
    });
    let counts = sets.iter().map(|s| s.poses.len()).collect::<Vec<_>>();
    // The frames of each split's rows.
    let frames: Vec<Vec<usize>> = if let Some((ranges, f)) = given {
        notes.push(format!("splits: the ranges of {}", f.display()));
        ranged(&sets, &ranges, n_images, &f.display().to_string())?
    } else if let Some(ranges) = known_ranges(&folder) {
        notes.push(format!("splits: InstantAvatar's ranges for {folder}"));
        ranged(&sets, &ranges, n_images, &format!("{folder}'s"))?
    } else {
        let why = format!("{folder} is not one of the PeopleSnapshot subjects InstantAvatar names");
        if !full_file.is_file() {
            return Err(unplaced(
                &split_files[0],
                format!(
                    "which frames its rows belong to is unknown: {why}, and there is no poses.npz (every frame) to find the rows in"
                ),
                &counts,
                n_images,
            ));
        }
        let full = read_poses(&full_file)?;
        notes.push(format!(
            "splits: {why}; each row of poses/anim_nerf_*.npz found by value in poses.npz"
        ));
        by_value(&sets, &full, &why, &counts, n_images)?
    };
    let placed = SPLITS
        .iter()
        .zip(frames)
        .enumerate()
        .map(|(set, ((_, split), frames))| {
            let pairs = frames.into_iter().enumerate().map(|(row, i)| (i, row));
            (Some(*split), set, pairs.collect())
        })
        .collect();
    Ok(assign(sets, placed, notes))
}

/// Per split: its split, its pose set, and (image index, row) pairs.
type Placed = Vec<(Option<Split>, usize, Vec<(usize, usize)>)>;

/// The rows of `placed`, each image once (a frame in two splits is kept in the first),
/// sorted by image.
fn assign(sets: Vec<Poses>, placed: Placed, notes: Vec<String>) -> SplitRows {
    let mut first = std::collections::HashMap::new();
    let mut rows: Vec<Row> = Vec::new();
    let mut skipped = Vec::new();
    for (split, set, pairs) in placed {
        for (i, row) in pairs {
            match first.get(&i) {
                None => {
                    first.insert(i, (set, row));
                    rows.push((i, split, set, row));
                }
                Some(&(s0, r0)) => skipped.push(Skipped {
                    frame: format!("{i}"),
                    reason: if sets[s0].same_row(r0, &sets[set], row) {
                        "in two splits: kept in the first".into()
                    } else {
                        "in two splits with different poses: kept the first's".into()
                    },
                }),
            }
        }
    }
    rows.sort_by_key(|r| r.0);
    SplitRows {
        sets,
        rows,
        notes,
        skipped,
    }
}

/// The frames of each split's rows by `ranges` (`source`'s), which must give each file
/// one frame per row.
fn ranged(
    sets: &[Poses],
    ranges: &[Range; 3],
    n_images: usize,
    source: &str,
) -> Result<Vec<Vec<usize>>, ImportError> {
    let mut out = Vec::new();
    for ((set, r), (name, _)) in sets.iter().zip(ranges).zip(SPLITS) {
        let frames = r.frames(n_images);
        if frames.len() != set.poses.len() {
            return Err(ImportError::field(
                &set.file,
                "global_orient",
                format!(
                    "expected ({}, 3): one row per frame of {source} {name} range ({}..={} every {} of {} images), found {} rows",
                    frames.len(),
                    r.start,
                    r.end,
                    r.skip,
                    n_images,
                    set.poses.len()
                ),
            ));
        }
        out.push(frames);
    }
    Ok(out)
}

/// The frames of each split's rows found by value: the index of the one row of `full`
/// (every frame, in order) that holds the same pose and translation.
fn by_value(
    sets: &[Poses],
    full: &Poses,
    why: &str,
    counts: &[usize],
    n_images: usize,
) -> Result<Vec<Vec<usize>>, ImportError> {
    let mut out = Vec::new();
    for set in sets {
        let mut frames = Vec::new();
        for row in 0..set.poses.len() {
            let found: Vec<usize> = (0..full.poses.len())
                .filter(|&i| set.same_row(row, full, i))
                .take(2)
                .collect();
            match found[..] {
                [i] => frames.push(i),
                [] => {
                    return Err(unplaced(
                        &set.file,
                        format!(
                            "row {row} is not a row of {} (pose and translation), so which frame it belongs to is unknown: {why}",
                            full.file.display()
                        ),
                        counts,
                        n_images,
                    ));
                }
                _ => {
                    return Err(unplaced(
                        &set.file,
                        format!(
                            "row {row} equals rows {} and {} of {}, so which frame it belongs to is ambiguous",
                            found[0],
                            found[1],
                            full.file.display()
                        ),
                        counts,
                        n_images,
                    ));
                }
            }
        }
        out.push(frames);
    }
    Ok(out)
}

/// The error for split file `file` whose rows cannot be placed: `problem`, what to pass,
/// and the subject whose ranges give the files' row `counts`, if exactly one does.
fn unplaced(file: &Path, problem: String, counts: &[usize], n_images: usize) -> ImportError {
    let like: Vec<&str> = KNOWN_SUBJECTS
        .into_iter()
        .filter(|s| {
            known_ranges(s).is_some_and(|r| r.map(|r| r.frames(n_images).len())[..] == *counts)
        })
        .collect();
    let hint = match like.len() {
        0 => String::new(),
        _ => format!(
            " (the files' row counts {counts:?} are those of {})",
            like.join(" or ")
        ),
    };
    ImportError::file(
        file,
        format!(
            "{problem}; pass --splits with the subject's yaml from InstantAvatar (confs/dataset/peoplesnapshot/<subject>.yaml){hint}"
        ),
    )
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
    } = split_rows(opts, images.len())?;
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
