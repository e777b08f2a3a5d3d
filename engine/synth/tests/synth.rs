//! The synthetic generator end to end on a tiny config: determinism, the dataset loads,
//! labels, masks, poses, cameras and depth agree; motion files load and fail clearly.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use talkin_data::dataset::{Dataset, Split};
use talkin_data::motion::{MotionError, load_motion};
use talkin_data::params_json::ParamsJson;
use talkin_human::body::skeleton::joint;
use talkin_human::body::{FrameParams, limb_capsules};
use talkin_synth::{CaptureConfig, SynthConfig, TRUE_FITS_FILE, generate};

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("talkin-synth-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn tiny() -> SynthConfig {
    SynthConfig {
        identities: 2,
        frames: 4,
        size: 64,
        seed: 3,
        motion: None,
        capture: None,
        framing: None,
    }
}

/// Every file under `dir`, relative, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

#[test]
fn generator_is_deterministic_and_its_frames_are_consistent() {
    let (a, b) = (temp_dir("a"), temp_dir("b"));
    let mut calls = Vec::new();
    let made = generate(&tiny(), &a, &mut |done, total| calls.push((done, total))).unwrap();
    generate(&tiny(), &b, &mut |_, _| {}).unwrap();
    let total = made.frames.len();
    assert_eq!(calls.first(), Some(&(0, total)));
    assert_eq!(calls.last(), Some(&(total, total)));
    assert_eq!(calls.len(), total + 1, "progress once per frame");

    let (fa, fb) = (files(&a), files(&b));
    assert_eq!(fa, fb);
    assert_eq!(fa.len(), 1 + 4 * total);
    for f in &fa {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{} differs",
            f.display()
        );
    }

    let ds = Dataset::load(&a).unwrap();
    assert_eq!(ds.subjects.len(), 2);
    assert_eq!(ds.background, talkin_synth::BACKGROUND);
    for split in Split::ALL {
        for s in 0..2 {
            let n = ds
                .frames
                .iter()
                .filter(|f| f.split == split && f.subject == s)
                .count();
            assert!(n >= 1, "subject {s} has no {split} frames");
        }
    }
    assert_eq!(
        ds.frames
            .iter()
            .filter(|f| f.split == Split::Train && f.subject == 0)
            .count(),
        4
    );
    // Held-out frames are not training frames.
    for s in 0..2 {
        let train: Vec<f64> = ds
            .frames
            .iter()
            .filter(|f| f.subject == s && f.split == Split::Train)
            .map(|f| f.time)
            .collect();
        for f in ds
            .frames
            .iter()
            .filter(|f| f.subject == s && f.split == Split::TestSame)
        {
            assert!(!train.contains(&f.time));
        }
    }

    // How far clothing and hair stick out of the bare skeleton's capsules.
    let mut farthest = 0.0f32;
    let (mut soft, mut pixels) = (0usize, 0usize);
    for (i, frame) in ds.frames.iter().enumerate() {
        let img = ds.images(i).unwrap();
        let depth = ds.depth(i).unwrap().expect("synthetic frames carry depth");
        let (w, h) = (frame.camera.width, frame.camera.height);
        let mut count = [0usize; 5];
        let mut head_box = (u32::MAX, u32::MAX, 0u32, 0u32);
        let skeleton = &ds.subjects[frame.subject].skeleton;
        let posed = skeleton.pose(&frame.params);
        let capsules = limb_capsules(skeleton, &posed);
        let fx = frame.camera.intrinsics.x_axis.x;
        let fy = frame.camera.intrinsics.y_axis.y;
        let (cx, cy) = (
            frame.camera.intrinsics.z_axis.x,
            frame.camera.intrinsics.z_axis.y,
        );
        let world_from_camera = frame.camera.camera_from_world.inverse();
        for y in 0..h {
            for x in 0..w {
                let label = img.segmentation.get_pixel(x, y).0[0];
                let mask = img.mask.get_pixel(x, y).0[0];
                // The mask is the pixel's covered fraction in quarters, on the centre
                // ray's side of the 128 cut: it agrees with the label everywhere.
                assert!(
                    [0, 64, 127, 128, 191, 255].contains(&mask),
                    "frame {i} pixel ({x}, {y}): mask {mask}"
                );
                assert_eq!(
                    mask >= 128,
                    label > 0,
                    "frame {i} pixel ({x}, {y}): mask {mask}, label {label}"
                );
                soft += usize::from(mask != 0 && mask != 255);
                count[label as usize] += 1;
                if label == 4 {
                    head_box = (
                        head_box.0.min(x),
                        head_box.1.min(y),
                        head_box.2.max(x),
                        head_box.3.max(y),
                    );
                }
                let z = depth[(y * w + x) as usize];
                assert_eq!(
                    z.is_some(),
                    label > 0,
                    "frame {i} pixel ({x}, {y}): depth vs label"
                );
                if let Some(z) = z {
                    let z = z as f64;
                    assert!(z.is_finite() && z > 0.5 && z < 10.0, "depth {z}");
                    let p_cam = DVec3::new(
                        (x as f64 + 0.5 - cx) * z / fx,
                        (y as f64 + 0.5 - cy) * z / fy,
                        z,
                    );
                    let p = world_from_camera.transform_point3(p_cam).as_vec3();
                    let nearest = capsules
                        .iter()
                        .map(|c| capsule_distance(p, c.a, c.b, c.radius))
                        .fold(f32::MAX, f32::min);
                    farthest = farthest.max(nearest);
                    assert!(
                        nearest < 0.25,
                        "frame {i} pixel ({x}, {y}): surface point {p} is {nearest} m from every capsule"
                    );
                }
            }
        }
        assert!(count[3] > 0, "frame {i}: no hand pixels");
        assert!(count[4] > 0, "frame {i}: no head pixels");
        let head = frame.camera.project(posed.joint(joint::HEAD)).unwrap();
        let tol = 1.5;
        assert!(
            head.x >= head_box.0 as f64 - tol
                && head.x <= head_box.2 as f64 + 1.0 + tol
                && head.y >= head_box.1 as f64 - tol
                && head.y <= head_box.3 as f64 + 1.0 + tol,
            "frame {i}: head joint projects to {head:?}, head pixels span {head_box:?}"
        );
        assert!(img.rgb.pixels().any(|p| p.0 != [255, 255, 255]));
        pixels += (w * h) as usize;
        // Shown over black, a frame keeps its person: the coverage takes the white out.
        let mut over_black = ds.clone();
        over_black.show_over([0.0; 3]).unwrap();
        let black = over_black.images(i).unwrap().rgb;
        for ((p, q), m) in black.pixels().zip(img.rgb.pixels()).zip(img.mask.iter()) {
            match *m {
                0 => assert_eq!(p.0, [0, 0, 0]),
                255 => assert_eq!(p.0, q.0),
                // The white share goes (all of what is left where the mask rounds
                // the cover up to the cut).
                m => (0..3).for_each(|c| {
                    let lost = i32::from(q.0[c]) - i32::from(p.0[c]);
                    let white = 255 - i32::from(m);
                    let ok = (lost - white).abs() <= 1 || (p.0[c] == 0 && lost <= white);
                    assert!(ok, "{p:?} {q:?} {m}")
                }),
            }
        }
    }
    assert!(
        soft > 0 && soft * 10 < pixels,
        "{soft} of {pixels} pixels partly covered"
    );
    assert!(
        farthest > 0.03,
        "hair and clothes should stick out of the capsules, max {farthest} m"
    );
    let _ = std::fs::remove_dir_all(&a);
    let _ = std::fs::remove_dir_all(&b);
}

