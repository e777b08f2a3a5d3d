//! `talkin import` end to end: a tiny synthetic scene is written in each tool's exact
//! layout (pickles, npz, JSON, JPEG/PNG frames, PNG/npy masks), with a small SMPL-X model
//! file of the real layout whose regressor reproduces the scene's rest joints, and the
//! import must bring back the scene's poses, rest joints and cameras. Damaged inputs fail
//! with a message naming the file and field, leaving no output directory.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Arc, OnceLock};

use glam::{DMat3, DVec2, DVec3};
use talkin::data::array::{ArrayData, NdArray};
use talkin::data::dataset::{Dataset, Frame};
use talkin::data::npz::NpzWriter;
use talkin::data::pickle::{Value, write_protocol4};
use talkin::human::body::{
    FrameParams, N_JOINTS, PARENTS, axis_angle_from_rotation, rotation_from_axis_angle,
};
use talkin::human::camera::Camera;

/// The scene every fixture is written from: 1 identity, 64 px high.
fn scene() -> &'static Dataset {
    static SCENE: OnceLock<Dataset> = OnceLock::new();
    SCENE.get_or_init(|| common::synthetic_scene("import_scene", 1, 64, 5))
}

fn talkin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(args)
        .output()
        .unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Runs `talkin import`, which must succeed, and loads the result.
