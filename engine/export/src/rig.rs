//! The rig: the subject's 55 SMPL-X joints (body, jaw and eyes, fingers) as a node
//! hierarchy, bound in the canonical pose the mesh is made in. A joint's node holds its
//! local rotation and its offset from its parent, so a pose is a set of node rotations
//! (and the root's translation), exactly [`Skeleton::pose`]'s forward kinematics; the
//! inverse bind matrices are the canonical joints' frames inverted, so a joint's skinning
//! matrix `world_from_joint(pose) * inverse_bind` is the engine's `posed_from_canonical`.

use glam::{Affine3A, DAffine3, DQuat, Mat4, Quat, Vec3};
use talkin_human::body::rotation::rotation_from_axis_angle;
use talkin_human::body::{
    FrameParams, JOINT_NAMES, N_JOINTS, PARENTS, Skeleton, canonical_from_posed, canonical_params,
};

use crate::weights::SkinWeights;

/// A joint's node transform: rotation, then translation from its parent's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodePose {
    pub translation: Vec3,
    pub rotation: Quat,
}

/// A subject's skeleton ready to bind.
#[derive(Clone, Debug)]
pub struct Rig {
    pub skeleton: Skeleton,
    /// Per joint, the canonical pose's node transform (the bind pose).
    pub bind: [NodePose; N_JOINTS],
    /// Per joint, column-major `joint_from_world` of the canonical pose.
    pub inverse_bind: [Mat4; N_JOINTS],
}

impl Rig {
    pub fn new(skeleton: &Skeleton) -> Rig {
        let canonical = skeleton.pose(&canonical_params());
        Rig {
            skeleton: skeleton.clone(),
            bind: node_poses(skeleton, &canonical_params()),
            inverse_bind: std::array::from_fn(|j| mat4(&canonical.world_from_joint[j].inverse())),
        }
    }

    /// The parent of joint `j` (`None` for the pelvis).
    pub fn parent(j: usize) -> Option<usize> {
        usize::try_from(PARENTS[j]).ok()
    }

    /// The name of joint `j` (SMPL-X's).
    pub fn name(j: usize) -> &'static str {
        JOINT_NAMES[j]
    }
}

/// Every joint's node transform in pose `params`: the local rotation of `params`, the
/// offset from the parent in the rest skeleton, the root at `transl + J_0`.
pub fn node_poses(skeleton: &Skeleton, params: &FrameParams) -> [NodePose; N_JOINTS] {
    let local = params.local_rotations();
    std::array::from_fn(|j| {
        let translation = match Rig::parent(j) {
            None => params.transl + skeleton.rest_joints[0],
            Some(p) => skeleton.rest_joints[j] - skeleton.rest_joints[p],
        };
        NodePose {
            translation: translation.as_vec3(),
            rotation: DQuat::from_mat3(&rotation_from_axis_angle(local[j]))
                .normalize()
                .as_quat(),
        }
    })
}

/// Column-major f32 4x4 of `a`.
fn mat4(a: &DAffine3) -> Mat4 {
    Mat4::from(Affine3A::from_mat3_translation(
        a.matrix3.as_mat3(),
        a.translation.as_vec3(),
    ))
}

/// Canonical `positions` posed by linear blend skinning with `skin`, through the engine's
/// own per-joint maps (`posed_from_canonical = canonical_from_posed^-1` of the pose).
pub fn pose_vertices(
    skeleton: &Skeleton,
    params: &FrameParams,
    positions: &[Vec3],
    skin: &SkinWeights,
) -> Vec<Vec3> {
    let canonical = skeleton.pose(&canonical_params());
    let posed = skeleton.pose(params);
    let maps = canonical_from_posed(&posed, &canonical).map(|m| mat4(&m.inverse()));
    positions
        .iter()
        .zip(skin.joints.iter().zip(&skin.weights))
        .map(|(p, (joints, weights))| {
            joints
                .iter()
                .zip(weights)
                .map(|(&j, &w)| w * maps[j as usize].transform_point3(*p))
                .sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn skeleton() -> Skeleton {
        let mut rest = [DVec3::ZERO; N_JOINTS];
        for j in 1..N_JOINTS {
            let p = PARENTS[j] as usize;
            rest[j] = rest[p] + DVec3::new(0.01 * j as f64, 0.1, 0.02 * (j % 3) as f64);
        }
        Skeleton { rest_joints: rest }
    }

    fn posed_params() -> FrameParams {
        let mut p = canonical_params();
        p.global_orient = DVec3::new(0.1, 0.4, -0.2);
        p.transl = DVec3::new(0.3, -0.1, 0.2);
        for (k, r) in p.body_pose.iter_mut().enumerate() {
            *r += DVec3::new(0.05 * k as f64, -0.03, 0.02 * (k % 4) as f64);
        }
        p.left_hand_pose[3] = DVec3::new(0.0, 0.0, 0.8);
        p.jaw_pose = DVec3::new(0.3, 0.0, 0.0);
        p
    }

    /// The glTF chain (parent node matrices times each node's TRS) times the inverse
    /// bind matrix is the engine's posed_from_canonical, for every joint.
    #[test]
    fn node_chain_times_inverse_bind_is_the_engines_skinning() {
        let s = skeleton();
        let rig = Rig::new(&s);
        let params = posed_params();
        let nodes = node_poses(&s, &params);
        let mut world = [Mat4::IDENTITY; N_JOINTS];
        for j in 0..N_JOINTS {
            let local = Mat4::from_rotation_translation(nodes[j].rotation, nodes[j].translation);
            world[j] = match Rig::parent(j) {
                None => local,
                Some(p) => world[p] * local,
            };
        }
        let canonical = s.pose(&canonical_params());
        let posed = s.pose(&params);
        let maps = canonical_from_posed(&posed, &canonical);
        for j in 0..N_JOINTS {
            let want = mat4(&maps[j].inverse());
            let got = world[j] * rig.inverse_bind[j];
            assert!(
                got.abs_diff_eq(want, 1e-5),
                "joint {j}: {got} against {want}"
            );
        }
        // The bind pose is the canonical pose: its skinning matrices are the identity.
        let bind = node_poses(&s, &canonical_params());
        assert_eq!(bind, rig.bind);
    }

    #[test]
    fn a_vertex_on_one_joint_moves_with_it() {
        let s = skeleton();
        let params = posed_params();
        let skin = SkinWeights {
            joints: vec![[18, 0, 1, 2], [18, 19, 0, 1]],
            weights: vec![[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.0, 0.0]],
        };
        let p = Vec3::new(0.2, 1.0, 0.1);
        let posed = pose_vertices(&s, &params, &[p, p], &skin);
        let maps = canonical_from_posed(&s.pose(&params), &s.pose(&canonical_params()));
        let by = |j: usize| maps[j].inverse().transform_point3(p.as_dvec3()).as_vec3();
        assert!(posed[0].abs_diff_eq(by(18), 1e-5));
        assert!(posed[1].abs_diff_eq(0.5 * (by(18) + by(19)), 1e-5));
    }
}
