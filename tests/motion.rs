//! `talkin render --motion` end to end on a tiny trained run: BEAT2 and AMASS files in
//! their exact layouts drive the subject, `--poses` reads the same `.npz`, and bad files
//! fail naming the file and array without leaving an output directory.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use common::{npz_text, write_beat2};
use talkin::data::array::{ArrayData, NdArray};
use talkin::data::npz::{NpzWriter, object_npy_bytes};
use talkin::grids::SamplerKind;
use talkin::human::body::{N_JOINTS, PARENTS};
use talkin::train::train;

/// A one-identity scene (40x48 px) and a run trained on it for a few steps, made once.
fn scene() -> &'static (PathBuf, PathBuf, String) {
    static SCENE: OnceLock<(PathBuf, PathBuf, String)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let dataset = common::synthetic_scene("motion_data", 1, 48, 9);
        let run = common::temp_dir("motion_run");
        let opts = common::small_train_opts(SamplerKind::Accelerated, 4);
        train(&dataset, &run, &opts, &mut |_| {}).unwrap();
        let name = dataset.subjects[0].name.clone();
        (dataset.root.clone(), run, name)
    })
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

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A gentle talking pose per frame: arms down, a wave of the right elbow, jaw open.
fn poses(n: usize, columns: usize) -> Vec<f64> {
    let mut p = vec![0.0; n * columns];
    for i in 0..n {
        let row = &mut p[i * columns..(i + 1) * columns];
        row[3 * 16 + 2] = -1.1; // left shoulder down
        row[3 * 17 + 2] = 1.1; // right shoulder down
        row[3 * 19 + 1] = 0.3 * i as f64; // right elbow
        if columns == 165 {
            row[3 * 22] = 0.2; // jaw
        }
    }
    p
}

fn beat2_poses(n: usize) -> Vec<f32> {
    poses(n, 165).iter().map(|&x| x as f32).collect()
}

/// Legacy AMASS SMPL+H (as `amass_sample.npz`): z-up, `mocap_framerate`, 156 columns,
/// upright (the root turned +90 degrees about x).
fn write_amass(file: &Path, n: usize) {
    let mut p = poses(n, 156);
    for i in 0..n {
        p[i * 156] = std::f64::consts::FRAC_PI_2;
    }
    let mut w = NpzWriter::create(file).unwrap();
    w.array("poses", &NdArray::f64(&[n, 156], p).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], vec![0.2; 3 * n]).unwrap())
        .unwrap()
        .array("betas", &NdArray::f64(&[16], vec![0.0; 16]).unwrap())
        .unwrap()
        .array("gender", &npz_text("male"))
        .unwrap()
        .array("mocap_framerate", &NdArray::f64(&[], vec![60.0]).unwrap())
        .unwrap()
        .array("dmpls", &NdArray::f64(&[n, 8], vec![0.0; 8 * n]).unwrap())
        .unwrap();
    w.finish().unwrap();
}

/// A small model file in the SMPL-X layout (64 vertices, 20 shape columns).
fn write_model(file: &Path) {
    let v = 64;
    let mut w = NpzWriter::create(file).unwrap();
    let mut reg = vec![0.0; N_JOINTS * v];
    for j in 0..N_JOINTS {
        reg[j * v + j] = 1.0;
    }
    let mut kintree: Vec<i64> = PARENTS.iter().map(|&p| i64::from(p)).collect();
    kintree.extend(0..N_JOINTS as i64);
    w.array(
        "v_template",
        &NdArray::f64(&[v, 3], (0..v * 3).map(|k| k as f64 * 0.001).collect()).unwrap(),
    )
    .unwrap()
    .array(
        "shapedirs",
        &NdArray::f32(&[v, 3, 20], vec![0.001; v * 60]).unwrap(),
    )
    .unwrap()
    .array("J_regressor", &NdArray::f64(&[N_JOINTS, v], reg).unwrap())
    .unwrap()
    .array(
        "kintree_table",
        &NdArray::new(vec![2, N_JOINTS], ArrayData::I64(kintree)).unwrap(),
    )
    .unwrap()
    .array("hands_meanl", &NdArray::f32(&[45], vec![0.1; 45]).unwrap())
    .unwrap()
    .array("hands_meanr", &NdArray::f32(&[45], vec![-0.1; 45]).unwrap())
    .unwrap()
    .raw("part2num", &object_npy_bytes(b"\x80\x02}q\x00."))
    .unwrap();
    w.finish().unwrap();
}

fn frames_in(dir: &Path) -> Vec<(u32, u32)> {
    let mut k = 0;
    let mut sizes = Vec::new();
    while let Ok(img) = image::open(dir.join(format!("frame_{k:04}.png"))) {
        sizes.push((img.width(), img.height()));
        k += 1;
    }
    sizes
}

