//! The limb capsules of a posed skeleton, for the capsule BVH: one capsule per bone
//! (torso segments, neck, head, legs, upper and lower arms, palms, 30 finger segments),
//! labelled with its body part and the joint that moves it.
//!
//! Radii are fractions of the skeleton's size ([`Skeleton::scale`]); they are the bare
//! skeleton's. Clothing and hair stick out of them: the data decides the margin that
//! inflates them (grids' margin fitting), not these numbers.

use glam::DVec3;
use talkin_grids::{Capsule, Part};

use super::fk::{PosedSkeleton, Skeleton};
use super::skeleton::joint::*;

/// Where a capsule's second end comes from.
#[derive(Clone, Copy)]
enum End {
    Joint(usize),
    /// Past the last joint of a chain (finger tips): `to + (to - from) * k` in the rest
    /// pose, moving with `to`.
    Extrapolate {
        from: usize,
        to: usize,
        k: f64,
    },
    /// Along the joint's own +y axis (up in the T-pose), `len` x scale from the joint.
    Up(f64),
}

struct Bone {
    from: usize,
    to: End,
    radius: f64,
    part: Part,
}

const fn b(from: usize, to: usize, radius: f64, part: Part) -> Bone {
    Bone {
        from,
        to: End::Joint(to),
        radius,
        part,
    }
}

/// The bone table. Radii in units of [`Skeleton::scale`] (metres for an adult).
fn bones() -> Vec<Bone> {
    let mut v = vec![
        b(PELVIS, SPINE1, 0.12, Part::Body),
        b(SPINE1, SPINE2, 0.12, Part::Body),
        b(SPINE2, SPINE3, 0.13, Part::Body),
        b(SPINE3, NECK, 0.11, Part::Body),
        b(PELVIS, LEFT_HIP, 0.10, Part::Body),
        b(PELVIS, RIGHT_HIP, 0.10, Part::Body),
        b(SPINE3, LEFT_COLLAR, 0.07, Part::Body),
        b(SPINE3, RIGHT_COLLAR, 0.07, Part::Body),
        b(LEFT_COLLAR, LEFT_SHOULDER, 0.06, Part::Body),
        b(RIGHT_COLLAR, RIGHT_SHOULDER, 0.06, Part::Body),
        b(LEFT_HIP, LEFT_KNEE, 0.075, Part::Body),
        b(RIGHT_HIP, RIGHT_KNEE, 0.075, Part::Body),
        b(LEFT_KNEE, LEFT_ANKLE, 0.055, Part::Body),
        b(RIGHT_KNEE, RIGHT_ANKLE, 0.055, Part::Body),
        b(LEFT_ANKLE, LEFT_FOOT, 0.045, Part::Body),
        b(RIGHT_ANKLE, RIGHT_FOOT, 0.045, Part::Body),
        b(NECK, HEAD, 0.055, Part::Body),
        Bone {
            from: HEAD,
            to: End::Up(0.17),
            radius: 0.10,
            part: Part::Head,
        },
        b(LEFT_SHOULDER, LEFT_ELBOW, 0.045, Part::Arms),
        b(RIGHT_SHOULDER, RIGHT_ELBOW, 0.045, Part::Arms),
        b(LEFT_ELBOW, LEFT_WRIST, 0.038, Part::Arms),
        b(RIGHT_ELBOW, RIGHT_WRIST, 0.038, Part::Arms),
    ];
    for (wrist, first) in [
        (LEFT_WRIST, LEFT_HAND_FIRST),
        (RIGHT_WRIST, RIGHT_HAND_FIRST),
    ] {
        // Palm: wrist to the knuckles of index, middle and pinky covers its width.
        for finger in [0, 1, 2] {
            v.push(b(wrist, first + 3 * finger, 0.022, Part::Hands));
        }
        for finger in 0..5 {
            let j1 = first + 3 * finger;
            let radius = if finger == 4 { 0.011 } else { 0.009 };
            v.push(b(j1, j1 + 1, radius, Part::Hands));
            v.push(b(j1 + 1, j1 + 2, radius, Part::Hands));
            let tip = End::Extrapolate {
                from: j1 + 1,
                to: j1 + 2,
                k: 0.9,
            };
            v.push(Bone {
                from: j1 + 2,
                to: tip,
                radius: radius * 0.9,
                part: Part::Hands,
            });
        }
    }
    v
}

