//! The conditions of one frame the field is evaluated for: who, how each bone is posed,
//! the face's expression and the hands' pose.

use super::{EXPRESSION_DIM, HAND_POSE_DIM, JAW_DIM};
use crate::skinning::{BoneCapsule, N_SMPLX_JOINTS};

/// Per-frame conditions (one frame per forward call).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameConditions {
    /// Subject index (< `n_identities`).
    pub identity: usize,
    /// `[55]` row-major 4x4 `canonical_from_posed`, one per SMPL-X joint ([`crate::skinning`]).
    pub canonical_from_posed: Vec<[f32; 16]>,
    /// `[pose_dim]` body pose for D_nr (21 x 3 axis-angle).
    pub body_pose: Vec<f32>,
    /// psi.
    pub expression: [f32; EXPRESSION_DIM],
    /// Jaw axis-angle.
    pub jaw: [f32; JAW_DIM],
    /// `[90]` both hands' poses.
    pub hand_pose: Vec<f32>,
    /// The posed solid cores of the bones, each labelled with its SMPL-X joint, for the
    /// skinning's posed-space prior (see [`crate::skinning`]); unused without it.
    pub bone_capsules: Vec<BoneCapsule>,
    /// The training frame's latent code (a row of [`crate::TalkinField::frame_codes`]);
    /// `None`, every frame the run did not train on: the mean of the codes.
    pub frame_code: Option<usize>,
}

impl FrameConditions {
    /// A made-up frame for tests and benches: subject 0, every bone at rest (identity
    /// transforms), a slight body pose, expression and jaw, flat hands, no cores.
    #[doc(hidden)]
    pub fn still() -> FrameConditions {
        let mut t = [0.0f32; 16];
        for i in 0..4 {
            t[i * 5] = 1.0;
        }
        FrameConditions {
            identity: 0,
            canonical_from_posed: vec![t; N_SMPLX_JOINTS],
            body_pose: vec![0.05; 63],
            expression: [0.1; EXPRESSION_DIM],
            jaw: [0.2, 0.0, 0.0],
            hand_pose: vec![0.0; HAND_POSE_DIM],
            bone_capsules: vec![],
            frame_code: None,
        }
    }
}
