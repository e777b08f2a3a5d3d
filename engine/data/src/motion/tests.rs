//! Motion files in the exact layouts the tools write, and their conversion.

use std::path::PathBuf;

use glam::DVec3;

use super::*;
use crate::array::{ArrayData, NdArray};
use crate::npz::NpzWriter;
use crate::smplx_model::SmplxModel;
use talkin_human::body::{FrameParams, PARENTS, Skeleton, joint};

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("talkin_motion_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn text(s: &str) -> NdArray {
    NdArray::new(vec![], ArrayData::Str(vec![s.into()])).unwrap()
}

/// Pose values that differ per frame and column.
fn poses(n: usize, cols: usize) -> Vec<f64> {
    (0..n * cols)
        .map(|k| ((k * 7) % 23) as f64 * 0.01 - 0.1)
        .collect()
}

/// A BEAT2 file as `2_scott_0_1_1.npz` stores it: poses f4, expressions and trans f8,
/// betas f4 (300,), model and gender text, an int32 frame rate.
fn write_beat2(file: &std::path::Path, n: usize) {
    let p: Vec<f32> = poses(n, 165).iter().map(|&x| x as f32).collect();
    let e: Vec<f64> = (0..n * 100).map(|k| k as f64 * 0.001).collect();
    let t: Vec<f64> = (0..n)
        .flat_map(|i| [0.01 * i as f64, 1.29, 0.02 * i as f64])
        .collect();
    let mut w = NpzWriter::create(file).unwrap();
    w.array("betas", &NdArray::f32(&[300], vec![0.1; 300]).unwrap())
        .unwrap()
        .array("poses", &NdArray::f32(&[n, 165], p).unwrap())
        .unwrap()
        .array("expressions", &NdArray::f64(&[n, 100], e).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], t).unwrap())
        .unwrap()
        .array("model", &text("smplx2020"))
        .unwrap()
        .array("gender", &text("neutral"))
        .unwrap()
        .array(
            "mocap_frame_rate",
            &NdArray::new(vec![], ArrayData::I32(vec![30])).unwrap(),
        )
        .unwrap();
    w.finish().unwrap();
}

#[test]
fn beat2_layout_with_mixed_dtypes() {
    let file = temp("2_scott.npz");
    write_beat2(&file, 4);
    let m = read_motion(&file, None).unwrap();
    assert_eq!(m.layout, MotionLayout::Beat2);
    assert_eq!((m.up, m.hands), (UpAxis::Y, Hands::RelativeToMean));
    assert_eq!(m.fps, Some(30.0));
    assert_eq!(m.betas.len(), 300);
    assert_eq!(m.gender.as_deref(), Some("neutral"));
    assert_eq!(m.frames.len(), 4);
    let row: Vec<f64> = poses(4, 165)[2 * 165..3 * 165]
        .iter()
        .map(|&x| f64::from(x as f32))
        .collect();
    let f = &m.frames[2];
    assert_eq!(f.global_orient, DVec3::new(row[0], row[1], row[2]));
    assert_eq!(f.body_pose[20], DVec3::new(row[63], row[64], row[65]));
    assert_eq!(f.jaw_pose, DVec3::new(row[66], row[67], row[68]));
    assert_eq!(f.reye_pose, DVec3::new(row[72], row[73], row[74]));
    assert_eq!(f.left_hand_pose[0], DVec3::new(row[75], row[76], row[77]));
    assert_eq!(
        f.right_hand_pose[14],
        DVec3::new(row[162], row[163], row[164])
    );
    assert_eq!(f.expression[9], (2 * 100 + 9) as f64 * 0.001);
    assert_eq!(f.transl, DVec3::new(0.02, 1.29, 0.04));
    // Forcing the other layout reads the same arrays with AMASS's conventions.
    let forced = read_motion(&file, Some(MotionLayout::Amass)).unwrap();
    assert_eq!((forced.up, forced.hands), (UpAxis::Z, Hands::Absolute));
}

