//! `talkin import` end to end: a tiny synthetic scene is written in each tool's exact
//! layout (pickles, npz, JSON, JPEG/PNG frames, PNG/npy masks: `common::layouts`), with
//! a small SMPL-X model file of the real layout whose regressor reproduces the scene's
//! rest joints, and the import must bring back the scene's poses, rest joints and
//! cameras. Damaged inputs fail with a message naming the file and field, leaving no
//! output directory.

mod common;

use std::path::Path;
use std::sync::OnceLock;

use common::cli::{
    import_args, import_ok, p, stderr, synth_training_scene, talkin, train_and_test_same,
};
use common::layouts::{
    Clip, SmplerxFixture, f32_array, f64_array, root_in_camera, smplerx_args,
    write_humannerf_prepared, write_humannerf_wild, write_model, write_peoplesnapshot,
    write_smplerx,
};
use glam::{DVec2, DVec3};
use talkin::data::array::NdArray;
use talkin::data::dataset::{Dataset, Frame};
use talkin::data::npz::NpzWriter;
use talkin::human::body::N_JOINTS;
use talkin::import::pickle::{Value, write_protocol4};

/// The scene every fixture is written from: 1 identity, 64 px high.
fn scene() -> &'static Dataset {
    static SCENE: OnceLock<Dataset> = OnceLock::new();
    SCENE.get_or_init(|| common::synthetic_scene("import_scene", 1, 64, 5))
}

/// The scene's frames with their own files, as the layout writers take them.
fn clip() -> &'static Clip<'static> {
    static CLIP: OnceLock<Clip<'static>> = OnceLock::new();
    CLIP.get_or_init(|| Clip::subject0(scene()))
}

/// Runs `talkin import`, which must fail mentioning every `needles` and leave no `out`.
fn import_fails(args: &[&str], out_dir: &Path, needles: &[&str]) {
    let out = talkin(args);
    let err = stderr(&out);
    assert!(!out.status.success(), "import should fail: {args:?}");
    for n in needles {
        assert!(err.contains(n), "expected {n:?} in: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out_dir.exists(), "{} was left behind", out_dir.display());
    let parent = out_dir.parent().unwrap();
    for e in std::fs::read_dir(parent).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.contains(".import-"), "temporary {name} left behind");
    }
}

fn scene_frames() -> Vec<&'static Frame> {
    scene().frames.iter().filter(|f| f.subject == 0).collect()
}

fn rest() -> [DVec3; N_JOINTS] {
    scene().subjects[0].skeleton.rest_joints
}

/// Pixel positions of the posed joints `js` of a frame.
fn projections(ds: &Dataset, f: &Frame, js: std::ops::Range<usize>) -> Vec<DVec2> {
    let posed = ds.subjects[f.subject].skeleton.pose(&f.params);
    js.map(|j| f.camera.project(posed.joint(j)).unwrap().truncate())
        .collect()
}

/// The imported frames bring back the scene's local rotations (joints 1..21 and, when
/// `all`, the rest), and the posed joints project where the scene's do.
fn check_frames(got: &Dataset, joints: std::ops::Range<usize>, all_rotations: bool, px: f64) {
    let want = scene_frames();
    assert_eq!(got.frames.len(), want.len());
    for (g, w) in got.frames.iter().zip(&want) {
        let (lg, lw) = (g.params.local_rotations(), w.params.local_rotations());
        let upto = if all_rotations { N_JOINTS } else { 22 };
        for j in 1..upto {
            assert!(
                (lg[j] - lw[j]).length() < 1e-5,
                "joint {j}: {} vs {}",
                lg[j],
                lw[j]
            );
        }
        let (pg, pw) = (
            projections(got, g, joints.clone()),
            projections(scene(), w, joints.clone()),
        );
        for (j, (a, b)) in pg.iter().zip(&pw).enumerate() {
            assert!((*a - *b).length() < px, "joint {j}: {a} vs {b} px");
        }
        assert_eq!(
            (g.camera.width, g.camera.height),
            (w.camera.width, w.camera.height)
        );
    }
}

fn assert_joints(got: &[DVec3], want: &[DVec3], tol: f64) {
    for (j, (a, b)) in got.iter().zip(want).enumerate() {
        assert!((*a - *b).length() < tol, "rest joint {j}: {a} vs {b}");
    }
}

// ---------------------------------------------------------------------------------------
// HumanNeRF, prepared layout

