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

    /// The indices that exist among `n` images, as Python's `sorted(images)[start:end +
    /// 1:skip]` keeps them.
    fn frames(self, n: usize) -> Vec<usize> {
        self.indices().take_while(|&i| i < n).collect()
    }
}

/// The split names of InstantAvatar's files and yaml, in the order the importer keeps a
/// frame that is in two of them, with the split each becomes.
const SPLITS: [(&str, Split); 3] = [
    ("train", Split::Train),
    ("val", Split::TestSame),
    ("test", Split::TestSame),
];

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

/// The subjects [`known_ranges`] names.
const KNOWN_SUBJECTS: [&str; 8] = [
    "male-3-casual",
    "male-4-casual",
    "female-3-casual",
    "female-4-casual",
    "male-2-casual",
    "male-2-sport",
    "male-3-sport",
    "female-4-sport",
];

/// The train, val and test ranges of an InstantAvatar dataset yaml
/// (`confs/dataset/peoplesnapshot/<subject>.yaml`): the blocks `train:`, `val:` and `test:`
/// (under `opt:` there) with `start`, `end` (inclusive) and `skip` (default 1, as
/// InstantAvatar's `opt.get("skip", 1)`). Only block mappings of plain integers are read;
/// other keys, such as `num_workers` or `${...}` references, are ignored.
pub fn parse_splits_yaml(text: &str, file: &Path) -> Result<[Range; 3], ImportError> {
    // Per block `a.b.train`: (start, end, skip).
    type Fields = [Option<usize>; 3];
    let mut blocks: Vec<(String, Fields)> = Vec::new();
    // The open mapping keys: (indent, key).
    let mut open: Vec<(usize, String)> = Vec::new();
    for raw in text.lines() {
        let line = strip_comment(raw);
        if line.trim().is_empty() {
            continue;
        }
        let indent = line.len() - line.trim_start().len();
        while open.last().is_some_and(|(i, _)| *i >= indent) {
            open.pop();
        }
        let Some((key, value)) = line.trim().split_once(':') else {
            continue;
        };
        let (key, value) = (key.trim(), value.trim());
        if value.is_empty() {
            open.push((indent, key.to_string()));
            continue;
        }
        let field = ["start", "end", "skip"].iter().position(|f| *f == key);
        let parent = open.last().map(|(_, k)| k.as_str());
        let (Some(field), Some(parent)) = (field, parent) else {
            continue;
        };
        if !SPLITS.iter().any(|(s, _)| *s == parent) {
            continue;
        }
        let path: Vec<&str> = open.iter().map(|(_, k)| k.as_str()).collect();
        let path = path.join(".");
        let number = value.parse::<usize>().map_err(|_| {
            ImportError::field(
                file,
                format!("{path}.{key}"),
                format!("expected a frame index (a non-negative integer), found {value:?}"),
            )
        })?;
        match blocks.iter_mut().find(|(p, _)| *p == path) {
            Some((_, fields)) => fields[field] = Some(number),
            None => {
                let mut fields = [None; 3];
                fields[field] = Some(number);
                blocks.push((path, fields));
            }
        }
    }
    let range = |split: &str| -> Result<Range, ImportError> {
        let mut found = blocks
            .iter()
            .filter(|(p, _)| p.rsplit('.').next() == Some(split));
        let (path, fields) = found.next().ok_or_else(|| {
            ImportError::file(
                file,
                format!(
                    "no `{split}:` block with `start` and `end` (expected InstantAvatar's \
                     confs/dataset/peoplesnapshot/<subject>.yaml: opt: {split}: start: N, \
                     end: N, skip: N, one key a line)"
                ),
            )
        })?;
        if let Some((other, _)) = found.next() {
            return Err(ImportError::file(
                file,
                format!("two `{split}:` blocks with frame ranges ({path} and {other})"),
            ));
        }
        let get = |k: usize, name: &str| {
            fields[k].ok_or_else(|| {
                ImportError::field(
                    file,
                    format!("{path}.{name}"),
                    "missing (expected a frame index)",
                )
            })
        };
        let r = Range {
            start: get(0, "start")?,
            end: get(1, "end")?,
            skip: fields[2].unwrap_or(1),
        };
        if r.skip == 0 {
            return Err(ImportError::field(
                file,
                format!("{path}.skip"),
                "expected at least 1, found 0",
            ));
        }
        if r.end < r.start {
            return Err(ImportError::field(
                file,
                format!("{path}.end"),
                format!(
                    "expected at least start ({}), found {}: the range is empty",
                    r.start, r.end
                ),
            ));
        }
        Ok(r)
    };
    Ok([range("train")?, range("val")?, range("test")?])
}

