//! The field's per-frame conditions from a frame's parameters and posed scene.

use talkin_grids::{Capsule, PackedSamples, Part};
use talkin_nets::FrameConditions;
use talkin_nets::field::{EXPRESSION_DIM, JAW_DIM};
use talkin_nets::skinning::BoneCapsule;
use talkin_nets::volume::OwnedRaySamples;

use crate::scene::{CapsuleShells, FrameScene};
use talkin_human::body::FrameParams;

/// Identity `subject`, the 55 row-major `canonical_from_posed` matrices, the body pose
/// (D_nr), `e = [psi; jaw]`, both hands' poses and the posed solid cores of the bones
/// (`shells` fitted to the subject) for a field that skins the finger joints
/// (`finger_bones`) or not.
pub fn frame_conditions(
    subject: usize,
    params: &FrameParams,
    scene: &FrameScene,
    shells: &CapsuleShells,
    finger_bones: bool,
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
        bone_capsules: skinning_cores(&scene.capsules, shells, finger_bones),
        frame_code: None,
    }
}

/// The skinning prior's capsules, each labelled with its SMPL-X joint: the posed solid
/// cores. Where the field skins the fingers (`finger_bones`), the hand's capsules enter as
/// their bare axes (cores of radius 0) instead: fitted finger cores are a millimetre or
/// two (a 9 mm capsule, 0.85 x the closest surface - 5 mm) and a fingertip's is none (the
/// surface ends inside its capsule), so beside the palm's thicker core a fingertip
/// touching the palm could go with the palm. Axes compare like with like: the nearest
/// bone of the hand wins. Measured on `tests/hands.rs`' poses, against fitted cores with
/// an axis only where a core is missing: a fist's tips 0.5 against 0.8 mm from their true
/// canonical points on average, two touching hands' 7 against 28 mm at worst.
fn skinning_cores(
    bare: &[Capsule],
    shells: &CapsuleShells,
    finger_bones: bool,
) -> Vec<BoneCapsule> {
    let core = |c: &Capsule| BoneCapsule {
        bone: c.bone as usize,
        a: c.a.to_array(),
        b: c.b.to_array(),
        radius: c.radius,
    };
    let is_hand = |c: &Capsule| finger_bones && c.part == Part::Hands;
    let cores = shells.cores(bare);
    let axes = bare
        .iter()
        .filter(|c| is_hand(c))
        .map(|c| Capsule { radius: 0.0, ..*c });
    cores
        .iter()
        .filter(|c| !is_hand(c))
        .copied()
        .chain(axes)
        .map(|c| core(&c))
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