#[test]
fn amass_smplx_and_smplh_layouts() {
    let n = 3;
    let file = temp("stageii.npz");
    let mut w = NpzWriter::create(&file).unwrap();
    w.array("poses", &NdArray::f64(&[n, 165], poses(n, 165)).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], vec![0.5; 3 * n]).unwrap())
        .unwrap()
        .array("betas", &NdArray::f64(&[16], vec![0.0; 16]).unwrap())
        .unwrap()
        .array("gender", &text("female"))
        .unwrap()
        .array("surface_model_type", &text("smplx"))
        .unwrap()
        .array("mocap_frame_rate", &NdArray::f64(&[], vec![120.0]).unwrap())
        .unwrap();
    w.finish().unwrap();
    let m = read_motion(&file, None).unwrap();
    assert_eq!(
        (m.layout, m.up, m.hands),
        (MotionLayout::Amass, UpAxis::Z, Hands::Absolute)
    );
    assert_eq!((m.fps, m.gender.as_deref()), (Some(120.0), Some("female")));

    // Legacy SMPL+H: 156 columns, `mocap_framerate`, no jaw or eyes.
    let file = temp("amass_sample.npz");
    let mut w = NpzWriter::create(&file).unwrap();
    w.array("poses", &NdArray::f64(&[n, 156], poses(n, 156)).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], vec![0.5; 3 * n]).unwrap())
        .unwrap()
        .array("mocap_framerate", &NdArray::f64(&[], vec![60.0]).unwrap())
        .unwrap()
        .array("dmpls", &NdArray::f64(&[n, 8], vec![0.0; 8 * n]).unwrap())
        .unwrap();
    w.finish().unwrap();
    let m = read_motion(&file, None).unwrap();
    assert_eq!((m.layout, m.fps), (MotionLayout::Amass, Some(60.0)));
    let row = &poses(n, 156)[156..312];
    let f = &m.frames[1];
    assert_eq!(f.body_pose[20], DVec3::new(row[63], row[64], row[65]));
    assert_eq!(f.jaw_pose, DVec3::ZERO);
    assert_eq!(f.left_hand_pose[0], DVec3::new(row[66], row[67], row[68]));
    assert_eq!(
        f.right_hand_pose[14],
        DVec3::new(row[153], row[154], row[155])
    );
}

/// A skeleton standing on y = 0 (y up), pelvis at 0.9 m.
fn skeleton() -> Skeleton {
    let mut rest = [DVec3::ZERO; talkin_human::body::N_JOINTS];
    rest[0] = DVec3::new(0.01, 0.9, 0.02);
    for j in 1..rest.len() {
        let p = PARENTS[j] as usize;
        let up = if [1, 2, 4, 5, 7, 8, 10, 11].contains(&j) {
            -0.2
        } else {
            0.1
        };
        rest[j] = rest[p] + DVec3::new(0.003 * j as f64, up, 0.001);
    }
    Skeleton { rest_joints: rest }
}

