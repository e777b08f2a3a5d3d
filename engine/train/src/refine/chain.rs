//! The loss's gradient with respect to a frame's correction: the field gives it with
//! respect to the skinning transforms and the networks' conditions ([`PoseGrads`]); the
//! transforms depend on the pose through forward kinematics, differentiated here by
//! central differences in f64 (69 coordinates, and the hands' 90 where the field skins the
//! fingers; two 55-joint chains each: microseconds, and exact to ~1e-9 relative, far below
//! the gradient's own noise).

use talkin_avatar::refined::layout::{
    BODY, DIM, EXPRESSION, HANDS, JAW, ORIENT, TRANSL, corrected,
};
use talkin_human::body::skeleton::{N_BODY_JOINTS, N_JOINTS};
use talkin_human::body::{FrameParams, PosedSkeleton, Skeleton, canonical_from_posed};
use talkin_nets::PoseGrads;
use talkin_nets::field::leaves::TRANSFORM_ROWS;

/// Step of the central differences (radians or metres).
const H: f64 = 1e-6;

/// The top three rows of each joint's `canonical_from_posed` in pose `params`.
fn transforms(
    skeleton: &Skeleton,
    canonical: &PosedSkeleton,
    params: &FrameParams,
) -> [[f64; TRANSFORM_ROWS]; N_JOINTS] {
    canonical_from_posed(&skeleton.pose(params), canonical).map(|m| {
        let (r, t) = (m.matrix3, m.translation);
        [
            r.x_axis.x, r.y_axis.x, r.z_axis.x, t.x, //
            r.x_axis.y, r.y_axis.y, r.z_axis.y, t.y, //
            r.x_axis.z, r.y_axis.z, r.z_axis.z, t.z,
        ]
    })
}

/// `d loss / d delta` at correction `delta` of fit `fit`, from the field's gradients
/// `grads` at the corrected pose.
pub fn correction_gradient(
    skeleton: &Skeleton,
    canonical: &PosedSkeleton,
    fit: &FrameParams,
    delta: &[f32],
    grads: &PoseGrads,
) -> [f64; DIM] {
    let mut g = [0.0f64; DIM];
    let base = corrected(fit, delta);
    // Through the skinning transforms: orientation, body joints, translation, and the
    // hands where the field skins the fingers (their transforms have a gradient).
    let fingers_skinned = (grads.canonical_from_posed.get(N_BODY_JOINTS..))
        .unwrap_or_default()
        .iter()
        .flatten()
        .any(|&v| v != 0.0);
    let hands = if fingers_skinned { HANDS } else { 0..0 };
    let kinematic = ORIENT.chain(BODY).chain(TRANSL).chain(hands);
    for k in kinematic {
        // The shift is added in f64 on top of the corrected pose (an f32 step of 1e-6
        // would round away).
        let mut unit = [0.0f32; DIM];
        unit[k] = 1.0;
        let d = corrected(&FrameParams::default(), &unit);
        let at = |h: f64| {
            let mut p = base.clone();
            add_scaled(&mut p, &d, h);
            transforms(skeleton, canonical, &p)
        };
        let (plus, minus) = (at(H), at(-H));
        let mut sum = 0.0;
        for b in 0..grads.canonical_from_posed.len().min(N_JOINTS) {
            for r in 0..TRANSFORM_ROWS {
                sum += grads.canonical_from_posed[b][r] as f64 * (plus[b][r] - minus[b][r]);
            }
        }
        g[k] = sum / (2.0 * H);
    }
    // Through the networks' conditions.
    if grads.body_pose.len() == BODY.len() {
        for (i, v) in grads.body_pose.iter().enumerate() {
            g[BODY.start + i] += *v as f64;
        }
    }
    for (i, v) in grads.jaw.iter().enumerate().take(JAW.len()) {
        g[JAW.start + i] += *v as f64;
    }
    for (i, v) in grads.hand_pose.iter().enumerate().take(HANDS.len()) {
        g[HANDS.start + i] += *v as f64;
    }
    for (i, v) in grads.expression.iter().enumerate().take(EXPRESSION.len()) {
        g[EXPRESSION.start + i] += *v as f64;
    }
    g
}