/// The capsules of `skeleton` posed as `posed`, in world space.
pub fn limb_capsules(skeleton: &Skeleton, posed: &PosedSkeleton) -> Vec<Capsule> {
    let scale = skeleton.scale();
    bones()
        .into_iter()
        .map(|bone| {
            let a = posed.joint(bone.from);
            let end = match bone.to {
                End::Joint(j) => posed.joint(j),
                End::Extrapolate { from, to, k } => {
                    // The tip is rigid with `to` (the capsule's own joint): extrapolated in
                    // the rest pose and carried by `to`'s transform, so it follows a bent
                    // last phalanx instead of pointing on along the one before it.
                    let rest = &skeleton.rest_joints;
                    let tip = rest[to] + (rest[to] - rest[from]) * k;
                    posed.world_from_rest[to].transform_point3(tip)
                }
                End::Up(len) => {
                    let up = posed.world_from_joint[bone.from].transform_vector3(DVec3::Y);
                    a + up * (len * scale)
                }
            };
            Capsule {
                a: a.as_vec3(),
                b: end.as_vec3(),
                radius: (bone.radius * scale) as f32,
                part: bone.part,
                bone: bone.from as u16,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::{FrameParams, N_JOINTS};

    #[test]
    fn every_part_and_finger_has_capsules() {
        let mut rest = [DVec3::ZERO; N_JOINTS];
        for j in 1..N_JOINTS {
            rest[j] = rest[crate::body::PARENTS[j] as usize] + DVec3::new(0.01, 0.05, 0.0);
        }
        let s = Skeleton { rest_joints: rest };
        let caps = limb_capsules(&s, &s.pose(&FrameParams::default()));
        for part in Part::ALL {
            assert!(caps.iter().any(|c| c.part == part), "{part:?}");
        }
        // 3 segments per finger, 10 fingers.
        let finger_segments = caps
            .iter()
            .filter(|c| c.bone >= LEFT_HAND_FIRST as u16)
            .count();
        assert_eq!(finger_segments, 30);
        assert!(
            caps.iter()
                .all(|c| c.a.is_finite() && c.b.is_finite() && c.radius > 0.0)
        );
    }

    /// A last phalanx bent 90 degrees: its capsule turns with it (rigid with its joint,
    /// as the finger's surface is), not on along the middle phalanx.
    #[test]
    fn a_bent_fingertip_capsule_follows_its_phalanx() {
        let mut rest = [DVec3::ZERO; N_JOINTS];
        for j in 1..N_JOINTS {
            rest[j] = rest[crate::body::PARENTS[j] as usize] + DVec3::new(0.03, 0.0, 0.0);
        }
        let s = Skeleton { rest_joints: rest };
        let distal = LEFT_HAND_FIRST + 2; // index finger, third joint
        let mut p = FrameParams::default();
        p.left_hand_pose[2] = DVec3::new(0.0, 0.0, -std::f64::consts::FRAC_PI_2);
        let posed = s.pose(&p);
        let tip = limb_capsules(&s, &posed)
            .into_iter()
            .find(|c| c.bone as usize == distal)
            .unwrap();
        // The rest tip: 0.9 of the last segment past the joint, along +x.
        let want = posed.world_from_rest[distal]
            .transform_point3(rest[distal] + DVec3::new(0.027, 0.0, 0.0));
        assert!(
            (tip.b.as_dvec3() - want).length() < 1e-6,
            "{:?} against {want:?}",
            tip.b
        );
        // Bent: perpendicular to the middle phalanx.
        let middle = posed.joint(distal) - posed.joint(distal - 1);
        let last = tip.b.as_dvec3() - tip.a.as_dvec3();
        assert!(middle.normalize().dot(last.normalize()).abs() < 1e-6);
    }
}