fn import_ok(args: &[&str]) -> Dataset {
    let out = talkin(args);
    assert!(out.status.success(), "import failed: {}", stderr(&out));
    let dir = args[args.iter().position(|a| *a == "--out").unwrap() + 1];
    assert!(Path::new(dir).join("import.json").is_file());
    Dataset::load(dir).unwrap()
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

/// K with OpenCV's pixel centres (integers), as the tools store it.
fn opencv_k(c: &Camera) -> [[f64; 3]; 3] {
    let mut k = c.intrinsics_rows();
    k[0][2] -= 0.5;
    k[1][2] -= 0.5;
    k
}

fn f32_array(shape: &[usize], v: impl IntoIterator<Item = f64>) -> Value {
    Value::array(NdArray::f32(shape, v.into_iter().map(|x| x as f32).collect()).unwrap())
}

fn f64_array(shape: &[usize], v: impl IntoIterator<Item = f64>) -> Value {
    Value::array(NdArray::f64(shape, v.into_iter().collect()).unwrap())
}

fn rows<const N: usize>(m: [[f64; N]; N]) -> Vec<f64> {
    m.iter().flatten().copied().collect()
}

/// SMPL's 24 joints of a 55-joint SMPL-X skeleton: 0..21, then the hands (middle knuckles).
fn smpl24(j: &[DVec3; N_JOINTS]) -> Vec<f64> {
    (0..22)
        .chain([28, 43])
        .flat_map(|i| j[i].to_array())
        .collect()
}

/// SMPL's 72 pose numbers: the root, joints 1..21, zero hands.
fn smpl72(params: &FrameParams, root: DVec3) -> Vec<f64> {
    let mut v: Vec<f64> = root.to_array().to_vec();
    for r in &params.body_pose {
        v.extend(r.to_array());
    }
    v.extend([0.0; 6]);
    v
}

const BETAS: [f64; 10] = [0.8, -0.5, 0.3, 0.2, -0.1, 0.6, -0.4, 0.1, 0.05, -0.2];

/// An SMPL-X model file of the real layout (v1.0: 10 shape and 10 expression columns)
/// whose 55 "vertices" regress one to one onto the joints, shaped so that [`BETAS`] give
/// the scene's rest joints.
fn write_model(file: &Path, rest: &[DVec3; N_JOINTS]) {
    const S: usize = 20;
    let mut seed = 11u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    let shapedirs: Vec<f64> = (0..N_JOINTS * 3 * S).map(|_| 0.02 * rnd()).collect();
    let mut v_template = Vec::with_capacity(N_JOINTS * 3);
    for (j, r) in rest.iter().enumerate() {
        for k in 0..3 {
            let offset: f64 = (0..10)
                .map(|c| shapedirs[(j * 3 + k) * S + c] * BETAS[c])
                .sum();
            v_template.push(r[k] - offset);
        }
    }
    let mut regressor = vec![0.0; N_JOINTS * N_JOINTS];
    for j in 0..N_JOINTS {
        regressor[j * N_JOINTS + j] = 1.0;
    }
    let mut kintree: Vec<i64> = PARENTS.iter().map(|&p| i64::from(p)).collect();
    kintree.extend(0..N_JOINTS as i64);
    let mut w = NpzWriter::create(file).unwrap();
    w.array(
        "v_template",
        &NdArray::f64(&[N_JOINTS, 3], v_template).unwrap(),
    )
    .unwrap()
    .array(
        "shapedirs",
        &NdArray::f64(&[N_JOINTS, 3, S], shapedirs).unwrap(),
    )
    .unwrap()
    .array(
        "J_regressor",
        &NdArray::f64(&[N_JOINTS, N_JOINTS], regressor).unwrap(),
    )
    .unwrap()
    .array(
        "kintree_table",
        &NdArray::new(vec![2, N_JOINTS], ArrayData::I64(kintree)).unwrap(),
    )
    .unwrap()
    .array(
        "hands_meanl",
        &NdArray::f64(&[45], hands_mean(1.0)).unwrap(),
    )
    .unwrap()
    .array(
        "hands_meanr",
        &NdArray::f64(&[45], hands_mean(-1.0)).unwrap(),
    )
    .unwrap();
    w.finish().unwrap();
}

fn hands_mean(side: f64) -> Vec<f64> {
    (0..45)
        .map(|i| match i % 3 {
            0 => 0.1 + 0.002 * i as f64,
            _ => side * 0.05 * ((i % 7) as f64 - 3.0) / 3.0,
        })
        .collect()
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

/// Writes the scene as HumanNeRF's prepare scripts do: ZJU's (raw joints, `distortions`)
/// or the wild script's (pelvis-centred joints). Returns the folder.
fn write_humannerf_prepared(name: &str, centred: bool, distortion: Option<[f64; 5]>) -> PathBuf {
    let dir = common::temp_dir(name);
    for d in ["images", "masks"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    let s = rest();
    let s0 = s[0];
    let origin = if centred { s0 } else { DVec3::ZERO };
    let tpose: Vec<f64> = smpl24(&s.map(|j| j - origin));
    let mut cameras = Vec::new();
    let mut meshes = Vec::new();
    for (i, f) in scene_frames().into_iter().enumerate() {
        let stem = format!("frame_{i:06}");
        std::fs::copy(
            scene().root.join(&f.image),
            dir.join(format!("images/{stem}.png")),
        )
        .unwrap();
        std::fs::copy(
            scene().root.join(&f.mask),
            dir.join(format!("masks/{stem}.png")),
        )
        .unwrap();
        let g = f.params.global_orient;
        let r = rotation_from_axis_angle(g);
        let mut rootless = f.params.clone();
        rootless.global_orient = DVec3::ZERO;
        rootless.transl = DVec3::ZERO;
        let posed = scene().subjects[0].skeleton.pose(&rootless).joints();
        // x_world = R(Rh) x_body + Th; x_body is SMPL without the root (pelvis at S0).
        let th = if centred {
            s0 + f.params.transl
        } else {
            s0 + f.params.transl - r * s0
        };
        let mut cam = vec![
            ("intrinsics", f32_array(&[3, 3], rows(opencv_k(&f.camera)))),
            (
                "extrinsics",
                f64_array(&[4, 4], rows(f.camera.extrinsics_rows())),
            ),
        ];
        if let Some(d) = distortion {
            cam.push(("distortions", f32_array(&[5], d)));
        }
        cameras.push((stem.clone(), Value::dict(cam)));
        meshes.push((
            stem,
            Value::dict([
                ("Rh", f32_array(&[3], g.to_array())),
                ("Th", f64_array(&[3], th.to_array())),
                ("poses", f32_array(&[72], smpl72(&f.params, DVec3::ZERO))),
                (
                    "joints",
                    f64_array(&[24, 3], smpl24(&posed.map(|j| j - origin))),
                ),
                ("tpose_joints", f64_array(&[24, 3], tpose.clone())),
            ]),
        ));
    }
    let write = |file: &str, v: Value| std::fs::write(dir.join(file), write_protocol4(&v)).unwrap();
    write("cameras.pkl", Value::dict(cameras));
    write("mesh_infos.pkl", Value::dict(meshes));
    write(
        "canonical_joints.pkl",
        Value::dict([("joints", f64_array(&[24, 3], smpl24(&s)))]),
    );
    dir
}

#[test]
fn humannerf_prepared_brings_back_poses_joints_and_cameras() {
    let src = write_humannerf_prepared("import_hn_zju", false, None);
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
    let got = import_ok(&[
        "import",
        "humannerf",
        p(&src),
        "--out",
        p(&out),
        "--body-model",
        p(&model),
    ]);
    assert_joints(&got.subjects[0].skeleton.rest_joints, &rest(), 1e-5);
    check_frames(&got, 0..22, false, 0.5);
}

#[test]
fn humannerf_prepared_wild_centred_joints_give_the_same_bodies() {
    let src = write_humannerf_prepared("import_hn_wild", true, None);
    let out = common::temp_dir("import_hn_wild_out").join("ds");
    let got = import_ok(&["import", "humannerf", p(&src), "--out", p(&out)]);
    let s = rest();
    let centred: Vec<DVec3> = s[..22].iter().map(|j| *j - s[0]).collect();
    assert_joints(&got.subjects[0].skeleton.rest_joints[..22], &centred, 1e-5);
    check_frames(&got, 0..22, false, 0.5);
}

#[allow(dead_code)]
fn camera_rotation(c: &Camera) -> DMat3 {
    c.camera_from_world.matrix3.into()
}

#[allow(dead_code)]
fn root_in_camera(f: &Frame) -> DVec3 {
    axis_angle_from_rotation(
        camera_rotation(&f.camera) * rotation_from_axis_angle(f.params.global_orient),
    )
}

#[allow(dead_code)]
fn shared(v: Value) -> Arc<Value> {
    Arc::new(v)
}