#[test]
fn humannerf_prepared_brings_back_poses_joints_and_cameras() {
    let src = write_humannerf_prepared(clip(), "import_hn_zju", false, None);
    let out = common::temp_dir("import_hn_zju_out").join("ds");
    let got = import_ok(&[
        "import",
        "humannerf",
        p(&src),
        "--out",
        p(&out),
        "--fps",
        "25",
    ]);
    // Without a model file the body joints are as given, the rest from the template.
    assert_joints(
        &got.subjects[0].skeleton.rest_joints[..22],
        &rest()[..22],
        1e-5,
    );
    check_frames(&got, 0..22, false, 0.5);
    let report = std::fs::read_to_string(out.join("import.json")).unwrap();
    assert!(report.contains("template"), "{report}");
    // Every 5th frame is held out by default.
    assert_eq!(got.frames[4].split.name(), "test_same");

    // With the model file, betas fitted to the body joints give every joint back.
    let model = src.join("SMPLX_TEST.npz");
    write_model(&model, &rest());
    let out = common::temp_dir("import_hn_zju_model").join("ds");
    let got = import_ok(&import_args("humannerf", &src, &out, &model));
    assert_joints(&got.subjects[0].skeleton.rest_joints, &rest(), 1e-5);
    check_frames(&got, 0..22, false, 0.5);
}

#[test]
fn humannerf_prepared_wild_centred_joints_give_the_same_bodies() {
    let src = write_humannerf_prepared(clip(), "import_hn_wild", true, None);
    let out = common::temp_dir("import_hn_wild_out").join("ds");
    let got = import_ok(&["import", "humannerf", p(&src), "--out", p(&out)]);
    let s = rest();
    let centred: Vec<DVec3> = s[..22].iter().map(|j| *j - s[0]).collect();
    assert_joints(&got.subjects[0].skeleton.rest_joints[..22], &centred, 1e-5);
    check_frames(&got, 0..22, false, 0.5);
}

// ---------------------------------------------------------------------------------------
// SMPLer-X

#[test]
fn smplerx_brings_back_poses_joints_and_one_real_camera() {
    let fx = write_smplerx(clip(), "import_smplerx");
    let out = common::temp_dir("import_smplerx_out").join("ds");
    let focal = format!("{}", scene_frames()[0].camera.intrinsics_rows()[0][0]);
    let got = import_ok(&smplerx_args(&fx, &out, &focal));
    assert_joints(&got.subjects[0].skeleton.rest_joints, &rest(), 1e-5);
    check_frames(&got, 0..N_JOINTS, true, 1.5);
    for (i, (g, w)) in got.frames.iter().zip(scene_frames()).enumerate() {
        // The world is the camera frame: the root rotation as the scene's camera sees it.
        assert!((g.params.global_orient - root_in_camera(w)).length() < 1e-5);
        assert!((g.time - i as f64 / 25.0).abs() < 1e-9);
    }
    let report = std::fs::read_to_string(out.join("import.json")).unwrap();
    assert!(report.contains("no person"), "{report}");
}

// ---------------------------------------------------------------------------------------
// HumanNeRF, wild-video input

#[test]
fn humannerf_wild_metadata_brings_back_poses_joints_and_cameras() {
    let (src, model) = write_humannerf_wild(clip(), "import_hn_meta");
    let out = common::temp_dir("import_hn_meta_out").join("ds");
    let got = import_ok(&import_args("humannerf", &src, &out, &model));
    assert_joints(&got.subjects[0].skeleton.rest_joints, &rest(), 1e-5);
    check_frames(&got, 0..22, false, 0.5);
    for (g, w) in got.frames.iter().zip(scene_frames()) {
        assert!((g.params.global_orient - w.params.global_orient).length() < 1e-5);
    }
}

// ---------------------------------------------------------------------------------------
// PeopleSnapshot (InstantAvatar)

#[test]
fn peoplesnapshot_brings_back_poses_joints_cameras_and_splits() {
    let (src, model) = write_peoplesnapshot(clip(), "import_ps");
    let out = common::temp_dir("import_ps_out").join("ds");
    let got = import_ok(&import_args("peoplesnapshot", &src, &out, &model));
    assert_joints(&got.subjects[0].skeleton.rest_joints, &rest(), 1e-5);
    check_frames(&got, 0..22, false, 0.5);
    let n = got.frames.len();
    let splits: Vec<&str> = got.frames.iter().map(|f| f.split.name()).collect();
    assert_eq!(&splits[n - 3..], &["train", "test_same", "test_same"]);
}

