//! Per-frame SMPL-X parameters, named and shaped as SMPLer-X exports them.

use glam::DVec3;

use super::skeleton::{N_BODY_JOINTS, N_HAND_JOINTS, N_JOINTS, joint};

/// Number of expression coefficients the engine conditions on (the paper's psi).
pub const N_EXPRESSION: usize = 10;

/// One frame's pose, expression and translation. Rotations are axis-angle, local to the
/// parent joint (SMPL-X convention; zero is the T-pose).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameParams {
    pub global_orient: DVec3,
    /// Joints 1..22 (left_hip .. right_wrist).
    pub body_pose: [DVec3; N_BODY_JOINTS - 1],
    pub jaw_pose: DVec3,
    pub leye_pose: DVec3,
    pub reye_pose: DVec3,
    pub left_hand_pose: [DVec3; N_HAND_JOINTS],
    pub right_hand_pose: [DVec3; N_HAND_JOINTS],
    pub expression: [f64; N_EXPRESSION],
    /// Root translation in metres, world space.
    pub transl: DVec3,
}

impl Default for FrameParams {
    /// The T-pose at the origin with a neutral face.
    fn default() -> Self {
        Self {
            global_orient: DVec3::ZERO,
            body_pose: [DVec3::ZERO; N_BODY_JOINTS - 1],
            jaw_pose: DVec3::ZERO,
            leye_pose: DVec3::ZERO,
            reye_pose: DVec3::ZERO,
            left_hand_pose: [DVec3::ZERO; N_HAND_JOINTS],
            right_hand_pose: [DVec3::ZERO; N_HAND_JOINTS],
            expression: [0.0; N_EXPRESSION],
            transl: DVec3::ZERO,
        }
    }
}

impl FrameParams {
    /// Local axis-angle rotation of every joint, in SMPL-X joint order.
    pub fn local_rotations(&self) -> [DVec3; N_JOINTS] {
        let mut r = [DVec3::ZERO; N_JOINTS];
        r[0] = self.global_orient;
        r[1..N_BODY_JOINTS].copy_from_slice(&self.body_pose);
        r[joint::JAW] = self.jaw_pose;
        r[joint::LEFT_EYE] = self.leye_pose;
        r[joint::RIGHT_EYE] = self.reye_pose;
        r[joint::LEFT_HAND_FIRST..joint::RIGHT_HAND_FIRST].copy_from_slice(&self.left_hand_pose);
        r[joint::RIGHT_HAND_FIRST..N_JOINTS].copy_from_slice(&self.right_hand_pose);
        r
    }

    /// Sets every joint's local rotation from SMPL-X joint order (inverse of
    /// [`Self::local_rotations`]).
    pub fn set_local_rotations(&mut self, r: &[DVec3; N_JOINTS]) {
        self.global_orient = r[0];
        self.body_pose.copy_from_slice(&r[1..N_BODY_JOINTS]);
        self.jaw_pose = r[joint::JAW];
        self.leye_pose = r[joint::LEFT_EYE];
        self.reye_pose = r[joint::RIGHT_EYE];
        self.left_hand_pose
            .copy_from_slice(&r[joint::LEFT_HAND_FIRST..joint::RIGHT_HAND_FIRST]);
        self.right_hand_pose
            .copy_from_slice(&r[joint::RIGHT_HAND_FIRST..N_JOINTS]);
    }

    /// The paper's facial condition e = [psi; jaw] (13 numbers).
    pub fn face_condition(&self) -> [f32; N_EXPRESSION + 3] {
        let mut e = [0.0f32; N_EXPRESSION + 3];
        for (dst, src) in e.iter_mut().zip(self.expression) {
            *dst = src as f32;
        }
        e[N_EXPRESSION..].copy_from_slice(&self.jaw_pose.as_vec3().to_array());
        e
    }

    /// The paper's hand condition: left then right hand pose, flattened (90 numbers).
    pub fn hand_condition(&self) -> [f32; 2 * N_HAND_JOINTS * 3] {
        let mut h = [0.0f32; 2 * N_HAND_JOINTS * 3];
        for (i, r) in self
            .left_hand_pose
            .iter()
            .chain(&self.right_hand_pose)
            .enumerate()
        {
            h[3 * i..3 * i + 3].copy_from_slice(&r.as_vec3().to_array());
        }
        h
    }

    /// Body pose (joints 1..22) flattened, the condition of D_nr (63 numbers).
    pub fn body_condition(&self) -> [f32; (N_BODY_JOINTS - 1) * 3] {
        let mut p = [0.0f32; (N_BODY_JOINTS - 1) * 3];
        for (i, r) in self.body_pose.iter().enumerate() {
            p[3 * i..3 * i + 3].copy_from_slice(&r.as_vec3().to_array());
        }
        p
    }

    /// True if every number is finite.
    pub fn is_finite(&self) -> bool {
        self.local_rotations().iter().all(|r| r.is_finite())
            && self.transl.is_finite()
            && self.expression.iter().all(|x| x.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_rotations_order_and_round_trip() {
        let mut p = FrameParams::default();
        p.body_pose[3] = DVec3::new(0.1, -0.2, 0.3);
        p.right_hand_pose[14] = DVec3::new(0.5, 0.0, -0.25);
        p.expression[9] = -1.5;
        p.transl = DVec3::new(0.0, 1.0, 2.0);
        let r = p.local_rotations();
        assert_eq!(r[4], p.body_pose[3]);
        assert_eq!(r[54], p.right_hand_pose[14]);
        let mut q = FrameParams::default();
        q.set_local_rotations(&r);
        q.expression = p.expression;
        q.transl = p.transl;
        assert_eq!(q, p);
    }
}
