//! The field's per-frame conditions from a frame's parameters and posed scene.

use talkin_grids::{Capsule, PackedSamples};
use talkin_nets::FrameConditions;
use talkin_nets::field::{EXPRESSION_DIM, JAW_DIM};
use talkin_nets::render::OwnedRaySamples;
use talkin_nets::skinning::BoneCapsule;

use crate::scene::{CapsuleShells, FrameScene};
use talkin_human::body::FrameParams;
use talkin_human::body::skeleton::body_ancestor;

/// Identity `subject`, the 22 row-major `canonical_from_posed` matrices, the body pose
/// (D_nr), `e = [psi; jaw]`, both hands' poses and the posed solid cores of the body
/// bones (`shells` fitted to the subject).
pub fn frame_conditions(
    subject: usize,
    params: &FrameParams,
    scene: &FrameScene,
    shells: &CapsuleShells,
) -> FrameConditions {
    let canonical_from_posed = scene
        .canonical_from_posed
        .iter()
        .map(|a| {
            let m = a.matrix3;
            let t = a.translation;
            [
                m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
                m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
                m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z, //
                0.0, 0.0, 0.0, 1.0,
            ]
        })
        .collect();
    let face = params.face_condition();
    let mut expression = [0.0f32; EXPRESSION_DIM];
    expression.copy_from_slice(&face[..EXPRESSION_DIM]);
    let mut jaw = [0.0f32; JAW_DIM];
    jaw.copy_from_slice(&face[EXPRESSION_DIM..]);
    FrameConditions {
        identity: subject,
        canonical_from_posed,
        body_pose: params.body_condition().to_vec(),
        expression,
        jaw,
        hand_pose: params.hand_condition().to_vec(),
        bone_capsules: skinning_cores(&scene.capsules, shells),
    }
}

/// The skinning prior's capsules: the posed solid cores (fingertips, which the data leaves
/// without one, drop out: their bone, the wrist, has the other finger segments' cores), each
/// labelled with the body joint that drives it.
fn skinning_cores(bare: &[Capsule], shells: &CapsuleShells) -> Vec<BoneCapsule> {
    shells
        .cores(bare)
        .iter()
        .map(|c| BoneCapsule {
            bone: body_ancestor(c.bone as usize),
            a: c.a.to_array(),
            b: c.b.to_array(),
            radius: c.radius,
        })
        .collect()
}

/// The nets' packed layout of grids' samples.
pub fn packed_layout(s: &PackedSamples) -> OwnedRaySamples {
    OwnedRaySamples {
        offsets: s.ray_offsets.iter().map(|&o| o as usize).collect(),
        t_start: s.t_start.clone(),
        t_end: s.t_end.clone(),
    }
}