/// No partial render directory is left beside `out`.
fn no_staging_left(out: &Path) {
    let parent = out.parent().unwrap();
    let left: Vec<_> = std::fs::read_dir(parent)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn beat2_and_amass_motions_render() {
    let (data, run, name) = scene();
    let dir = common::temp_dir("motion_render");

    // BEAT2 at 30 fps, 5 frames, rendered at 15 fps: frames at 0, 2/30, 4/30.
    let beat2 = dir.join("2_scott_0_1_1.npz");
    write_beat2(&beat2, 5, beat2_poses(5));
    let out = dir.join("beat2");
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--motion",
        s(&beat2),
        "--subject",
        name,
        "--out",
        s(&out),
        "--fps",
        "15",
        "--size",
        "32",
    ]);
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    assert_eq!(frames_in(&out), vec![(24, 32); 3]);
    let err = stderr(&res);
    assert!(err.contains("BEAT2") && err.contains("mean hand"), "{err}");
    no_staging_left(&out);

    // The same file through --poses (which once read it as JSON), with a model file: its
    // mean hand is added, no note about it.
    let model = dir.join("SMPLX_NEUTRAL.npz");
    write_model(&model);
    let out = dir.join("beat2_poses");
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--poses",
        s(&beat2),
        "--out",
        s(&out),
        "--size",
        "32",
        "--body-model",
        s(&model),
    ]);
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    assert_eq!(frames_in(&out).len(), 5);
    assert!(!stderr(&res).contains("mean hand"), "{}", stderr(&res));

    // AMASS SMPL+H at 60 fps, through the dataset's camera.
    let amass = dir.join("amass_sample.npz");
    write_amass(&amass, 4);
    let out = dir.join("amass");
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--motion",
        s(&amass),
        "--subject",
        name,
        "--out",
        s(&out),
        "--camera-from",
        s(data),
    ]);
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    assert_eq!(frames_in(&out), vec![(40, 48); 4]);
    assert!(stderr(&res).contains("AMASS"), "{}", stderr(&res));
    // Rendered upright, the subject covers the middle of the frame as in its own dataset.
    let img = image::open(out.join("frame_0000.png")).unwrap().to_rgb8();
    let background = *img.get_pixel(0, 0);
    let covered = img.pixels().filter(|p| **p != background).count();
    assert!(
        covered > 40 * 48 / 20,
        "{covered} pixels differ from the background"
    );
}

#[test]
fn bad_motion_files_fail_cleanly_and_leave_no_output() {
    let (_, run, name) = scene();
    let dir = common::temp_dir("motion_bad");
    let good = dir.join("good.npz");
    write_beat2(&good, 3, beat2_poses(3));
    let bytes = std::fs::read(&good).unwrap();
    let truncated = dir.join("truncated.npz");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let write = |file: &str, arrays: &[(&str, NdArray)]| {
        let f = dir.join(file);
        let mut w = NpzWriter::create(&f).unwrap();
        for (k, a) in arrays {
            w.array(k, a).unwrap();
        }
        w.finish().unwrap();
        f
    };
    let columns = write(
        "columns.npz",
        &[("poses", NdArray::f64(&[3, 160], vec![0.0; 480]).unwrap())],
    );
    let mut values = vec![0.0; 3 * 165];
    values[200] = f64::NAN;
    let nan = write(
        "nan.npz",
        &[("poses", NdArray::f64(&[3, 165], values).unwrap())],
    );
    let missing = write(
        "missing.npz",
        &[("trans", NdArray::f64(&[3, 3], vec![0.0; 9]).unwrap())],
    );
    let cases: [(&Path, &[&str]); 4] = [
        (&truncated, &["truncated.npz"]),
        (
            &columns,
            &["columns.npz", "`poses`", "(N, 165)", "[3, 160]"],
        ),
        (&nan, &["nan.npz", "`poses`", "non-finite", "[1, 35]"]),
        (&missing, &["missing.npz", "`poses` is missing", "(N, 165)"]),
    ];
    for (file, needles) in cases {
        let out = dir.join(format!(
            "out_{}",
            file.file_stem().unwrap().to_string_lossy()
        ));
        let res = talkin(&[
            "render",
            "--run",
            s(run),
            "--motion",
            s(file),
            "--subject",
            name,
            "--out",
            s(&out),
        ]);
        let err = stderr(&res);
        assert_eq!(res.status.code(), Some(1), "{err}");
        for n in needles {
            assert!(err.contains(n), "{n:?} not in {err}");
        }
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "{} was left behind", out.display());
        no_staging_left(&out);
    }
    // A bad model file and a frame rate for a motion without one.
    let out = dir.join("out_model");
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--motion",
        s(&good),
        "--out",
        s(&out),
        "--body-model",
        s(&columns),
    ]);
    assert_eq!(res.status.code(), Some(1));
    assert!(
        stderr(&res).contains("`v_template` is missing"),
        "{}",
        stderr(&res)
    );
    assert!(!out.exists());
}
