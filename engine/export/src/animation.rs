//! A motion as keyframes on the rig's nodes: per frame, every joint's local rotation and
//! the root's translation ([`crate::rig::node_poses`]), at the motion's rate. Rotations
//! are kept on one hemisphere frame to frame, so a player's linear interpolation (a
//! normalised lerp or slerp) takes the short way between keys.

use glam::{Quat, Vec3};
use talkin_human::body::{FrameParams, N_JOINTS, Skeleton};

use crate::rig::node_poses;

/// Frames per second of a motion that does not say.
pub const DEFAULT_FPS: f64 = 30.0;

/// Keyframes of a motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframes {
    /// Seconds, from 0. `[frames]`
    pub times: Vec<f32>,
    /// Per joint, its rotation at every key. `[joints][frames]`
    pub rotations: Vec<Vec<Quat>>,
    /// The root's translation at every key. `[frames]`
    pub root_translation: Vec<Vec3>,
}

/// The keyframes of `frames` played at `fps` on `skeleton`'s rig.
pub fn keyframes(skeleton: &Skeleton, frames: &[FrameParams], fps: f64) -> Keyframes {
    let mut rotations: Vec<Vec<Quat>> = (0..N_JOINTS)
        .map(|_| Vec::with_capacity(frames.len()))
        .collect();
    let mut root_translation = Vec::with_capacity(frames.len());
    for params in frames {
        let nodes = node_poses(skeleton, params);
        for (j, node) in nodes.iter().enumerate() {
            let mut q = node.rotation;
            if let Some(prev) = rotations[j].last()
                && prev.dot(q) < 0.0
            {
                q = -q;
            }
            rotations[j].push(q);
        }
        root_translation.push(nodes[0].translation);
    }
    Keyframes {
        times: (0..frames.len()).map(|i| (i as f64 / fps) as f32).collect(),
        rotations,
        root_translation,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use talkin_human::body::canonical_params;

    #[test]
    fn keys_follow_the_frames_on_one_hemisphere() {
        let skeleton = Skeleton {
            rest_joints: std::array::from_fn(|j| DVec3::new(0.0, j as f64 * 0.01, 0.0)),
        };
        // The elbow turning past half a turn: its quaternion's sign would flip.
        let frames: Vec<FrameParams> = (0..5)
            .map(|i| {
                let mut p = canonical_params();
                p.body_pose[17] = DVec3::new(0.0, 0.0, 2.6 + 0.2 * i as f64);
                p.transl = DVec3::new(0.1 * i as f64, 0.0, 0.0);
                p
            })
            .collect();
        let k = keyframes(&skeleton, &frames, 25.0);
        assert_eq!(k.times, vec![0.0, 0.04, 0.08, 0.12, 0.16]);
        for w in k.rotations[18].windows(2) {
            assert!(w[0].dot(w[1]) > 0.9);
        }
        for (i, t) in k.root_translation.iter().enumerate() {
            assert!((t.x - 0.1 * i as f32).abs() < 1e-6);
        }
        // Each key still turns the elbow by its frame's angle.
        let angle = k.rotations[18][4].angle_between(Quat::IDENTITY);
        assert!((angle - (2.0 * std::f32::consts::PI - 3.4)).abs() < 1e-4);
    }
}
