//! Body measurements per identity and the rest (T-pose) skeleton built from them,
//! fingers and thumbs included. The figure's shapes hang on these joints.

use glam::DVec3;

use super::head_frame::HeadFrame;
use crate::talk::scene_rng;
use talkin_human::body::skeleton::joint::*;
use talkin_human::body::{N_JOINTS, Skeleton};

/// Body measurements of one identity (factors of a 1.7 m adult, shoulder half-width in m).
#[derive(Clone, Copy, Debug)]
pub struct Proportions {
    pub height: f64,
    pub shoulder: f64,
    pub arm: f64,
    pub leg: f64,
    pub head: f64,
    pub hand: f64,
}

/// The authored proportions of identities 0, 1 and 2.
const PROPORTIONS: [Proportions; 3] = [
    Proportions {
        height: 0.97,
        shoulder: 0.165,
        arm: 0.97,
        leg: 1.0,
        head: 1.0,
        hand: 0.95,
    },
    Proportions {
        height: 1.07,
        shoulder: 0.198,
        arm: 1.06,
        leg: 1.03,
        head: 1.06,
        hand: 1.08,
    },
    Proportions {
        height: 0.91,
        shoulder: 0.152,
        arm: 0.92,
        leg: 0.96,
        head: 0.95,
        hand: 0.9,
    },
];

/// The proportions of identity `i`: three authored ones, then random variations of them.
pub fn proportions(identity: usize) -> Proportions {
    let p = PROPORTIONS[identity % 3];
    if identity < 3 {
        return p;
    }
    let mut rng = scene_rng(0x5eed_1d00 + identity as u64);
    let mut f = |x: f64, spread: f64| x * (1.0 + rng.uniform(-spread, spread));
    Proportions {
        height: f(p.height, 0.06),
        shoulder: f(p.shoulder, 0.08),
        arm: f(p.arm, 0.05),
        leg: f(p.leg, 0.04),
        head: f(p.head, 0.05),
        hand: f(p.hand, 0.06),
    }
}

/// Left-hand finger knuckles relative to the wrist (index, middle, pinky, ring), segment
/// lengths and radii, for a 1.0 hand. The right hand mirrors x.
pub(super) const FINGERS: [([f64; 3], [f64; 3], f32); 4] = [
    ([0.088, 0.004, 0.026], [0.038, 0.024, 0.021], 0.0093),
    ([0.093, 0.004, 0.006], [0.042, 0.027, 0.023], 0.0096),
    ([0.080, 0.000, -0.032], [0.030, 0.020, 0.018], 0.0080),
    ([0.089, 0.002, -0.013], [0.038, 0.026, 0.021], 0.0090),
];
/// Left thumb: base (CMC) relative to the wrist, direction, segment lengths, radius.
pub(super) const THUMB: ([f64; 3], [f64; 3], [f64; 3], f32) = (
    [0.024, -0.012, 0.026],
    [0.72, -0.2, 0.66],
    [0.036, 0.032, 0.026],
    0.0108,
);

/// Rest (T-pose) joints of identity `identity`, in metres, feet near y = 0.
pub fn default_rest_joints(identity: usize) -> Skeleton {
    rest_joints(&proportions(identity))
}