#[test]
fn peoplesnapshot_splits_yaml_places_the_rows_of_a_renamed_folder() {
    let (src, model) = write_peoplesnapshot(clip(), "import_ps_yaml");
    // Without poses.npz only the subject's yaml says which frames the rows belong to.
    std::fs::remove_file(src.join("poses.npz")).unwrap();
    let out = common::temp_dir("import_ps_yaml_out").join("ds");
    let base = import_args("peoplesnapshot", &src, &out, &model);
    import_fails(&base, &out, &["anim_nerf_train.npz", "--splits"]);
    let n = scene_frames().len();
    let yaml = common::temp_dir("import_ps_yaml_conf").join("subject.yaml");
    std::fs::write(
        &yaml,
        format!(
            "opt:\n  train:\n    start: 0\n    end: {}\n    skip: 1\n  val:\n    start: {}\n    end: {}\n  test:\n    start: {}\n    end: {}\n",
            n - 3,
            n - 2,
            n - 2,
            n - 2,
            n - 1
        ),
    )
    .unwrap();
    let mut args = base.to_vec();
    args.extend(["--splits", p(&yaml)]);
    let got = import_ok(&args);
    check_frames(&got, 0..22, false, 0.5);
    let splits: Vec<&str> = got.frames.iter().map(|f| f.split.name()).collect();
    assert_eq!(&splits[n - 3..], &["train", "test_same", "test_same"]);
}

// ---------------------------------------------------------------------------------------
// Bad input: one clean message naming file, field and shape; nothing left under --out.

/// Rewrites archive `file` with member `key` replaced (or removed when `None`).
fn patch_npz(file: &Path, key: &str, value: Option<NdArray>) {
    let mut contents = talkin::data::npz::Npz::open(file)
        .unwrap()
        .read_all()
        .unwrap();
    match value {
        Some(v) => contents.arrays.insert(key.into(), v),
        None => contents.arrays.remove(key),
    };
    let mut w = NpzWriter::create(file).unwrap();
    for (k, v) in &contents.arrays {
        w.array(k, v).unwrap();
    }
    w.finish().unwrap();
}

/// Rewrites pickle `file` through `edit`.
fn patch_pickle(file: &Path, edit: impl FnOnce(&mut Vec<(Value, Value)>)) {
    let bytes = std::fs::read(file).unwrap();
    let Value::Dict(mut items) = talkin::import::pickle::parse_pickle(&bytes, file).unwrap() else {
        panic!("not a dict")
    };
    edit(&mut items);
    std::fs::write(file, write_protocol4(&Value::Dict(items))).unwrap();
}

fn set_member(frame: &mut Value, key: &str, v: Value) {
    let Value::Dict(items) = frame else { panic!() };
    for (k, old) in items.iter_mut() {
        if k.as_str() == Some(key) {
            *old = v;
            return;
        }
    }
    items.push((Value::Str(key.into()), v));
}

fn f32_nd(shape: &[usize], v: Vec<f64>) -> NdArray {
    NdArray::f32(shape, v.iter().map(|&x| x as f32).collect()).unwrap()
}

