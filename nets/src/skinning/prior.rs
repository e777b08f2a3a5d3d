//! The skinning priors' geometry and logits: canonical bone segments (HumanNeRF's
//! bone-distance initialisation) and posed solid cores (the posed-space prior), and the
//! distances both are made of.

use talkin_geometry::segment_distance2;

use super::{N_BODY_JOINTS, channels, skinned_joint};

/// A segment of bone `bone` in canonical space (a bone may have several, e.g. the pelvis
/// to both hips; a leaf bone may give a point, `a == b`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoneSegment {
    /// SMPL-X joint index (< 55); the volume reads it as its skinned joint.
    pub bone: usize,
    /// Segment start (metres, canonical).
    pub a: [f32; 3],
    /// Segment end.
    pub b: [f32; 3],
}

/// A made-up prior for tests and benches, not a body: one horizontal segment per body
/// bone, 9 cm apart upwards from 1 m below the origin, inside the unit box.
#[doc(hidden)]
pub fn ladder_prior() -> Vec<BoneSegment> {
    (0..N_BODY_JOINTS)
        .map(|b| {
            let y = -1.0 + b as f32 * 0.09;
            BoneSegment {
                bone: b,
                a: [-0.3, y, 0.0],
                b: [0.3, y + 0.05, 0.0],
            }
        })
        .collect()
}

/// A solid core of bone `bone` in the posed (observation) frame: the posed-space prior's
/// geometry (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoneCapsule {
    /// SMPL-X joint index (< 55); the volume reads it as its skinned joint.
    pub bone: usize,
    /// Segment start (metres, posed).
    pub a: [f32; 3],
    /// Segment end.
    pub b: [f32; 3],
    /// Radius (metres; 0 for a bare segment).
    pub radius: f32,
}

/// Logit of a bone with no capsule in the posed-space prior.
pub(super) const NO_CAPSULE_LOGIT: f32 = -1e4;

/// HumanNeRF's initialisation: per skinned joint, `-d^2 / (2 sigma^2)` at every vertex,
/// `d` the distance to the joint's nearest canonical segment; joints without one get -1e4.
pub(super) fn canonical_prior_logits(
    r: usize,
    aabb_min: [f32; 3],
    aabb_max: [f32; 3],
    prior: &[BoneSegment],
    sigma: f64,
    finger_bones: bool,
) -> Vec<f32> {
    let inv = 1.0 / (2.0 * sigma * sigma);
    let mut logits = vec![-1e4f32; channels(finger_bones) * r * r * r];
    for z in 0..r {
        for y in 0..r {
            for x in 0..r {
                let p: [f64; 3] = std::array::from_fn(|a| {
                    let t = [x, y, z][a] as f64 / (r - 1) as f64;
                    aabb_min[a] as f64 + t * (aabb_max[a] as f64 - aabb_min[a] as f64)
                });
                for s in prior {
                    let d2 = segment_distance2(p, s.a.map(f64::from), s.b.map(f64::from));
                    let j = skinned_joint(s.bone, finger_bones);
                    let slot = &mut logits[((j * r + z) * r + y) * r + x];
                    *slot = slot.max((-d2 * inv) as f32);
                }
            }
        }
    }
    logits
}

/// Signed distance from `p` to capsule `c` (negative inside), in f64 for the products.
/// Inlined: the posed prior calls it about three times a pair, and out of line (as the
/// compiler left it in the pairs' parallel layout) it doubled the pairs' time.
#[inline(always)]
pub(super) fn capsule_distance(p: [f32; 3], c: &BoneCapsule) -> f32 {
    let p = p.map(|v| v as f64);
    (segment_distance2(p, c.a.map(f64::from), c.b.map(f64::from)).sqrt() - c.radius as f64) as f32
}
