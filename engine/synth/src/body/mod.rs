//! The mannequin: per-identity proportions (rest joints), looks (skin, hair, clothing
//! patterns) and the primitives of one posed, expressive frame.
//!
//! Every primitive is authored in the T-pose ("rest") space of the joint that carries it
//! and moves rigidly with that joint, so textures evaluated at rest-space coordinates are
//! glued to the limb. Rest space is the SMPL-X convention: metres, y up, the subject faces
//! +z, +x is the subject's left.
//!
//! The figure is data: tables of shapes (`tables`, `head`) evaluated by a small
//! interpreter (`shapes`), plus small functions for the parts that follow the expression
//! coefficients and the jaw (`head`) or the look (garment, sleeves, hair). This module
//! owns the figure's types and the order in which its parts are added.

mod head;
mod head_frame;
mod looks;
mod material;
mod measures;
mod shapes;
mod tables;

use glam::Vec3;

use crate::sdf::Shape;
use talkin_human::body::{FrameParams, PosedSkeleton, Skeleton};

pub use looks::{Garment, HairStyle, Look, Pattern, Sleeve, look};
pub use material::{Material, albedo, eye_colour};
pub use measures::{Proportions, default_rest_joints, proportions, rest_joints};

/// Segmentation labels of the dataset format.
pub mod label {
    pub const BODY: u8 = 1;
    pub const ARMS: u8 = 2;
    pub const HANDS: u8 = 3;
    pub const HEAD: u8 = 4;
}

/// One primitive: a shape carried by a joint, its blend radius, material and label.
#[derive(Clone, Copy, Debug)]
pub struct Prim {
    pub joint: usize,
    pub shape: Shape,
    /// Smooth-union radius with what came before (0 = hard union).
    pub blend: f32,
    pub material: Material,
    pub label: u8,
}

/// Face state derived from the expression coefficients and the jaw (see the module docs
/// of `synth` for the mapping).
#[derive(Clone, Copy, Debug, Default)]
pub struct FaceState {
    /// Mouth opening height at the lips (m, unscaled by the head factor).
    pub mouth_open: f32,
    pub mouth_half_width: f32,
    pub mouth_y: f32,
    pub mouth_z: f32,
}

/// Everything the renderer needs about one frame's mannequin.
pub struct Figure {
    pub prims: Vec<Prim>,
    pub face: FaceState,
    pub look: Look,
    /// Head joint's rest position and scale (for the painted mouth).
    pub head_joint: Vec3,
    pub head_scale: f32,
}

impl Figure {
    /// The joint carrying the primitive nearest to `p_world` in the frame posed as
    /// `posed`: for a surface point, the joint it is rigidly attached to (where primitives
    /// blend, the nearer one). Ground truth for the skinning's canonical map.
    pub fn owning_joint(&self, posed: &PosedSkeleton, p_world: Vec3) -> usize {
        let p = p_world.as_dvec3();
        let mut best = (f32::INFINITY, 0);
        for prim in &self.prims {
            let p_rest = posed.world_from_rest[prim.joint]
                .inverse()
                .transform_point3(p);
            let d = prim.shape.distance(p_rest.as_vec3());
            if d < best.0 {
                best = (d, prim.joint);
            }
        }
        best.1
    }
}

/// Builds the primitives of identity `look`/`prop` for one frame's expression and jaw.
///
/// The order is part of the output: the renderer smooth-unions primitives in order.
pub fn figure(
    skeleton: &Skeleton,
    prop: &Proportions,
    look: &Look,
    params: &FrameParams,
) -> Figure {
    let mut b = shapes::Builder::new(skeleton, prop);
    b.add_all(&tables::TORSO, 0);
    for side in 0..2 {
        b.add_all(&tables::COLLAR_AND_LEG, side);
    }
    b.add(&tables::NECK_ROW, 0);
    b.add(tables::garment(look.garment), 0);
    for side in 0..2 {
        tables::arm(&mut b, look.sleeve, side);
    }
    let e = params.expression.map(|x| x.clamp(-3.0, 3.0) as f32);
    head::face(&mut b, &e);
    head::eyes(&mut b, &e);
    let face = head::mouth(&mut b, &e, params.jaw_pose.x);
    head::hair(&mut b, look.hair_style);
    Figure {
        prims: b.prims,
        face,
        look: *look,
        head_joint: b.head.joint,
        head_scale: b.head.k,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hair_and_clothes_stick_out_of_the_capsules() {
        for identity in 0..3 {
            let skeleton = default_rest_joints(identity);
            let fig = figure(
                &skeleton,
                &proportions(identity),
                &look(identity),
                &FrameParams::default(),
            );
            let caps = talkin_human::body::limb_capsules(
                &skeleton,
                &skeleton.pose(&FrameParams::default()),
            );
            // The farthest point inside the picked primitives from every capsule.
            let outside = |pick: &dyn Fn(&Prim) -> bool| {
                let mut farthest = 0.0f32;
                for p in fig.prims.iter().filter(|p| pick(p)) {
                    let (c, r) = p.shape.bounding_sphere();
                    for k in 0..12 * 12 * 12 {
                        let g = Vec3::new((k % 12) as f32, (k / 12 % 12) as f32, (k / 144) as f32);
                        let q = c + (g / 11.0 * 2.0 - 1.0) * r;
                        if p.shape.distance(q) > 0.0 {
                            continue;
                        }
                        let d = caps
                            .iter()
                            .map(|cap| {
                                let ab = cap.b - cap.a;
                                let t = ((q - cap.a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
                                (q - (cap.a + ab * t)).length() - cap.radius
                            })
                            .fold(f32::MAX, f32::min);
                        farthest = farthest.max(d);
                    }
                }
                farthest
            };
            let hair = outside(&|p| p.material == Material::Hair);
            // Skirts, hems, cuffs and loose sleeves are the capped cones.
            let loose = outside(&|p| matches!(p.shape, Shape::CappedCone { .. }));
            assert!(
                hair > 0.03 && loose > 0.03,
                "identity {identity}: hair {hair} m, clothing {loose} m outside"
            );
        }
    }

    /// FNV-1a over the debug text of the figures of five identities in a talking clip (f32
    /// debug text is the shortest round-trip form: equal text, equal bits).
    fn figures_digest() -> u64 {
        let clip = crate::talk::talking_clip(
            11,
            12,
            crate::Style {
                tempo: 1.0,
                wide: true,
            },
        );
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for identity in 0..5 {
            let skeleton = default_rest_joints(identity);
            for params in &clip {
                let fig = figure(&skeleton, &proportions(identity), &look(identity), params);
                let text = format!("{:?} {:?} {:?}", fig.prims, fig.face, fig.head_joint);
                for byte in text.bytes() {
                    h = (h ^ byte as u64).wrapping_mul(0x100_0000_01b3);
                }
            }
        }
        h
    }

    #[test]
    fn figures_are_unchanged() {
        // The synthetic datasets are meant to be byte-identical across refactors of the
        // shape tables; a change here changes every image.
        assert_eq!(figures_digest(), 0x896c_1479_2a5c_1e2e);
    }
}