#[test]
fn damaged_smplerx_inputs_are_named_and_leave_nothing() {
    let out_root = common::temp_dir("import_bad_smplerx_out");
    let out = out_root.join("ds");
    let focal = "100";
    let case = |name: &str, damage: &dyn Fn(&SmplerxFixture), needles: &[&str]| {
        let fx = write_smplerx(clip(), &format!("import_bad_smplerx_{name}"));
        damage(&fx);
        import_fails(&smplerx_args(&fx, &out, focal), &out, needles);
    };
    let npz2 = |fx: &SmplerxFixture| fx.results.join("smplx/00002_0.npz");
    case(
        "truncated",
        &|fx| {
            let bytes = std::fs::read(npz2(fx)).unwrap();
            std::fs::write(npz2(fx), &bytes[..bytes.len() / 2]).unwrap();
        },
        &["00002_0.npz"],
    );
    case(
        "betas",
        &|fx| patch_npz(&npz2(fx), "betas", Some(f32_nd(&[1, 9], vec![0.0; 9]))),
        &["00002_0.npz", "betas", "(1, 10)"],
    );
    case(
        "hands",
        &|fx| {
            patch_npz(
                &npz2(fx),
                "left_hand_pose",
                Some(f32_nd(&[12, 3], vec![0.0; 36])),
            )
        },
        &["00002_0.npz", "left_hand_pose", "(15, 3)"],
    );
    case(
        "nan",
        &|fx| {
            patch_npz(
                &npz2(fx),
                "body_pose",
                Some(f32_nd(&[21, 3], [vec![f64::NAN], vec![0.0; 62]].concat())),
            )
        },
        &["00002_0.npz", "body_pose", "(21, 3)", "NaN"],
    );
    case(
        "inf",
        &|fx| {
            patch_npz(
                &npz2(fx),
                "transl",
                Some(f32_nd(&[1, 3], vec![0.0, f64::INFINITY, 3.0])),
            )
        },
        &["00002_0.npz", "transl", "(1, 3)", "inf"],
    );
    case(
        "camera",
        &|fx| std::fs::remove_file(fx.results.join("meta/00002_0.json")).unwrap(),
        &["00002_0.json", "missing"],
    );
    case(
        "mask",
        &|fx| std::fs::remove_file(fx.masks.join("000002.png")).unwrap(),
        &["000002.png", "missing", "mask"],
    );
    case(
        "image",
        &|fx| std::fs::remove_file(fx.images.join("000002.jpg")).unwrap(),
        &["000002.jpg", "missing"],
    );
    case(
        "model",
        &|fx| patch_npz(&fx.model, "hands_meanl", None),
        &["SMPLX_NEUTRAL.npz", "hands_meanl", "(45,)"],
    );
    // No masks at all: SMPLer-X writes none, so --masks is required.
    let fx = write_smplerx(clip(), "import_bad_smplerx_nomasks");
    let mut args = smplerx_args(&fx, &out, focal);
    let at = args.iter().position(|a| *a == "--masks").unwrap();
    args.drain(at..at + 2);
    import_fails(&args, &out, &["--masks", "matting"]);
}

#[test]
fn damaged_humannerf_and_peoplesnapshot_inputs_are_named_and_leave_nothing() {
    let out = common::temp_dir("import_bad_hn_out").join("ds");
    let hn = |name: &str| {
        write_humannerf_prepared(clip(), &format!("import_bad_hn_{name}"), false, None)
    };
    let args = |src: &Path| -> Vec<String> {
        ["import", "humannerf", p(src), "--out", p(&out)]
            .map(String::from)
            .to_vec()
    };
    let run = |src: &Path, needles: &[&str]| {
        let a = args(src);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        import_fails(&a, &out, needles);
    };
    // A frame without a camera.
    let src = hn("nocam");
    patch_pickle(&src.join("cameras.pkl"), |items| {
        items.retain(|(k, _)| k.as_str() != Some("frame_000002"))
    });
    run(
        &src,
        &["cameras.pkl", "frame_000002", "intrinsics", "(3, 3)"],
    );
    // Wrong pose length.
    let src = hn("poses");
    patch_pickle(&src.join("mesh_infos.pkl"), |items| {
        set_member(&mut items[1].1, "poses", f32_array(&[69], vec![0.0; 69]))
    });
    run(&src, &["mesh_infos.pkl", "poses", "(72,)", "[69]"]);
    // NaN in a T-pose joint.
    let src = hn("nan");
    patch_pickle(&src.join("mesh_infos.pkl"), |items| {
        set_member(
            &mut items[0].1,
            "tpose_joints",
            f64_array(&[24, 3], [vec![f64::NAN], vec![0.0; 71]].concat()),
        )
    });
    run(&src, &["mesh_infos.pkl", "tpose_joints", "(24, 3)", "NaN"]);
    // A missing mask, and a truncated pickle.
    let src = hn("mask");
    std::fs::remove_file(src.join("masks/frame_000001.png")).unwrap();
    run(&src, &["frame_000001.png", "missing", "mask"]);
    let src = hn("truncated");
    let bytes = std::fs::read(src.join("cameras.pkl")).unwrap();
    std::fs::write(src.join("cameras.pkl"), &bytes[..bytes.len() - 40]).unwrap();
    run(&src, &["cameras.pkl"]);

    // PeopleSnapshot: wrong betas, a missing npy mask, a model file without a key.
    let (src, model) = write_peoplesnapshot(clip(), "import_bad_ps_betas");
    patch_npz(
        &src.join("poses/anim_nerf_train.npz"),
        "betas",
        Some(f32_nd(&[1, 8], vec![0.0; 8])),
    );
    let ps = |src: &Path, model: &Path, needles: &[&str]| {
        import_fails(
            &[
                "import",
                "peoplesnapshot",
                p(src),
                "--out",
                p(&out),
                "--body-model",
                p(model),
            ],
            &out,
            needles,
        )
    };
    ps(&src, &model, &["anim_nerf_train.npz", "betas", "(1, 10)"]);
    let (src, model) = write_peoplesnapshot(clip(), "import_bad_ps_mask");
    let last = scene_frames().len() - 1;
    std::fs::remove_file(src.join(format!("masks/mask_{last:04}.npy"))).unwrap();
    ps(&src, &model, &["masks", "required"]);
    let (src, model) = write_peoplesnapshot(clip(), "import_bad_ps_model");
    patch_npz(&model, "J_regressor", None);
    ps(
        &src,
        &model,
        &["SMPLX_NEUTRAL.npz", "J_regressor", "(55, 55)"],
    );
}