#[test]
fn z_up_frames_stand_upright_and_keep_the_pelvis() {
    let s = skeleton();
    let j0 = s.rest_joints[0];
    // Upright in a z-up world: the body's +y turned onto +z (90 degrees about x),
    // facing -y; the pelvis 0.9 m above the floor z = 0 (trans z = 0 with this J0).
    let mut f = FrameParams {
        global_orient: DVec3::new(std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        transl: DVec3::new(0.3, -0.2, 0.9 - j0.y),
        ..Default::default()
    };
    f.body_pose[joint::LEFT_ELBOW - 1] = DVec3::new(0.0, 0.4, 0.0);
    let z_up = s.pose(&f);
    assert!(z_up.joint(joint::HEAD).z > z_up.joint(joint::PELVIS).z + 0.2);
    let g = z_up_to_y_up(&f, j0);
    let y_up = s.pose(&g);
    // Upright: the head straight above the pelvis, as in the rest pose.
    let rise = y_up.joint(joint::HEAD) - y_up.joint(joint::PELVIS);
    let rest_rise = s.rest_joints[joint::HEAD] - j0;
    assert!((rise - rest_rise).length() < 1e-12, "{rise} vs {rest_rise}");
    // Every posed joint is the z-up one turned by Q: the pelvis per the formula.
    for j in 0..talkin_human::body::N_JOINTS {
        assert!(
            (y_up.joint(j) - Z_UP_TO_Y_UP * z_up.joint(j)).length() < 1e-12,
            "joint {j}"
        );
    }
    assert!((g.transl - (Z_UP_TO_Y_UP * (f.transl + j0) - j0)).length() < 1e-15);
    assert!((y_up.joint(0) - Z_UP_TO_Y_UP * (j0 + f.transl)).length() < 1e-12);
    assert!((Z_UP_TO_Y_UP * DVec3::Z - DVec3::Y).length() < 1e-15);
}

#[test]
fn resampling_interpolates_rotations_as_rotations() {
    let mut a = FrameParams::default();
    let mut b = FrameParams::default();
    a.body_pose[0] = DVec3::new(0.0, 0.0, 0.0);
    b.body_pose[0] = DVec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    // Near pi the short way round passes through pi, not through the identity.
    a.jaw_pose = DVec3::new(0.0, 0.0, 3.0);
    b.jaw_pose = DVec3::new(0.0, 0.0, -3.0);
    b.transl = DVec3::new(1.0, 2.0, 3.0);
    b.expression[0] = 1.0;
    let out = resample(&[a.clone(), b.clone()], 1.0, 2.0);
    assert_eq!(out.len(), 3);
    assert_eq!(out[0], a);
    let m = &out[1];
    assert!((m.body_pose[0] - DVec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_4)).length() < 1e-12);
    assert!(
        (m.jaw_pose.length() - std::f64::consts::PI).abs() < 1e-9,
        "{}",
        m.jaw_pose
    );
    assert!((m.transl - DVec3::new(0.5, 1.0, 1.5)).length() < 1e-15);
    assert_eq!(m.expression[0], 0.5);
    assert!((out[2].body_pose[0] - b.body_pose[0]).length() < 1e-12);
    // 30 -> 15 fps keeps every other frame; 30 -> 30 is the identity.
    let frames: Vec<FrameParams> = (0..7)
        .map(|i| FrameParams {
            transl: DVec3::X * i as f64,
            ..Default::default()
        })
        .collect();
    let half = resample(&frames, 30.0, 15.0);
    assert_eq!(half.len(), 4);
    assert_eq!(half[3].transl, DVec3::X * 6.0);
    assert_eq!(resample(&frames, 30.0, 30.0), frames);
    assert_eq!(resample(&frames, 30.0, 25.0).len(), 6);
}

#[test]
fn prepare_adds_mean_hands_anchors_and_resamples() {
    let file = temp("prep.npz");
    write_beat2(&file, 7);
    let m = read_motion(&file, None).unwrap();
    let s = skeleton();
    let p = Prepare {
        subject: &s,
        model: None,
        fps: None,
        keep_trans: false,
    };
    let out = m.prepare(&p).unwrap();
    assert_eq!(out.frames.len(), 7);
    assert!(
        out.notes.iter().any(|n| n.contains("mean hand")),
        "{:?}",
        out.notes
    );
    assert_eq!(out.frames[0].transl, DVec3::ZERO);
    assert!((out.frames[2].transl - DVec3::new(0.02, 0.0, 0.04)).length() < 1e-12);
    assert_eq!(out.frames[3].left_hand_pose, m.frames[3].left_hand_pose);
    let kept = m
        .prepare(&Prepare {
            keep_trans: true,
            ..p
        })
        .unwrap();
    assert_eq!(kept.frames[1].transl, m.frames[1].transl);
    let slow = m
        .prepare(&Prepare {
            fps: Some(15.0),
            ..p
        })
        .unwrap();
    assert_eq!((slow.frames.len(), slow.fps), (4, Some(15.0)));
    assert!(
        m.prepare(&Prepare {
            fps: Some(0.0),
            ..p
        })
        .is_err()
    );

    // With a model: its mean hand is added and its rest pelvis places the motion.
    let model_file = temp("SMPLX_NEUTRAL.npz");
    crate::smplx_model::fixture::write_fixture(&model_file, &PARENTS);
    let model = SmplxModel::load(&model_file).unwrap();
    let with = m
        .prepare(&Prepare {
            model: Some(&model),
            keep_trans: true,
            ..p
        })
        .unwrap();
    assert!(
        with.notes.iter().any(|n| n.contains("betas beyond")),
        "{:?}",
        with.notes
    );
    let (l, r) = model.hands_mean();
    assert!(
        (with.frames[3].left_hand_pose[1] - (m.frames[3].left_hand_pose[1] + l[1])).length()
            < 1e-12
    );
    assert!(
        (with.frames[3].right_hand_pose[14] - (m.frames[3].right_hand_pose[14] + r[14])).length()
            < 1e-12
    );
    let j0_model = model.rest_joints(&m.betas[..10]).unwrap()[0];
    let want = m.frames[5].transl + j0_model - s.rest_joints[0];
    assert!((with.frames[5].transl - want).length() < 1e-12);
}

