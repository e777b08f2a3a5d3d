//! The PeopleSnapshot importer on fixture captures: its split rules and their errors.

use super::splits::*;
use super::*;
use crate::Format;
use talkin_data::array::{ArrayData, NdArray};
use talkin_data::npz::NpzWriter;
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
    talkin_data::smplx_model::fixture::write_fixture(&model, &PARENTS);
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