#[test]
fn a_non_empty_out_is_refused_and_kept() {
    let src = write_humannerf_prepared(clip(), "import_out_busy", false, None);
    let out = common::temp_dir("import_out_busy_out");
    std::fs::write(out.join("keep.txt"), "mine").unwrap();
    let o = talkin(&["import", "humannerf", p(&src), "--out", p(&out)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not empty"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(out.join("keep.txt")).unwrap(),
        "mine"
    );
    // An empty directory is fine.
    std::fs::remove_file(out.join("keep.txt")).unwrap();
    import_ok(&["import", "humannerf", p(&src), "--out", p(&out)]);
}

#[test]
fn humannerf_zju_distortion_is_removed_from_images_and_masks() {
    // Strong enough to move the image corners by about 15% of their radius.
    let c = &scene_frames()[0].camera;
    let r2 = (c.width as f64 / 2.0).powi(2) + (c.height as f64 / 2.0).powi(2);
    let k1 = -0.15 * c.intrinsics_rows()[0][0].powi(2) / r2;
    let d = [k1, 0.0, 0.002, -0.001, 0.0];
    let src = write_humannerf_prepared(clip(), "import_hn_distorted", false, Some(d));
    let out = common::temp_dir("import_hn_distorted_out").join("ds");
    let got = import_ok(&["import", "humannerf", p(&src), "--out", p(&out)]);
    check_frames(&got, 0..22, false, 0.5);
    let report = std::fs::read_to_string(out.join("import.json")).unwrap();
    assert!(report.contains("\"undistorted\": true"), "{report}");
    // The masks come back where the scene has them; the distorted ones are elsewhere.
    let mismatch = |a: &Path, b: &Path| {
        let (a, b) = (
            image::open(a).unwrap().to_luma8(),
            image::open(b).unwrap().to_luma8(),
        );
        let n = a
            .pixels()
            .zip(b.pixels())
            .filter(|(x, y)| (x[0] >= 128) != (y[0] >= 128))
            .count();
        n as f64 / (a.width() * a.height()) as f64
    };
    for (i, (g, w)) in got.frames.iter().zip(scene_frames()).enumerate() {
        let back = mismatch(&out.join(&g.mask), &scene().root.join(&w.mask));
        let stored = mismatch(
            &src.join(format!("masks/frame_{i:06}.png")),
            &scene().root.join(&w.mask),
        );
        assert!(
            back < 0.02 && stored > 2.0 * back,
            "frame {i}: {back} after, {stored} stored"
        );
    }
}

/// Training on an imported dataset does as well as training on the dataset it came from:
/// the synthetic scene written in HumanNeRF's prepared layout (SMPL poses: no fingers,
/// jaw or eyes; no depth, no segmentation) and imported, against the scene itself, with
/// the same frames, budget, seed and recipe (the demo's `--patches 0 --batch 512`), scored
/// on test_same. Run with `cargo test --release --test import -- --ignored --nocapture`
/// (TALKIN_IMPORT_STEPS sets the budget; docs/results.md has the figure).
#[test]
#[ignore = "trains twice (minutes in release)"]
fn training_on_an_imported_dataset_matches_its_source() {
    let steps: usize = std::env::var("TALKIN_IMPORT_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(600);
    let root = common::temp_dir("import_train");
    let data = root.join("source");
    let ds = synth_training_scene(&data);
    let frames = train_and_test_same(&ds);
    let hn = write_humannerf_prepared(
        &Clip::from_files(&ds, frames.clone()),
        "import_train_hn",
        false,
        None,
    );
    let model = root.join("SMPLX_TEST.npz");
    write_model(&model, &ds.subjects[0].skeleton.rest_joints);
    let imported = root.join("imported");
    let got = import_ok(&[
        "import",
        "humannerf",
        p(&hn),
        "--out",
        p(&imported),
        "--body-model",
        p(&model),
        "--test-every",
        "5",
        "--fps",
        "25",
    ]);
    let splits = |fs: &mut dyn Iterator<Item = &Frame>| -> Vec<&'static str> {
        fs.map(|f| f.split.name()).collect()
    };
    assert_eq!(
        splits(&mut got.frames.iter()),
        splits(&mut frames.iter().copied()),
        "the same frames are held out"
    );
    let steps = steps.to_string();
    let mut psnr = Vec::new();
    for (name, dir) in [("source", &data), ("imported", &imported)] {
        let run = root.join(format!("run_{name}"));
        // The paper's loss, without the silhouette term: this compares the data. The
        // term sharpens the source's face and fingers, whose expression, jaw and finger
        // poses SMPL's fits do not carry, and so widens a gap the import cannot close
        // (docs/results.md gives both).
        let o = talkin(&[
            "train",
            "--data",
            p(dir),
            "--out",
            p(&run),
            "--steps",
            &steps,
            "--patches",
            "0",
            "--batch",
            "512",
            "--mask-weight",
            "0",
            // The same recipe for both: the import is a camera capture to `train`, which
            // would give it the capture recipe (and `eval` black) unless told.
            "--mask-edge",
            "0",
            "--random-background",
            "off",
            "--frame-codes",
            "0",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let json = root.join(format!("eval_{name}.json"));
        let o = talkin(&[
            "eval",
            "--run",
            p(&run),
            "--data",
            p(dir),
            "--split",
            "test_same",
            "--json",
            p(&json),
            "--background",
            "declared",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        psnr.push(report["psnr"].as_f64().unwrap());
        println!(
            "{name}: PSNR {:.2}, SSIM {:.4}, face {:.2}, hands {:.2}, person {:.2} dB",
            report["psnr"].as_f64().unwrap(),
            report["ssim"].as_f64().unwrap(),
            report["psnr_face"].as_f64().unwrap_or(f64::NAN),
            report["psnr_hands"].as_f64().unwrap_or(f64::NAN),
            report["psnr_person"].as_f64().unwrap_or(f64::NAN),
        );
    }
    println!(
        "test_same PSNR after {steps} steps: source {:.2} dB, imported {:.2} dB, difference {:.2} dB",
        psnr[0],
        psnr[1],
        psnr[0] - psnr[1]
    );
    assert!((psnr[0] - psnr[1]).abs() < 1.0, "{psnr:?}");
}

#[test]
fn loading_a_fitters_folder_as_a_dataset_suggests_the_import() {
    let src = write_humannerf_prepared(clip(), "import_hint", false, None);
    // The dataset crate names the missing file; the CLI, which knows the importers, says
    // how to convert the folder.
    let err = Dataset::load(&src).unwrap_err().to_string();
    assert!(err.contains("dataset.json"), "{err}");
    let o = talkin(&["inspect", p(&src)]);
    assert!(!o.status.success());
    let said = stderr(&o);
    assert!(said.contains("talkin import humannerf"), "{said}");
    assert!(said.contains("mesh_infos.pkl"), "{said}");
}

#[test]
fn every_and_max_size_keep_frames_and_scale_the_cameras() {
    let src = write_humannerf_prepared(clip(), "import_every", false, None);
    let out = common::temp_dir("import_every_out").join("ds");
    let got = import_ok(&[
        "import",
        "humannerf",
        p(&src),
        "--out",
        p(&out),
        "--every",
        "2",
        "--max-size",
        "32",
        "--test-every",
        "0",
    ]);
    let want: Vec<&Frame> = scene_frames().into_iter().step_by(2).collect();
    assert_eq!(got.frames.len(), want.len());
    for (g, w) in got.frames.iter().zip(&want) {
        assert_eq!(g.split.name(), "train");
        let s = g.camera.height as f64 / w.camera.height as f64;
        assert_eq!(g.camera.width.max(g.camera.height), 32);
        let (pg, pw) = (projections(&got, g, 0..22), projections(scene(), w, 0..22));
        for (a, b) in pg.iter().zip(&pw) {
            assert!(
                (*a - *b * s).length() < 0.5 * s.max(1.0) + 1e-6,
                "{a} vs {}",
                *b * s
            );
        }
    }
}