#[test]
fn jaw_and_expressions_move_only_the_face() {
    let dir = temp_dir("face");
    let neutral = FrameParams::default();
    let mut pose = neutral.clone();
    // Arms down and forward so the hands are in view.
    pose.body_pose[joint::LEFT_SHOULDER - 1] = DVec3::new(0.0, 0.0, -1.2);
    pose.body_pose[joint::RIGHT_SHOULDER - 1] = DVec3::new(0.0, 0.0, 1.2);
    let mut jaw = pose.clone();
    jaw.jaw_pose = DVec3::new(0.35, 0.0, 0.0);
    let mut brows = pose.clone();
    brows.expression[1] = 2.0;
    let mut smile = pose.clone();
    smile.expression[0] = 2.0;
    let mut blink = pose.clone();
    blink.expression[3] = 2.5;
    let cfg = SynthConfig {
        identities: 1,
        frames: 1,
        size: 160,
        seed: 0,
        motion: Some(vec![pose, jaw, brows, smile, blink]),
        capture: None,
        framing: None,
    };
    let ds = generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    let base = ds.images(0).unwrap();
    // Lowest head row of the neutral face, projected chin included.
    let chin_row = base
        .segmentation
        .enumerate_pixels()
        .filter(|p| p.2.0[0] == 4)
        .map(|p| p.1)
        .max()
        .unwrap();
    for (i, what) in [(1, "jaw"), (2, "brow raise"), (3, "smile"), (4, "blink")] {
        let img = ds.images(i).unwrap();
        let mut changed = 0;
        for (x, y, p) in img.rgb.enumerate_pixels() {
            if p != base.rgb.get_pixel(x, y) {
                changed += 1;
                let labels = [
                    base.segmentation.get_pixel(x, y).0[0],
                    img.segmentation.get_pixel(x, y).0[0],
                ];
                // Head pixels, or the neck just under the chin (the chin blends smoothly
                // into it) and anti-aliased pixels beside the head: never arms or hands.
                let ok =
                    labels.contains(&4) || (labels.iter().all(|&l| l <= 1) && y <= chin_row + 8);
                assert!(
                    ok,
                    "{what} changed pixel ({x}, {y}) with labels {labels:?}, chin row {chin_row}"
                );
            }
        }
        assert!(changed > 3, "{what} changed only {changed} pixels");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn capsule_distance(p: Vec3, a: Vec3, b: Vec3, r: f32) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + ab * t)).length() - r
}

