//! Forward kinematics and the skinning transforms of a posed skeleton, in f64.

use glam::{DAffine3, DVec3};

use super::params::FrameParams;
use super::rotation::rotation_from_axis_angle;
use super::skeleton::{N_JOINTS, PARENTS, joint};

/// A subject's skeleton: rest-pose (T-pose) joint locations in metres.
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    pub rest_joints: [DVec3; N_JOINTS],
}

impl Skeleton {
    /// A stick figure in a T-pose, pelvis 0.95 m up: each joint a step from its parent,
    /// 12 cm up along the spine, neck, head and legs, 15 cm out along each arm, 3 cm out
    /// along each finger. For tests and examples that need a plausible body, not a
    /// person's.
    pub fn stick_figure() -> Skeleton {
        use joint::*;
        let mut rest = [DVec3::ZERO; N_JOINTS];
        rest[0] = DVec3::new(0.0, 0.95, 0.0);
        for j in 1..N_JOINTS {
            let side = match j {
                LEFT_COLLAR | LEFT_SHOULDER | LEFT_ELBOW | LEFT_WRIST => 0.15,
                RIGHT_COLLAR | RIGHT_SHOULDER | RIGHT_ELBOW | RIGHT_WRIST => -0.15,
                j if (LEFT_HAND_FIRST..RIGHT_HAND_FIRST).contains(&j) => 0.03,
                j if j >= RIGHT_HAND_FIRST => -0.03,
                _ => 0.0,
            };
            let up = if side == 0.0 { 0.12 } else { 0.0 };
            rest[j] = rest[PARENTS[j] as usize] + DVec3::new(side, up, 0.0);
        }
        Skeleton { rest_joints: rest }
    }
}

/// A skeleton in one pose.
#[derive(Clone, Debug)]
pub struct PosedSkeleton {
    /// Joint frame -> world: rotation = the joint's global rotation, translation = its
    /// posed location.
    pub world_from_joint: [DAffine3; N_JOINTS],
    /// Rest (T-pose) space -> world for points rigidly attached to each joint: the SMPL
    /// skinning transform `G_j * T(-J_j)`.
    pub world_from_rest: [DAffine3; N_JOINTS],
}

impl PosedSkeleton {
    /// Posed joint location.
    pub fn joint(&self, j: usize) -> DVec3 {
        self.world_from_joint[j].translation
    }

    /// All posed joint locations.
    pub fn joints(&self) -> [DVec3; N_JOINTS] {
        std::array::from_fn(|j| self.joint(j))
    }
}

impl Skeleton {
    /// Poses the skeleton: `G_j = G_parent(j) * [R_j | J_j - J_parent(j)]`, root at
    /// `transl + J_0`.
    pub fn pose(&self, params: &FrameParams) -> PosedSkeleton {
        let local = params.local_rotations();
        let mut world_from_joint = [DAffine3::IDENTITY; N_JOINTS];
        for j in 0..N_JOINTS {
            let rotation = rotation_from_axis_angle(local[j]);
            world_from_joint[j] = match usize::try_from(PARENTS[j]) {
                Err(_) => {
                    DAffine3::from_mat3_translation(rotation, params.transl + self.rest_joints[0])
                }
                Ok(p) => {
                    let offset = self.rest_joints[j] - self.rest_joints[p];
                    world_from_joint[p] * DAffine3::from_mat3_translation(rotation, offset)
                }
            };
        }
        let world_from_rest = std::array::from_fn(|j| {
            world_from_joint[j] * DAffine3::from_translation(-self.rest_joints[j])
        });
        PosedSkeleton {
            world_from_joint,
            world_from_rest,
        }
    }

    /// Distance pelvis -> neck relative to an adult's (0.55 m): the size unit that capsule
    /// radii and the generator's proportions scale with.
    pub fn scale(&self) -> f64 {
        (self.rest_joints[joint::NECK] - self.rest_joints[joint::PELVIS]).length() / 0.55
    }
}

