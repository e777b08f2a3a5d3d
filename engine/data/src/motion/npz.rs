//! The `.npz` motion layouts (BEAT2, AMASS SMPL-X, AMASS SMPL+H).

use std::path::Path;

use glam::DVec3;

use super::{Hands, Motion, MotionError, MotionLayout, POSE_COLUMNS, SMPLH_POSE_COLUMNS, UpAxis};
use crate::array::{Dim, NdArray};
use crate::npz::{Npz, check_array};
use talkin_human::body::{FrameParams, N_BODY_JOINTS, N_EXPRESSION, N_HAND_JOINTS};

/// Keys only AMASS files carry.
const AMASS_KEYS: [&str; 6] = [
    "mocap_framerate",
    "surface_model_type",
    "mocap_time_length",
    "markers_latent",
    "dmpls",
    "marker_data",
];

pub(super) fn read(file: &Path, forced: Option<MotionLayout>) -> Result<Motion, MotionError> {
    let mut npz = Npz::open(file)?;
    let poses = npz.read_checked("poses", &[Dim::Any("N"), Dim::Any("165")])?;
    let (n, columns) = (poses.shape()[0], poses.shape()[1]);
    if n == 0 {
        return Err(MotionError::Array {
            file: file.into(),
            array: "poses".into(),
            problem: "has no frames".into(),
        });
    }
    let layout = forced.unwrap_or_else(|| {
        let amass = columns == SMPLH_POSE_COLUMNS || AMASS_KEYS.iter().any(|k| npz.contains(k));
        if amass {
            MotionLayout::Amass
        } else {
            MotionLayout::Beat2
        }
    });
    let columns_ok =
        columns == POSE_COLUMNS || (layout == MotionLayout::Amass && columns == SMPLH_POSE_COLUMNS);
    if !columns_ok {
        let expected = match layout {
            MotionLayout::Amass => {
                format!("(N, {POSE_COLUMNS}) for SMPL-X or (N, {SMPLH_POSE_COLUMNS}) for SMPL+H")
            }
            _ => format!("(N, {POSE_COLUMNS}): 55 SMPL-X joints, axis-angle"),
        };
        return Err(MotionError::Array {
            file: file.into(),
            array: "poses".into(),
            problem: format!("expected shape {expected}, found {:?}", poses.shape()),
        });
    }
    let trans = first_of(&mut npz, &["trans", "transl"], &[Dim::Is(n), Dim::Is(3)])?;
    let expression = first_of(
        &mut npz,
        &["expressions", "expression"],
        &[Dim::Is(n), Dim::Any("E")],
    )?;
    let betas = match npz.get("betas")? {
        None => Vec::new(),
        Some(b) => {
            // (S,) or (1, S).
            let dims: &[Dim] = if b.shape().len() == 2 {
                &[Dim::Is(1), Dim::Any("S")]
            } else {
                &[Dim::Any("S")]
            };
            check_array(&b, file, "betas", dims)?;
            b.to_f64().unwrap_or_default()
        }
    };
    let gender = npz
        .get("gender")?
        .and_then(|g| g.scalar_str().map(str::to_string));
    let fps = frame_rate(&mut npz, file, n)?;
    let pose = poses.to_f64().unwrap_or_default();
    let trans = trans.map(|(_, t)| t.to_f64().unwrap_or_default());
    let expression = expression.map(|(_, e)| (e.shape()[1], e.to_f64().unwrap_or_default()));
    let frames = (0..n)
        .map(|i| {
            let row = &pose[i * columns..(i + 1) * columns];
            let mut p = if columns == POSE_COLUMNS {
                smplx_row(row)
            } else {
                smplh_row(row)
            };
            if let Some(t) = &trans {
                p.transl = DVec3::new(t[3 * i], t[3 * i + 1], t[3 * i + 2]);
            }
            if let Some((cols, e)) = &expression {
                let k = (*cols).min(N_EXPRESSION);
                p.expression[..k].copy_from_slice(&e[i * cols..i * cols + k]);
            }
            p
        })
        .collect();
    let (up, hands) = match layout {
        MotionLayout::Amass => (UpAxis::Z, Hands::Absolute),
        _ => (UpAxis::Y, Hands::RelativeToMean),
    };
    Ok(Motion {
        file: file.into(),
        layout,
        frames,
        fps,
        betas,
        gender,
        up,
        hands,
    })
}

/// The first present array among `names` (aliases), checked against `dims`.
fn first_of(
    npz: &mut Npz,
    names: &[&str],
    dims: &[Dim],
) -> Result<Option<(String, NdArray)>, MotionError> {
    for name in names {
        if let Some(a) = npz.get_checked(name, dims)? {
            return Ok(Some((name.to_string(), a)));
        }
    }
    Ok(None)
}

/// `mocap_frame_rate` or `mocap_framerate` (a 0-d int or float), else frames over
/// `mocap_time_length`, else none.
fn frame_rate(npz: &mut Npz, file: &Path, n: usize) -> Result<Option<f64>, MotionError> {
    for key in ["mocap_frame_rate", "mocap_framerate"] {
        if let Some(a) = npz.get(key)? {
            let rate = a.scalar_f64().filter(|r| r.is_finite() && *r > 0.0);
            return rate.map(Some).ok_or_else(|| MotionError::Array {
                file: file.into(),
                array: key.into(),
                problem: format!(
                    "expected a positive frame rate (a 0-d number), found shape {:?} of {}",
                    a.shape(),
                    a.dtype()
                ),
            });
        }
    }
    if let Some(length) = npz.get("mocap_time_length")?.and_then(|a| a.scalar_f64())
        && length.is_finite()
        && length > 0.0
    {
        return Ok(Some(n as f64 / length));
    }
    Ok(None)
}

fn v(row: &[f64], k: usize) -> DVec3 {
    DVec3::new(row[3 * k], row[3 * k + 1], row[3 * k + 2])
}

/// One SMPL-X row: root, 21 body joints, jaw, eyes, left hand, right hand.
fn smplx_row(row: &[f64]) -> FrameParams {
    let mut p = FrameParams {
        global_orient: v(row, 0),
        jaw_pose: v(row, 22),
        leye_pose: v(row, 23),
        reye_pose: v(row, 24),
        ..Default::default()
    };
    for j in 0..N_BODY_JOINTS - 1 {
        p.body_pose[j] = v(row, 1 + j);
    }
    for j in 0..N_HAND_JOINTS {
        p.left_hand_pose[j] = v(row, 25 + j);
        p.right_hand_pose[j] = v(row, 40 + j);
    }
    p
}

/// One SMPL+H row: root, 21 body joints, left hand, right hand (no jaw, no eyes).
fn smplh_row(row: &[f64]) -> FrameParams {
    let mut p = FrameParams {
        global_orient: v(row, 0),
        ..Default::default()
    };
    for j in 0..N_BODY_JOINTS - 1 {
        p.body_pose[j] = v(row, 1 + j);
    }
    for j in 0..N_HAND_JOINTS {
        p.left_hand_pose[j] = v(row, N_BODY_JOINTS + j);
        p.right_hand_pose[j] = v(row, N_BODY_JOINTS + N_HAND_JOINTS + j);
    }
    p
}
