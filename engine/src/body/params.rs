//! Per-frame SMPL-X parameters, named and shaped as SMPLer-X exports them.

use glam::DVec3;
use serde::Serialize;
use serde_json::Value;

use super::skeleton::{N_BODY_JOINTS, N_HAND_JOINTS, N_JOINTS, joint};
use crate::json_shape::{self, ShapeError};

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

    /// Parses the dataset's `params` object; `path` names it in errors
    /// (e.g. `frames[3].params`). Expression may carry more than 10 coefficients (the
    /// first 10 are kept); everything else must have exactly its shape.
    pub fn from_json(v: &Value, path: &str) -> Result<Self, ShapeError> {
        let field = |k: &str| format!("{path}.{k}");
        let vec3 = |k: &str| -> Result<DVec3, ShapeError> {
            let x = json_shape::vector(json_shape::member(v, path, k)?, &field(k), 3)?;
            Ok(DVec3::new(x[0], x[1], x[2]))
        };
        let rows = |k: &str, n: usize, out: &mut [DVec3]| -> Result<(), ShapeError> {
            let x = json_shape::matrix(json_shape::member(v, path, k)?, &field(k), n, 3)?;
            for (i, r) in out.iter_mut().enumerate() {
                *r = DVec3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
            }
            Ok(())
        };
        let mut p = FrameParams {
            global_orient: vec3("global_orient")?,
            jaw_pose: vec3("jaw_pose")?,
            leye_pose: vec3("leye_pose")?,
            reye_pose: vec3("reye_pose")?,
            transl: vec3("transl")?,
            ..Default::default()
        };
        rows("body_pose", N_BODY_JOINTS - 1, &mut p.body_pose)?;
        rows("left_hand_pose", N_HAND_JOINTS, &mut p.left_hand_pose)?;
        rows("right_hand_pose", N_HAND_JOINTS, &mut p.right_hand_pose)?;
        let e = json_shape::vector_at_least(
            json_shape::member(v, path, "expression")?,
            &field("expression"),
            N_EXPRESSION,
        )?;
        p.expression.copy_from_slice(&e[..N_EXPRESSION]);
        Ok(p)
    }

    /// The dataset's `params` object.
    pub fn to_json(&self) -> Value {
        #[derive(Serialize)]
        struct Wire<'a> {
            global_orient: [f64; 3],
            body_pose: Vec<[f64; 3]>,
            jaw_pose: [f64; 3],
            leye_pose: [f64; 3],
            reye_pose: [f64; 3],
            left_hand_pose: Vec<[f64; 3]>,
            right_hand_pose: Vec<[f64; 3]>,
            expression: &'a [f64],
            transl: [f64; 3],
        }
        let rows = |r: &[DVec3]| r.iter().map(|v| round6(v.to_array())).collect::<Vec<_>>();
        let expression: Vec<f64> = self
            .expression
            .iter()
            .map(|x| round6([*x, 0.0, 0.0])[0])
            .collect();
        serde_json::to_value(Wire {
            global_orient: round6(self.global_orient.to_array()),
            body_pose: rows(&self.body_pose),
            jaw_pose: round6(self.jaw_pose.to_array()),
            leye_pose: round6(self.leye_pose.to_array()),
            reye_pose: round6(self.reye_pose.to_array()),
            left_hand_pose: rows(&self.left_hand_pose),
            right_hand_pose: rows(&self.right_hand_pose),
            expression: &expression,
            transl: round6(self.transl.to_array()),
        })
        .expect("plain numbers always serialise")
    }
}

/// Rounds to 1e-9 so written JSON stays short and byte-stable.
fn round6(v: [f64; 3]) -> [f64; 3] {
    v.map(|x| (x * 1e9).round() / 1e9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip_and_rotation_order() {
        let mut p = FrameParams::default();
        p.body_pose[3] = DVec3::new(0.1, -0.2, 0.3);
        p.right_hand_pose[14] = DVec3::new(0.5, 0.0, -0.25);
        p.expression[9] = -1.5;
        p.transl = DVec3::new(0.0, 1.0, 2.0);
        let back = FrameParams::from_json(&p.to_json(), "params").unwrap();
        assert_eq!(back, p);
        let r = p.local_rotations();
        assert_eq!(r[4], p.body_pose[3]);
        assert_eq!(r[54], p.right_hand_pose[14]);
        let mut q = FrameParams::default();
        q.set_local_rotations(&r);
        q.expression = p.expression;
        q.transl = p.transl;
        assert_eq!(q, p);
    }

    #[test]
    fn wrong_shape_names_the_field() {
        let mut v = FrameParams::default().to_json();
        v["left_hand_pose"] = serde_json::json!([[0, 0, 0]]);
        let e = FrameParams::from_json(&v, "frames[7].params").unwrap_err();
        assert_eq!(e.field, "frames[7].params.left_hand_pose");
        assert!(e.expected.contains("15 x 3"));
    }
}
