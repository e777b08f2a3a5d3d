//! A frame's correction as one flat vector, and how it is added to a fit.
//!
//! Rotations are axis-angle vectors added to the fit's (a correction may carry a joint
//! past pi: Rodrigues' formula takes any length, so the posed skeleton stays finite);
//! translation in metres; expression in the fit's units.

use std::ops::Range;

use glam::DVec3;
use talkin_human::body::FrameParams;
use talkin_human::body::params::N_EXPRESSION;
use talkin_human::body::skeleton::{N_BODY_JOINTS, N_HAND_JOINTS};

/// Global orientation.
pub const ORIENT: Range<usize> = 0..3;
/// Body joints 1..22, 3 each.
pub const BODY: Range<usize> = 3..3 + 3 * (N_BODY_JOINTS - 1);
/// Jaw.
pub const JAW: Range<usize> = BODY.end..BODY.end + 3;
/// Left then right hand, 15 joints x 3 each.
pub const HANDS: Range<usize> = JAW.end..JAW.end + 6 * N_HAND_JOINTS;
/// Expression coefficients.
pub const EXPRESSION: Range<usize> = HANDS.end..HANDS.end + N_EXPRESSION;
/// Translation (metres).
pub const TRANSL: Range<usize> = EXPRESSION.end..EXPRESSION.end + 3;
/// Numbers in a correction.
pub const DIM: usize = TRANSL.end;

/// The groups of a correction, with the scale of their learning rate (per unit of the
/// group: a step of `lr` radians turns a joint by as much as `0.2 lr` metres moves the
/// body at arm's length).
pub const GROUPS: [(&str, Range<usize>, f64); 6] = [
    ("global_orient", ORIENT, 1.0),
    ("body_pose", BODY, 1.0),
    ("jaw_pose", JAW, 1.0),
    ("hand_pose", HANDS, 1.0),
    ("expression", EXPRESSION, 1.0),
    ("transl", TRANSL, 0.2),
];

/// `params` as a flat vector in the correction's layout (the fit's coordinates).
pub fn flatten(params: &FrameParams) -> [f64; DIM] {
    let mut v = [0.0; DIM];
    v[ORIENT].copy_from_slice(&params.global_orient.to_array());
    for (j, r) in params.body_pose.iter().enumerate() {
        v[BODY.start + 3 * j..BODY.start + 3 * j + 3].copy_from_slice(&r.to_array());
    }
    v[JAW].copy_from_slice(&params.jaw_pose.to_array());
    for (j, r) in params
        .left_hand_pose
        .iter()
        .chain(&params.right_hand_pose)
        .enumerate()
    {
        v[HANDS.start + 3 * j..HANDS.start + 3 * j + 3].copy_from_slice(&r.to_array());
    }
    v[EXPRESSION].copy_from_slice(&params.expression);
    v[TRANSL].copy_from_slice(&params.transl.to_array());
    v
}

/// `params` with correction `delta` added (eyes are not corrected).
pub fn corrected(params: &FrameParams, delta: &[f32]) -> FrameParams {
    assert_eq!(delta.len(), DIM, "a correction has {DIM} numbers");
    let d = |i: usize| DVec3::new(delta[i] as f64, delta[i + 1] as f64, delta[i + 2] as f64);
    let mut p = params.clone();
    p.global_orient += d(ORIENT.start);
    for (j, r) in p.body_pose.iter_mut().enumerate() {
        *r += d(BODY.start + 3 * j);
    }
    p.jaw_pose += d(JAW.start);
    for (j, r) in p
        .left_hand_pose
        .iter_mut()
        .chain(p.right_hand_pose.iter_mut())
        .enumerate()
    {
        *r += d(HANDS.start + 3 * j);
    }
    for (e, x) in p.expression.iter_mut().zip(&delta[EXPRESSION]) {
        *e += *x as f64;
    }
    p.transl += d(TRANSL.start);
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_covers_every_number_once() {
        assert_eq!(DIM, 3 + 63 + 3 + 90 + 10 + 3);
        let mut seen = [0; DIM];
        for (_, r, _) in GROUPS {
            r.for_each(|i| seen[i] += 1);
        }
        assert!(seen.iter().all(|&c| c == 1));
    }

    #[test]
    fn a_correction_adds_to_the_flattened_fit() {
        let mut p = FrameParams::default();
        p.body_pose[4] = DVec3::new(0.1, 0.2, 0.3);
        p.transl = DVec3::new(1.0, 2.0, 3.0);
        let delta: Vec<f32> = (0..DIM).map(|i| i as f32 * 1e-3).collect();
        let q = corrected(&p, &delta);
        let (a, b) = (flatten(&p), flatten(&q));
        for i in 0..DIM {
            assert!((b[i] - a[i] - delta[i] as f64).abs() < 1e-9, "{i}");
        }
        assert_eq!(q.leye_pose, p.leye_pose);
    }
}