/// The canonical pose every frame is mapped back to: a mild A-pose (arms 35 degrees below
/// horizontal, legs 8 degrees apart) so that arms and legs stay clear of the torso, as in
/// HumanNeRF's canonical space. Zero translation.
pub fn canonical_params() -> FrameParams {
    let arm = 35f64.to_radians();
    let leg = 8f64.to_radians();
    let mut p = FrameParams::default();
    // body_pose[j - 1] is joint j. +x is the subject's left: lowering the left arm (along
    // +x) is a rotation about -z, the right arm about +z.
    p.body_pose[joint::LEFT_SHOULDER - 1] = DVec3::new(0.0, 0.0, -arm);
    p.body_pose[joint::RIGHT_SHOULDER - 1] = DVec3::new(0.0, 0.0, arm);
    p.body_pose[joint::LEFT_HIP - 1] = DVec3::new(0.0, 0.0, leg);
    p.body_pose[joint::RIGHT_HIP - 1] = DVec3::new(0.0, 0.0, -leg);
    p
}

/// Per SMPL-X joint, the map from posed (observation) space to canonical space of points
/// rigidly attached to that joint: `canonical_from_posed_j = world_from_rest_j(canonical)
/// * world_from_rest_j(posed)^-1`. Inverse LBS blends these with learned weights.
pub fn canonical_from_posed(
    posed: &PosedSkeleton,
    canonical: &PosedSkeleton,
) -> [DAffine3; N_JOINTS] {
    std::array::from_fn(|j| canonical.world_from_rest[j] * posed.world_from_rest[j].inverse())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain_skeleton() -> Skeleton {
        // Every joint one step further along +y than its parent, plus its index in x so
        // joints are distinct.
        let mut rest = [DVec3::ZERO; N_JOINTS];
        for j in 1..N_JOINTS {
            let p = PARENTS[j] as usize;
            rest[j] = rest[p] + DVec3::new(0.01 * j as f64, 0.1, 0.0);
        }
        Skeleton { rest_joints: rest }
    }

    #[test]
    fn zero_pose_is_the_rest_pose() {
        let s = chain_skeleton();
        let posed = s.pose(&FrameParams::default());
        for j in 0..N_JOINTS {
            assert!((posed.joint(j) - s.rest_joints[j]).length() < 1e-15);
            let p = DVec3::new(0.3, -0.2, 0.1);
            assert!((posed.world_from_rest[j].transform_point3(p) - p).length() < 1e-15);
        }
    }

    #[test]
    fn hand_computed_chain() {
        // pelvis -> spine1 -> spine2: rotate pelvis 90 deg about z, spine1 90 deg about x.
        let s = chain_skeleton();
        let mut p = FrameParams {
            global_orient: DVec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            transl: DVec3::new(1.0, 2.0, 3.0),
            ..Default::default()
        };
        p.body_pose[joint::SPINE1 - 1] = DVec3::new(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        let posed = s.pose(&p);
        let r = |j: usize| s.rest_joints[j];
        // Rz(90) maps (x, y, z) -> (-y, x, z).
        let rz = |v: DVec3| DVec3::new(-v.y, v.x, v.z);
        // Rx(90) maps (x, y, z) -> (x, -z, y).
        let rx = |v: DVec3| DVec3::new(v.x, -v.z, v.y);
        let pelvis = p.transl + r(0);
        let spine1 = pelvis + rz(r(3) - r(0));
        let spine2 = spine1 + rz(rx(r(6) - r(3)));
        assert!((posed.joint(0) - pelvis).length() < 1e-14);
        assert!((posed.joint(joint::SPINE1) - spine1).length() < 1e-14);
        assert!(
            (posed.joint(joint::SPINE2) - spine2).length() < 1e-14,
            "{:?} vs {spine2:?}",
            posed.joint(6)
        );
    }

    #[test]
    fn canonical_from_posed_maps_attached_points_back() {
        let s = chain_skeleton();
        let canonical = s.pose(&canonical_params());
        let mut p = FrameParams {
            global_orient: DVec3::new(0.2, -0.4, 0.1),
            transl: DVec3::new(0.1, 0.0, 2.0),
            ..Default::default()
        };
        p.body_pose[joint::LEFT_ELBOW - 1] = DVec3::new(0.0, 1.2, 0.0);
        p.left_hand_pose[4] = DVec3::new(0.0, 0.0, -1.4); // a finger bent past 80 degrees
        let posed = s.pose(&p);
        let maps = canonical_from_posed(&posed, &canonical);
        for j in 0..N_JOINTS {
            // A point rigidly attached to joint j at a fixed offset in the joint's frame.
            let offset = DVec3::new(0.02, -0.03, 0.05);
            let p_posed = posed.world_from_joint[j].transform_point3(offset);
            let p_canonical = canonical.world_from_joint[j].transform_point3(offset);
            assert!((maps[j].transform_point3(p_posed) - p_canonical).length() < 1e-12);
        }
    }
}