#[test]
fn bad_motion_files_name_file_and_array() {
    let good = temp("good.npz");
    write_beat2(&good, 3);
    let bytes = std::fs::read(&good).unwrap();
    let cut = temp("truncated.npz");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let e = read_motion(&cut, None).unwrap_err().to_string();
    assert!(e.contains("truncated.npz"), "{e}");

    let write = |name: &str, arrays: &[(&str, NdArray)]| {
        let f = temp(name);
        let mut w = NpzWriter::create(&f).unwrap();
        for (k, a) in arrays {
            w.array(k, a).unwrap();
        }
        w.finish().unwrap();
        read_motion(&f, None).unwrap_err().to_string()
    };
    let e = write(
        "cols.npz",
        &[("poses", NdArray::f64(&[2, 160], vec![0.0; 320]).unwrap())],
    );
    assert!(
        e.contains("cols.npz") && e.contains("`poses`") && e.contains("(N, 165)"),
        "{e}"
    );
    let mut nan = vec![0.0; 330];
    nan[170] = f64::NAN;
    let e = write(
        "nan.npz",
        &[("poses", NdArray::f64(&[2, 165], nan).unwrap())],
    );
    assert!(
        e.contains("nan.npz") && e.contains("`poses`") && e.contains("[1, 5]"),
        "{e}"
    );
    let e = write(
        "nopose.npz",
        &[("trans", NdArray::f64(&[2, 3], vec![0.0; 6]).unwrap())],
    );
    assert!(
        e.contains("nopose.npz") && e.contains("`poses` is missing") && e.contains("(N, 165)"),
        "{e}"
    );
    let e = write(
        "short_trans.npz",
        &[
            ("poses", NdArray::f64(&[2, 165], vec![0.0; 330]).unwrap()),
            ("trans", NdArray::f64(&[1, 3], vec![0.0; 3]).unwrap()),
        ],
    );
    assert!(e.contains("`trans`") && e.contains("(2, 3)"), "{e}");
    let e = write(
        "inf_trans.npz",
        &[
            ("poses", NdArray::f64(&[2, 165], vec![0.0; 330]).unwrap()),
            (
                "trans",
                NdArray::f64(&[2, 3], vec![0.0, 0.0, 0.0, 0.0, f64::INFINITY, 0.0]).unwrap(),
            ),
        ],
    );
    assert!(
        e.contains("`trans`") && e.contains("non-finite") && e.contains("[1, 1]"),
        "{e}"
    );
    let e = write(
        "rate.npz",
        &[
            ("poses", NdArray::f64(&[2, 165], vec![0.0; 330]).unwrap()),
            ("mocap_frame_rate", NdArray::f64(&[], vec![-30.0]).unwrap()),
        ],
    );
    assert!(
        e.contains("`mocap_frame_rate`") && e.contains("positive"),
        "{e}"
    );
    let e = read_motion(temp("m.bvh"), None).unwrap_err().to_string();
    assert!(e.contains(".json or .npz"), "{e}");
}