/// `line` without a YAML comment (`#` at the start or after a space).
fn strip_comment(line: &str) -> &str {
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        if c == '#' && prev.is_whitespace() {
            return &line[..i];
        }
        prev = c;
    }
    line
}

/// [`parse_splits_yaml`] of `file`.
fn read_splits_yaml(file: &Path) -> Result<[Range; 3], ImportError> {
    let text = std::fs::read_to_string(file).map_err(ImportError::io(file))?;
    parse_splits_yaml(&text, file)
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::{ArrayData, NdArray};
    use crate::import::Format;
    use crate::npz::NpzWriter;
    use talkin_human::body::{FrameParams, PARENTS};

    /// Images of the fixture capture.
    const N: usize = 20;
    /// The fixture's split ranges, InstantAvatar-like: they start at 1, val is test's
    /// first frame, and the skips differ.
    const TRAIN: [usize; 4] = [1, 4, 7, 10];
    const VAL: [usize; 1] = [13];
    const TEST: [usize; 4] = [13, 15, 17, 19];

    /// Frame `i`'s SMPL pose (72) and translation as the files store them (f32): every
    /// frame differs from every other.
    fn pose(i: usize) -> (Vec<f32>, [f32; 3]) {
        let p = (0..72)
            .map(|k| ((i * 31 + k * 7) % 97) as f32 * 0.01 - 0.4)
            .collect();
        (p, [0.05 * i as f32, 0.2, 3.0 + 0.01 * i as f32])
    }

    /// What the import must give frame `i` (poses moved by `offset`, as a refit would).
    fn params(i: usize, offset: f32) -> FrameParams {
        let (p, t) = pose(i);
        let p: Vec<f64> = p.iter().map(|&x| f64::from(x + offset)).collect();
        let t = t.map(|x| f64::from(x + offset));
        params_from_smpl(&p, DVec3::from_array(t))
    }

    fn f32_array(shape: &[usize], v: Vec<f32>) -> NdArray {
        NdArray::f32(shape, v).unwrap()
    }

    /// `poses/anim_nerf_<split>.npz` with the poses of `frames`, each number moved by
    /// `offset` (Anim-NeRF's files are fits of their own, not rows of `poses.npz`).
    fn write_split(file: &Path, frames: &[usize], offset: f32) {
        let n = frames.len();
        let rows: Vec<(Vec<f32>, [f32; 3])> = frames
            .iter()
            .map(|&i| {
                let (p, t) = pose(i);
                (
                    p.iter().map(|x| x + offset).collect(),
                    t.map(|x| x + offset),
                )
            })
            .collect();
        let mut w = NpzWriter::create(file).unwrap();
        w.array("betas", &f32_array(&[1, 10], vec![0.1; 10]))
            .unwrap()
            .array(
                "global_orient",
                &f32_array(
                    &[n, 3],
                    rows.iter().flat_map(|r| r.0[..3].to_vec()).collect(),
                ),
            )
            .unwrap()
            .array(
                "body_pose",
                &f32_array(
                    &[n, 69],
                    rows.iter().flat_map(|r| r.0[3..].to_vec()).collect(),
                ),
            )
            .unwrap()
            .array(
                "transl",
                &f32_array(&[n, 3], rows.iter().flat_map(|r| r.1).collect()),
            )
            .unwrap();
        w.finish().unwrap();
    }

    /// `poses.npz` as `preprocess_PeopleSnapshot.py` writes it: every frame's `thetas`,
    /// `transl`, and `betas` (10,). Row `i` holds frame `rows[i]`'s pose.
    fn write_full(file: &Path, rows: &[usize]) {
        let n = rows.len();
        let mut w = NpzWriter::create(file).unwrap();
        w.array("betas", &f32_array(&[10], vec![0.1; 10]))
            .unwrap()
            .array(
                "thetas",
                &f32_array(&[n, 72], rows.iter().flat_map(|&i| pose(i).0).collect()),
            )
            .unwrap()
            .array(
                "transl",
                &f32_array(&[n, 3], rows.iter().flat_map(|&i| pose(i).1).collect()),
            )
            .unwrap();
        w.finish().unwrap();
    }

    /// A processed subject in a folder named `folder` (not a subject InstantAvatar
    /// names): cameras, `N` images and masks (empty files: the reader only lists them),
    /// the split files with `offset` and, if given, `poses.npz` with those rows; and a
    /// model file. Returns the options importing it.
    fn capture(
        tmp: &tempfile::TempDir,
        folder: &str,
        offset: f32,
        full: Option<&[usize]>,
    ) -> ImportOptions {
        let src = tmp.path().join(folder);
        for d in ["images", "masks", "poses"] {
            std::fs::create_dir_all(src.join(d)).unwrap();
        }
        let mut w = NpzWriter::create(src.join("cameras.npz")).unwrap();
        let k = vec![500.0, 0.0, 270.0, 0.0, 500.0, 540.0, 0.0, 0.0, 1.0];
        let e = (0..16)
            .map(|i| if i % 5 == 0 { 1.0 } else { 0.0 })
            .collect();
        let scalar = |v| NdArray::new(vec![], ArrayData::I64(vec![v])).unwrap();
        w.array("intrinsic", &NdArray::f64(&[3, 3], k).unwrap())
            .unwrap()
            .array("extrinsic", &NdArray::f64(&[4, 4], e).unwrap())
            .unwrap()
            .array("height", &scalar(1080))
            .unwrap()
            .array("width", &scalar(540))
            .unwrap();
        w.finish().unwrap();
        for i in 0..N {
            std::fs::write(src.join(format!("images/image_{i:04}.png")), b"").unwrap();
            std::fs::write(src.join(format!("masks/mask_{i:04}.npy")), b"").unwrap();
        }
        for (name, frames) in [("train", &TRAIN[..]), ("val", &VAL), ("test", &TEST)] {
            write_split(
                &src.join(format!("poses/anim_nerf_{name}.npz")),
                frames,
                offset,
            );
        }
        if let Some(rows) = full {
            write_full(&src.join("poses.npz"), rows);
        }
        let model = tmp.path().join("SMPLX_NEUTRAL.npz");
        crate::smplx_model::tests::write_fixture(&model, &PARENTS);
        ImportOptions {
            body_model: Some(model),
            ..ImportOptions::new(Format::PeopleSnapshot, src, tmp.path().join("out"))
        }
    }

    /// The frames read: image stem, split and parameters, which must be those of the
    /// fixture's ranges (test's first frame kept once, as val's).
    fn assert_fixture_frames(source: &Source, offset: f32) {
        let got: Vec<(&str, Option<Split>)> = source
            .frames
            .iter()
            .map(|f| (f.name.as_str(), f.split))
            .collect();
        let (tr, ts) = (Some(Split::Train), Some(Split::TestSame));
        let want = [
            ("image_0001", tr),
            ("image_0004", tr),
            ("image_0007", tr),
            ("image_0010", tr),
            ("image_0013", ts),
            ("image_0015", ts),
            ("image_0017", ts),
            ("image_0019", ts),
        ];
        assert_eq!(got, want);
        for f in &source.frames {
            let i: usize = f.name["image_".len()..].parse().unwrap();
            assert_eq!(f.params, params(i, offset), "frame {}", f.name);
            assert!(f.image.ends_with(format!("images/{}.png", f.name)));
        }
        assert!(
            source.skipped.iter().any(|s| s.frame == "13"),
            "{:?}",
            source.skipped
        );
    }

    /// The error reading `opts` gives (it must fail).
    fn refusal(opts: &ImportOptions) -> String {
        match read(opts) {
            Ok(s) => panic!(
                "imported {:?}",
                s.frames
                    .iter()
                    .map(|f| (&f.name, f.split))
                    .collect::<Vec<_>>()
            ),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_renamed_folder_finds_its_rows_in_poses_npz() {
        let tmp = tempfile::tempdir().unwrap();
        let all: Vec<usize> = (0..N).collect();
        let opts = capture(&tmp, "my-capture", 0.0, Some(&all));
        let source = read(&opts).unwrap();
        assert_fixture_frames(&source, 0.0);
        assert!(
            source.notes.iter().any(|n| n.contains("by value")),
            "{:?}",
            source.notes
        );
    }

    #[test]
    fn a_renamed_folder_whose_rows_are_not_in_poses_npz_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let all: Vec<usize> = (0..N).collect();
        // Refit poses (as Anim-NeRF's files are): no row of poses.npz equals them.
        let opts = capture(&tmp, "my-capture", 0.003, Some(&all));
        let err = refusal(&opts);
        for needle in ["anim_nerf_train.npz", "poses.npz", "--splits", "my-capture"] {
            assert!(err.contains(needle), "{needle:?} not in: {err}");
        }
        // Without poses.npz nothing says where the rows belong either.
        let tmp = tempfile::tempdir().unwrap();
        let opts = capture(&tmp, "my-capture", 0.0, None);
        let err = refusal(&opts);
        for needle in ["anim_nerf_train.npz", "--splits", "poses.npz"] {
            assert!(err.contains(needle), "{needle:?} not in: {err}");
        }
    }

    #[test]
    fn a_row_equal_to_two_rows_of_poses_npz_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        // Frame 16 holds frame 4's pose: train's row 1 could be either.
        let mut all: Vec<usize> = (0..N).collect();
        all[16] = 4;
        let opts = capture(&tmp, "my-capture", 0.0, Some(&all));
        let err = refusal(&opts);
        for needle in ["anim_nerf_train.npz", "row 1", "4", "16", "--splits"] {
            assert!(err.contains(needle), "{needle:?} not in: {err}");
        }
    }

    #[test]
    fn known_ranges_give_instantavatars_counts() {
        let count = |s: &str| known_ranges(s).unwrap().map(|r| r.indices().count());
        assert_eq!(count("male-3-casual"), [114, 1, 55]);
        assert_eq!(count("male-4-casual"), [110, 1, 36]);
        assert_eq!(count("female-3-casual"), [112, 1, 51]);
        assert_eq!(count("female-4-casual"), [84, 1, 48]);
        assert!(known_ranges("someone-else").is_none());
    }

    #[test]
    fn an_unplaced_file_names_the_subject_its_row_counts_fit() {
        let file = Path::new("anim_nerf_train.npz");
        let msg = |counts: &[usize], n| unplaced(file, "row 0".into(), counts, n).to_string();
        // The row counts of the files InstantAvatar ships for male-3-casual.
        let m = msg(&[114, 1, 55], 676);
        assert!(
            m.contains("--splits") && m.contains("those of male-3-casual)"),
            "{m}"
        );
        let m = msg(&[114, 1, 23], 456);
        assert!(m.contains("those of male-2-casual or male-2-sport)"), "{m}");
        let m = msg(&[4, 1, 4], 20);
        assert!(m.contains("--splits") && !m.contains("those of"), "{m}");
    }

    /// InstantAvatar's `confs/dataset/peoplesnapshot/female-4-sport.yaml` as it is (no
    /// newline at the end).
    const FEMALE_4_SPORT: &str =
        "_target_: instant_avatar.datasets.peoplesnapshot.PeopleSnapshotDataModule
name: peoplesnapshot
subject: female-4-sport
gender: female
opt:
  dataroot: ./data/PeopleSnapshot/${dataset.subject}/
  subject: ${dataset.subject}
  train:
    num_workers: 8
    batch_size: 4
    start: 1
    end: 336
    skip: 4
    downscale: 2
    sampler: ${sampler}
    fitting: ${model.opt.optimize_SMPL.enable}
  val:
    num_workers: 0
    batch_size: 1
    start: 336
    end: 336
    skip: 8
    downscale: 2
  test:
    num_workers: 4
    batch_size: 1
    start: 336
    end: 524
    skip: 4
    downscale: 2";

    /// A yaml of InstantAvatar's layout with the given `(start, end, skip)` per split.
    fn yaml(ranges: [(usize, usize, usize); 3]) -> String {
        let mut s =
            "name: peoplesnapshot\nsubject: my-capture\nopt:\n  dataroot: ./data/x/\n".to_string();
        for (name, (start, end, skip)) in ["train", "val", "test"].into_iter().zip(ranges) {
            s += &format!(
                "  {name}:\n    num_workers: 0\n    start: {start}\n    end: {end}\n    skip: {skip}  # every {skip}th\n    downscale: 2\n"
            );
        }
        s
    }

    /// The fixture's ranges.
    const FIXTURE_RANGES: [(usize, usize, usize); 3] = [(1, 12, 3), (13, 13, 3), (13, 19, 2)];

    #[test]
    fn splits_yaml_reads_instantavatars_files() {
        let file = Path::new("female-4-sport.yaml");
        assert_eq!(
            parse_splits_yaml(FEMALE_4_SPORT, file).unwrap(),
            known_ranges("female-4-sport").unwrap()
        );
        let r = |start, end, skip| Range { start, end, skip };
        assert_eq!(
            parse_splits_yaml(&yaml(FIXTURE_RANGES), file).unwrap(),
            [r(1, 12, 3), r(13, 13, 3), r(13, 19, 2)]
        );
        // skip defaults to 1, as InstantAvatar's opt.get("skip", 1).
        let text = FEMALE_4_SPORT.replace("    skip: 8\n", "");
        assert_eq!(parse_splits_yaml(&text, file).unwrap()[1], r(336, 336, 1));
    }

    #[test]
    fn splits_yaml_names_what_is_wrong() {
        let file = Path::new("s.yaml");
        let err = |text: &str| parse_splits_yaml(text, file).unwrap_err().to_string();
        let e = err(&FEMALE_4_SPORT.replace("start: 336\n    end: 336\n", "start: 336\n"));
        assert!(
            e.contains("s.yaml") && e.contains("opt.val.end") && e.contains("missing"),
            "{e}"
        );
        let e = err(&FEMALE_4_SPORT.replace("skip: 8", "skip: 0"));
        assert!(e.contains("opt.val.skip"), "{e}");
        let e = err(&FEMALE_4_SPORT.replace("start: 1\n", "start: ${x}\n"));
        assert!(e.contains("opt.train.start") && e.contains("${x}"), "{e}");
        let e = err(&FEMALE_4_SPORT.replace("  test:", "  testing:"));
        assert!(e.contains("no `test:` block"), "{e}");
        let e = err(&FEMALE_4_SPORT.replace("end: 524", "end: 300"));
        assert!(e.contains("opt.test.end") && e.contains("empty"), "{e}");
        let e = err(&format!(
            "{FEMALE_4_SPORT}\nother:\n  train:\n    start: 0\n    end: 9\n"
        ));
        assert!(e.contains("two `train:` blocks"), "{e}");
    }

    #[test]
    fn a_renamed_folder_imports_with_its_yaml() {
        let tmp = tempfile::tempdir().unwrap();
        let all: Vec<usize> = (0..N).collect();
        // Refit poses, as InstantAvatar ships: only the yaml places them.
        let opts = capture(&tmp, "my-capture", 0.003, Some(&all));
        let file = tmp.path().join("my-capture.yaml");
        std::fs::write(&file, yaml(FIXTURE_RANGES)).unwrap();
        let opts = ImportOptions {
            splits: Some(file.clone()),
            ..opts
        };
        let source = read(&opts).unwrap();
        assert_fixture_frames(&source, 0.003);
        let note = format!("splits: the ranges of {}", file.display());
        assert!(source.notes.contains(&note), "{:?}", source.notes);

        // A yaml whose ranges do not give one frame per row is refused.
        std::fs::write(&file, yaml([(1, 12, 2), (13, 13, 3), (13, 19, 2)])).unwrap();
        let err = refusal(&opts);
        for needle in [
            "anim_nerf_train.npz",
            "global_orient",
            "(6, 3)",
            "found 4 rows",
        ] {
            assert!(err.contains(needle), "{needle:?} not in: {err}");
        }
    }

    #[test]
    fn a_yaml_picks_rows_of_poses_npz_without_split_files() {
        let tmp = tempfile::tempdir().unwrap();
        let all: Vec<usize> = (0..N).collect();
        let opts = capture(&tmp, "my-capture", 0.0, Some(&all));
        std::fs::remove_dir_all(opts.src.join("poses")).unwrap();
        // Every frame, no splits of its own.
        let source = read(&opts).unwrap();
        assert_eq!(source.frames.len(), N);
        assert!(source.frames.iter().all(|f| f.split.is_none()));
        let file = tmp.path().join("my-capture.yaml");
        std::fs::write(&file, yaml(FIXTURE_RANGES)).unwrap();
        let opts = ImportOptions {
            splits: Some(file),
            ..opts
        };
        assert_fixture_frames(&read(&opts).unwrap(), 0.0);
    }
}