/// Rest joints from measurements.
pub fn rest_joints(p: &Proportions) -> Skeleton {
    let s = p.height;
    let mut j = [DVec3::ZERO; N_JOINTS];
    let hip_y = 0.88 * s * p.leg;
    j[PELVIS] = DVec3::new(0.0, hip_y + 0.07 * s, 0.0);
    j[LEFT_HIP] = DVec3::new(0.085 * s, hip_y, 0.0);
    j[RIGHT_HIP] = DVec3::new(-0.085 * s, hip_y, 0.0);
    j[SPINE1] = j[PELVIS] + DVec3::new(0.0, 0.10 * s, -0.012);
    j[SPINE2] = j[SPINE1] + DVec3::new(0.0, 0.13 * s, 0.004);
    j[SPINE3] = j[SPINE2] + DVec3::new(0.0, 0.06 * s, 0.01);
    j[NECK] = j[SPINE3] + DVec3::new(0.0, 0.2 * s, -0.02);
    j[HEAD] = j[NECK] + DVec3::new(0.0, 0.08 * s, 0.015);
    for (side, sign) in [(0usize, 1.0f64), (1, -1.0)] {
        let m = |v: DVec3| DVec3::new(v.x * sign, v.y, v.z);
        j[LEFT_KNEE + side] = m(DVec3::new(0.09 * s, hip_y - 0.40 * s * p.leg, 0.01));
        j[LEFT_ANKLE + side] = m(DVec3::new(0.085 * s, hip_y - 0.80 * s * p.leg, -0.03));
        j[LEFT_FOOT + side] = m(DVec3::new(0.10 * s, 0.02, 0.10));
        let shoulder_y = j[SPINE3].y + 0.16 * s;
        j[LEFT_COLLAR + side] = m(DVec3::new(0.075 * s, j[SPINE3].y + 0.14 * s, -0.005));
        j[LEFT_SHOULDER + side] = m(DVec3::new(p.shoulder, shoulder_y, -0.015));
        let elbow_x = p.shoulder + 0.27 * p.arm;
        j[LEFT_ELBOW + side] = m(DVec3::new(elbow_x, shoulder_y, -0.025));
        let wrist = m(DVec3::new(elbow_x + 0.24 * p.arm, shoulder_y, -0.015));
        j[LEFT_WRIST + side] = wrist;
        hand_joints(&mut j, p.hand, side, wrist, m);
    }
    let head = HeadFrame::new(j[HEAD], p.head);
    j[JAW] = head.at(0.0, 0.06, 0.0);
    for (eye, sign) in [(LEFT_EYE, 1.0f32), (RIGHT_EYE, -1.0)] {
        j[eye] = head.eye_centre(sign).as_dvec3();
    }
    Skeleton { rest_joints: j }
}

/// The finger and thumb joints of one hand, laid out from the wrist; `m` mirrors x for
/// the right hand.
fn hand_joints(
    j: &mut [DVec3; N_JOINTS],
    hand: f64,
    side: usize,
    wrist: DVec3,
    m: impl Fn(DVec3) -> DVec3,
) {
    let first = LEFT_HAND_FIRST + 15 * side;
    for (f, (knuckle, lengths, _)) in FINGERS.iter().enumerate() {
        let mut at = wrist + m(DVec3::from(*knuckle) * hand);
        for (k, &len) in lengths.iter().enumerate() {
            j[first + 3 * f + k] = at;
            at += m(DVec3::X) * len * hand;
        }
    }
    let (base, dir, lengths, _) = THUMB;
    let dir = m(DVec3::from(dir).normalize());
    let mut at = wrist + m(DVec3::from(base) * hand);
    for (k, &len) in lengths.iter().enumerate() {
        j[first + 12 + k] = at;
        at += dir * len * hand;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identities_differ_and_hands_follow_the_smplx_convention() {
        let a = default_rest_joints(0).rest_joints;
        let b = default_rest_joints(1).rest_joints;
        let height = |j: &[DVec3; N_JOINTS]| j[HEAD].y - j[LEFT_ANKLE].y;
        let shoulders = |j: &[DVec3; N_JOINTS]| j[LEFT_SHOULDER].x - j[RIGHT_SHOULDER].x;
        assert!(height(&b) > height(&a) + 0.05);
        assert!(shoulders(&b) > shoulders(&a) + 0.04);
        for j in [a, b, default_rest_joints(5).rest_joints] {
            // +x is the subject's left; fingers point away from the body; the thumb sits on
            // the front (+z) side of the palm in the T-pose with palms down.
            assert!(j[LEFT_WRIST].x > j[LEFT_ELBOW].x && j[RIGHT_WRIST].x < j[RIGHT_ELBOW].x);
            for (wrist, first, sign) in [
                (LEFT_WRIST, LEFT_HAND_FIRST, 1.0),
                (RIGHT_WRIST, RIGHT_HAND_FIRST, -1.0),
            ] {
                for f in 0..5 {
                    for k in 0..3 {
                        assert!((j[first + 3 * f + k].x - j[wrist].x) * sign > 0.0);
                    }
                }
                let thumb = j[first + 12];
                assert!(
                    thumb.z > j[first + 3].z && thumb.z > j[first + 9].z,
                    "thumb in front"
                );
                assert!(j[first].z > j[first + 6].z, "index in front of the pinky");
            }
            assert!(j[LEFT_EYE].x > 0.0 && j[LEFT_EYE].z > j[HEAD].z);
        }
    }
}