#[test]
fn generator_renders_a_given_motion() {
    let dir = temp_dir("motion");
    let mut p = FrameParams::default();
    p.body_pose[joint::LEFT_SHOULDER - 1] = DVec3::new(0.0, 0.0, -1.2);
    p.body_pose[joint::RIGHT_SHOULDER - 1] = DVec3::new(0.0, 0.0, 1.2);
    p.jaw_pose = DVec3::new(0.3, 0.0, 0.0);
    let cfg = SynthConfig {
        identities: 1,
        frames: 1,
        size: 48,
        seed: 0,
        motion: Some(vec![
            p.clone(),
            FrameParams {
                transl: DVec3::new(0.0, 0.0, 0.1),
                ..p
            },
        ]),
        capture: None,
        framing: None,
    };
    let ds = generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    assert_eq!(ds.frames.len(), 2);
    assert!(ds.frames.iter().all(|f| f.split == Split::Train));
    Dataset::load(&dir).unwrap();
    let bad = SynthConfig {
        identities: 0,
        ..tiny()
    };
    assert!(generate(&bad, &dir, &mut |_, _| {}).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A .npy file with a hand-made v1 header.
fn npy(descr: &str, shape: &[usize], values: &[f64]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((header.len() as u16).to_le_bytes());
    b.extend(header.as_bytes());
    for v in values {
        if descr == "<f4" {
            b.extend((*v as f32).to_le_bytes());
        } else {
            b.extend(v.to_le_bytes());
        }
    }
    b
}

fn npz(path: &Path, arrays: &[(&str, Vec<u8>)]) {
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    for (name, bytes) in arrays {
        zip.start_file(
            format!("{name}.npy"),
            zip::write::SimpleFileOptions::default(),
        )
        .unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap();
}

#[test]
fn motion_files_load_and_fail_clearly() {
    let dir = temp_dir("npz");
    let n = 2;
    let poses: Vec<f64> = (0..n * 165)
        .map(|k| (k % 7) as f64 * 0.125 - 0.25)
        .collect();
    let expressions: Vec<f64> = (0..n * 12).map(|k| k as f64 * 0.5).collect();
    let trans: Vec<f64> = vec![0.0, 0.5, 1.0, 0.25, 0.75, 1.25];
    for descr in ["<f4", "<f8"] {
        let file = dir.join(format!("ok{}.npz", &descr[2..]));
        npz(
            &file,
            &[
                ("poses", npy(descr, &[n, 165], &poses)),
                ("expressions", npy(descr, &[n, 12], &expressions)),
                ("trans", npy(descr, &[n, 3], &trans)),
            ],
        );
        let m = load_motion(&file).unwrap();
        assert_eq!(m.len(), 2);
        let row = &poses[165..];
        assert_eq!(m[1].global_orient, DVec3::new(row[0], row[1], row[2]));
        assert_eq!(m[1].body_pose[20], DVec3::new(row[63], row[64], row[65]));
        assert_eq!(m[1].jaw_pose, DVec3::new(row[66], row[67], row[68]));
        assert_eq!(
            m[1].right_hand_pose[14],
            DVec3::new(row[162], row[163], row[164])
        );
        assert_eq!(m[1].expression[9], expressions[12 + 9]);
        assert_eq!(m[1].transl, DVec3::new(0.25, 0.75, 1.25));
    }
    // Optional arrays default to zeros.
    let only = dir.join("only.npz");
    npz(&only, &[("poses", npy("<f8", &[n, 165], &poses))]);
    let m = load_motion(&only).unwrap();
    assert_eq!(m[0].transl, DVec3::ZERO);
    assert_eq!(m[0].expression, [0.0; 10]);

    let message = |e: MotionError| e.to_string();
    let wrong = dir.join("wrong.npz");
    npz(
        &wrong,
        &[("poses", npy("<f8", &[n, 160], &poses[..n * 160]))],
    );
    let e = message(load_motion(&wrong).unwrap_err());
    assert!(
        e.contains("wrong.npz") && e.contains("poses") && e.contains("165"),
        "{e}"
    );
    let mismatch = dir.join("mismatch.npz");
    npz(
        &mismatch,
        &[
            ("poses", npy("<f8", &[n, 165], &poses)),
            ("trans", npy("<f8", &[1, 3], &trans[..3])),
        ],
    );
    let e = message(load_motion(&mismatch).unwrap_err());
    assert!(e.contains("trans") && e.contains("(2, 3)"), "{e}");
    let mut with_nan = poses.clone();
    with_nan[170] = f64::NAN;
    let nan = dir.join("nan.npz");
    npz(&nan, &[("poses", npy("<f4", &[n, 165], &with_nan))]);
    let e = message(load_motion(&nan).unwrap_err());
    assert!(
        e.contains("poses") && e.contains("non-finite") && e.contains("[1, 5]"),
        "{e}"
    );
    let missing = dir.join("missing.npz");
    npz(&missing, &[("trans", npy("<f8", &[n, 3], &trans))]);
    let e = message(load_motion(&missing).unwrap_err());
    assert!(e.contains("missing") && e.contains("poses"), "{e}");
    // Text where numbers belong (8-byte elements as 2-character strings): refused.
    let text = dir.join("text.npz");
    npz(&text, &[("poses", npy("<U2", &[n, 165], &poses))]);
    let e = message(load_motion(&text).unwrap_err());
    assert!(e.contains("text.npz") && e.contains("`poses`"), "{e}");

    // JSON: a list of params objects.
    let mut a = FrameParams {
        jaw_pose: DVec3::new(0.25, 0.0, 0.0),
        ..Default::default()
    };
    a.expression[3] = 1.5;
    let json = dir.join("motion.json");
    std::fs::write(
        &json,
        serde_json::to_string(&vec![a.to_json(), FrameParams::default().to_json()]).unwrap(),
    )
    .unwrap();
    assert_eq!(
        load_motion(&json).unwrap(),
        vec![a.clone(), FrameParams::default()]
    );
    let mut broken = FrameParams::default().to_json();
    broken["body_pose"] = serde_json::json!([[0, 0, 0]]);
    std::fs::write(
        &json,
        serde_json::to_string(&vec![a.to_json(), broken]).unwrap(),
    )
    .unwrap();
    let e = message(load_motion(&json).unwrap_err());
    assert!(
        e.contains("[1].body_pose") && e.contains("motion.json"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The capture-like scene: its splits, masks only, the whole body in frame, the fits off
/// by about the asked RMS with the true poses beside them, and skin that bends.
#[test]
fn the_capture_scene_has_its_flaws_and_its_true_fits() {
    let dir = temp_dir("capture");
    let cfg = SynthConfig {
        identities: 1,
        frames: 10,
        size: 96,
        seed: 1,
        motion: None,
        capture: Some(CaptureConfig::default()),
        framing: None,
    };
    let made = generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    let count = |s: Split| made.frames.iter().filter(|f| f.split == s).count();
    assert_eq!(count(Split::Train), 10);
    assert_eq!(count(Split::TestSame), 2);
    assert!(count(Split::TestOod) >= 2);
    // Masks only: no depth, no labels, no empty folders for them.
    assert!(
        made.frames
            .iter()
            .all(|f| f.depth.is_none() && f.segmentation.is_none())
    );
    assert!(!dir.join("depth").exists() && !dir.join("segmentation").exists());
    let loaded = Dataset::load(&dir).unwrap();
    assert_eq!(loaded.frames.len(), made.frames.len());
    // The true fits: the same frames, each pose off by a few degrees, no more.
    let text = std::fs::read_to_string(dir.join(TRUE_FITS_FILE)).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let truth = doc["frames"].as_array().unwrap();
    assert_eq!(truth.len(), made.frames.len());
    let mut sq = 0.0;
    let mut n = 0.0;
    for (frame, t) in made.frames.iter().zip(truth) {
        let true_params = FrameParams::from_json(&t["params"], "params").unwrap();
        for j in 0..21 {
            let r = talkin_human::body::rotation_from_axis_angle(frame.params.body_pose[j])
                .transpose()
                * talkin_human::body::rotation_from_axis_angle(true_params.body_pose[j]);
            let e = talkin_human::body::axis_angle_from_rotation(r)
                .length()
                .to_degrees();
            sq += e * e;
            n += 1.0;
        }
    }
    let rms = (sq / n).sqrt();
    assert!((1.0..6.0).contains(&rms), "RMS offset {rms} degrees");
    // The whole body in frame: both feet inside every image.
    let skeleton = &made.subjects[0].skeleton;
    for (frame, t) in made.frames.iter().zip(truth) {
        let posed = skeleton.pose(&FrameParams::from_json(&t["params"], "params").unwrap());
        for j in [joint::LEFT_FOOT, joint::RIGHT_FOOT, joint::HEAD] {
            let px = frame
                .camera
                .project(posed.joint(j))
                .expect("in front of the camera");
            assert!(
                px.x > 0.0
                    && px.y > 0.0
                    && px.x < frame.camera.width as f64
                    && px.y < frame.camera.height as f64,
                "joint {j} at {px:?}"
            );
        }
    }
}

/// Skin that bends changes the image near the joints only: the same pose rendered rigid
/// and with 4 cm of bend differs on a few percent of the person's pixels.
#[test]
fn smooth_skin_bends_the_joints_and_nothing_else() {
    use talkin_synth::tracer::Scene;
    let cfg = SynthConfig {
        identities: 1,
        frames: 10,
        size: 160,
        seed: 2,
        motion: None,
        capture: Some(CaptureConfig::clean()),
        framing: None,
    };
    let dir = temp_dir("smooth");
    let made = generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    let frame = &made.frames[3];
    let skeleton = &made.subjects[0].skeleton;
    let fig = talkin_synth::body::figure(
        skeleton,
        &talkin_synth::proportions(cfg.appearance(0)),
        &talkin_synth::look(cfg.appearance(0)),
        &frame.params,
    );
    let posed = skeleton.pose(&frame.params);
    let rigid = Scene::new(&fig, &posed, Vec3::ONE).render(&frame.camera);
    let bent = Scene::new(&fig, &posed, Vec3::ONE)
        .with_smooth_skin(0.04)
        .render(&frame.camera);
    let person = rigid.label.iter().filter(|&&l| l > 0).count();
    let changed = rigid
        .label
        .iter()
        .zip(&bent.label)
        .filter(|(a, b)| (**a > 0) != (**b > 0))
        .count();
    assert!(person > 500, "{person}");
    let share = changed as f64 / person as f64;
    assert!(
        share > 0.0 && share < 0.08,
        "{changed} of {person} pixels changed"
    );
    let unbent = Scene::new(&fig, &posed, Vec3::ONE)
        .with_smooth_skin(0.0)
        .render(&frame.camera);
    assert_eq!(unbent.rgb, rigid.rgb, "a width of 0 is the rigid scene");
}
