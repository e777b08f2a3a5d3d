//! The primitive the BVH is built over: a capsule (segment + radius) labelled with the
//! body part and the skeleton bone that moves it. Engine builds these from a posed
//! skeleton; this crate only intersects them.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Body part of a capsule. The discriminants are the dataset's segmentation labels
/// (0 is background), so `part as u8` is the label a pixel of this part carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum Part {
    Body = 1,
    Arms = 2,
    Hands = 3,
    Head = 4,
}

impl Part {
    /// All parts, in label order.
    pub const ALL: [Part; 4] = [Part::Body, Part::Arms, Part::Hands, Part::Head];

    /// Segmentation label of this part (1..=4).
    pub const fn label(self) -> u8 {
        self as u8
    }

    /// The part of a segmentation label, `None` for background (0) or unknown labels.
    pub const fn from_label(label: u8) -> Option<Part> {
        match label {
            1 => Some(Part::Body),
            2 => Some(Part::Arms),
            3 => Some(Part::Hands),
            4 => Some(Part::Head),
            _ => None,
        }
    }

    /// Bit of this part in a candidate-part mask (`1 << (label - 1)`).
    pub const fn bit(self) -> u8 {
        1 << (self as u8 - 1)
    }

    pub const fn name(self) -> &'static str {
        match self {
            Part::Body => "body",
            Part::Arms => "arms",
            Part::Hands => "hands",
            Part::Head => "head",
        }
    }
}

/// A capsule in posed (world) space: all points within `radius` of segment `a`-`b`.
/// `a == b` is a sphere.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Capsule {
    pub a: Vec3,
    pub b: Vec3,
    pub radius: f32,
    pub part: Part,
    /// SMPL-X joint index (0..55) whose transform moves this capsule.
    pub bone: u16,
}

/// Axis-aligned box around capsules (each grown by its radius) plus `pad` metres: the
/// dense sampler's "joints +/- margin" box, with the margin the data decided; with no
/// capsule, an inverted (infinite) box.
pub fn capsule_bounds(capsules: &[Capsule], pad: f32) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for c in capsules {
        lo = lo.min(c.a.min(c.b) - Vec3::splat(c.radius));
        hi = hi.max(c.a.max(c.b) + Vec3::splat(c.radius));
    }
    (lo - Vec3::splat(pad), hi + Vec3::splat(pad))
}