/// `p += h * d` for the coordinates a unit correction `d` (built on the zero pose) names.
fn add_scaled(p: &mut FrameParams, d: &FrameParams, h: f64) {
    p.global_orient += h * d.global_orient;
    let joints = (p.body_pose.iter_mut().zip(&d.body_pose))
        .chain(p.left_hand_pose.iter_mut().zip(&d.left_hand_pose))
        .chain(p.right_hand_pose.iter_mut().zip(&d.right_hand_pose));
    for (a, b) in joints {
        *a += h * *b;
    }
    p.transl += h * d.transl;
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use talkin_human::body::canonical_params;
    use talkin_human::body::skeleton::PARENTS;

    use super::*;

    fn skeleton() -> Skeleton {
        let mut rest = [DVec3::ZERO; N_JOINTS];
        for j in 1..N_JOINTS {
            let p = PARENTS[j] as usize;
            rest[j] = rest[p] + DVec3::new(0.013 * j as f64 - 0.2, 0.09, 0.01 * (j % 3) as f64);
        }
        Skeleton { rest_joints: rest }
    }

    /// A loss linear in the transforms, `sum(W * M)`: its gradient through the chain rule
    /// matches the finite difference of the loss in each coordinate, including an elbow
    /// and a finger carried past pi. With weight on the body joints' transforms only (a
    /// field that moves the fingers with their wrist), the hands' coordinates get only
    /// their conditions' gradient; with weight on the fingers' too, theirs through the
    /// fingers' transforms.
    #[test]
    fn the_chain_rule_matches_differences_of_the_loss() {
        let s = skeleton();
        let canonical = s.pose(&canonical_params());
        let mut fit = FrameParams {
            global_orient: DVec3::new(0.2, -0.4, 0.1),
            transl: DVec3::new(0.1, 0.9, 2.0),
            ..FrameParams::default()
        };
        fit.body_pose[17] = DVec3::new(0.0, 3.1, 0.0); // left elbow, near pi
        fit.left_hand_pose[1] = DVec3::new(0.0, 0.0, -3.1); // a finger, near pi
        let mut delta = vec![0.0f32; DIM];
        delta[BODY.start + 3 * 17 + 1] = 0.1; // past pi
        delta[HANDS.start + 3 + 2] = -0.1; // past pi
        for skinned in [N_BODY_JOINTS, N_JOINTS] {
            let w: Vec<[f32; TRANSFORM_ROWS]> = (0..N_JOINTS)
                .map(|b| {
                    std::array::from_fn(|r| match b < skinned {
                        true => ((b * 7 + r * 3) % 11) as f32 / 11.0 - 0.5,
                        false => 0.0,
                    })
                })
                .collect();
            let grads = PoseGrads {
                canonical_from_posed: w.clone(),
                body_pose: vec![0.0; 63],
                expression: vec![0.5; 10],
                jaw: vec![0.0; 3],
                hand_pose: vec![0.25; 90],
            };
            let loss = |delta: &[f32]| -> f64 {
                let m = transforms(&s, &canonical, &corrected(&fit, delta));
                (0..N_JOINTS)
                    .flat_map(|b| (0..TRANSFORM_ROWS).map(move |r| (b, r)))
                    .map(|(b, r)| w[b][r] as f64 * m[b][r])
                    .sum()
            };
            let g = correction_gradient(&s, &canonical, &fit, &delta, &grads);
            assert!(g.iter().all(|v| v.is_finite()));
            for k in ORIENT.chain(BODY).chain(TRANSL).chain(HANDS) {
                let h = 1e-3f32;
                let (mut plus, mut minus) = (delta.clone(), delta.clone());
                plus[k] += h;
                minus[k] -= h;
                // The hands' conditions add their own 0.25.
                let condition = if HANDS.contains(&k) { 0.25 } else { 0.0 };
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * h as f64) + condition;
                assert!(
                    (g[k] - fd).abs() < 2e-3 * (1.0 + fd.abs()),
                    "{skinned} joints, {k}: {} vs {fd}",
                    g[k]
                );
            }
            // Conditions pass straight through.
            assert!(EXPRESSION.clone().all(|k| g[k] == 0.5));
            if skinned == N_BODY_JOINTS {
                assert!(HANDS.clone().all(|k| g[k] == 0.25));
            } else {
                assert!(HANDS.clone().any(|k| (g[k] - 0.25).abs() > 1e-3));
            }
        }
    }
}
