//! Camera framing: one frontal camera per identity, framed from mid-thigh up (or, for the
//! capture-like scene, the whole body; or head and shoulders) and widened until the head
//! with its hair and both hands (and then the feet; head and shoulders: the head alone)
//! stay inside every frame.

use glam::DVec3;

use talkin_human::body::skeleton::joint;
use talkin_human::body::{PosedSkeleton, Skeleton};
use talkin_human::camera::{Camera, CameraError};

/// What a camera frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Framing {
    /// From mid-thigh up, both hands kept inside (the talking scene's).
    #[default]
    Waist,
    /// The whole body, feet included (the capture-like scene's).
    FullBody,
    /// Head and shoulders: from the chest up, the head kept inside; hands show only when
    /// raised above the chest.
    Chest,
    /// The head and the top of the shoulders: from the collarbones up.
    Head,
}

/// Points that must stay inside the image: the head with its hair, the hands.
fn keypoints(head_scale: f64, posed: &PosedSkeleton, framing: Framing) -> Vec<DVec3> {
    let full_body = framing == Framing::FullBody;
    let mut pts = Vec::new();
    let head = &posed.world_from_joint[joint::HEAD];
    for off in [
        DVec3::new(0.0, 0.23, 0.0),
        DVec3::new(0.1, 0.1, 0.0),
        DVec3::new(-0.1, 0.1, 0.0),
        DVec3::new(0.0, 0.17, -0.16),
        DVec3::new(0.0, -0.04, -0.19),
        DVec3::new(0.0, 0.0, 0.12),
    ] {
        pts.push(head.transform_point3(off * head_scale));
    }
    let feet: &[usize] = if full_body {
        &[
            joint::LEFT_ANKLE,
            joint::RIGHT_ANKLE,
            joint::LEFT_FOOT,
            joint::RIGHT_FOOT,
        ]
    } else {
        &[]
    };
    if matches!(framing, Framing::Chest | Framing::Head) {
        return pts;
    }
    for j in [joint::LEFT_WRIST, joint::RIGHT_WRIST]
        .into_iter()
        .chain(feet.iter().copied())
        .chain(joint::LEFT_HAND_FIRST..talkin_human::body::N_JOINTS)
    {
        pts.push(posed.joint(j));
    }
    // Finger tips: one more segment past the last joint.
    for first in [joint::LEFT_HAND_FIRST, joint::RIGHT_HAND_FIRST] {
        for f in 0..5 {
            let (a, b) = (
                posed.joint(first + 3 * f + 1),
                posed.joint(first + 3 * f + 2),
            );
            pts.push(b + (b - a) * 1.1);
        }
    }
    pts
}

/// A frontal camera for one identity, framed as `framing` says and widened so every
/// keypoint of every frame lies at least `margin` pixels inside.
pub(crate) fn frame_camera(
    skeleton: &Skeleton,
    head_scale: f64,
    (width, height): (u32, u32),
    posed: &[PosedSkeleton],
    aim: DVec3,
    framing: Framing,
) -> Result<Camera, CameraError> {
    let r = &skeleton.rest_joints;
    let bottom = match framing {
        Framing::FullBody => r[joint::LEFT_ANKLE].y - 0.1,
        Framing::Waist => (r[joint::LEFT_HIP].y + r[joint::LEFT_KNEE].y) * 0.5,
        Framing::Chest => r[joint::SPINE3].y - 0.05,
        Framing::Head => r[joint::NECK].y - 0.08,
    };
    let top = r[joint::HEAD].y + 0.24 * head_scale;
    let centre = DVec3::new(0.0, (top + bottom) * 0.5, 0.0) + aim;
    let distance = 3.2;
    let eye = centre + DVec3::new(0.0, 0.05, distance);
    let f0 = height as f64 * distance / (top - bottom);
    let probe = Camera::look_at(width, height, f0, eye, centre, DVec3::Y)?;
    let margin = 2.0 + height as f64 * 0.02;
    let (half_w, half_h) = (width as f64 / 2.0 - margin, height as f64 / 2.0 - margin);
    let mut focal = f0;
    for p in posed {
        for k in keypoints(head_scale, p, framing) {
            let c = probe.camera_from_world.transform_point3(k);
            if c.z > 0.1 {
                focal = focal
                    .min(half_w * c.z / c.x.abs().max(1e-9))
                    .min(half_h * c.z / c.y.abs().max(1e-9));
            }
        }
    }
    Camera::look_at(width, height, focal, eye, centre, DVec3::Y)
}
