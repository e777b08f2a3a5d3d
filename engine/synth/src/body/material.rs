//! Surface materials and their colours: what the renderer paints at a hit, given the
//! figure's look and face state and where (rest space) the ray hit.

use glam::Vec3;

use super::{Figure, Look};

/// Surface material; the colour also depends on where (rest space) the ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    Skin,
    /// Head skin: the mouth opening is painted on it.
    Face,
    Lip,
    Eye,
    /// Eyelid skin with a dark lash line at its free edge (`edge_y`, `up` = upper lid).
    Lid {
        edge_y: f32,
        up: bool,
    },
    Brow,
    Hair,
    Top,
    Bottom,
    Shoe,
}

/// The albedo of a material at rest-space point `p`.
pub fn albedo(fig: &Figure, material: Material, p: Vec3) -> Vec3 {
    let look = &fig.look;
    match material {
        Material::Skin => look.skin,
        Material::Face => {
            // Painted mouth opening, in head offsets.
            let q = (p - fig.head_joint) / fig.head_scale;
            let f = &fig.face;
            let h = f.mouth_open * 0.5;
            if h > 0.0005 && q.z > f.mouth_z - 0.03 {
                let dy = (q.y - (f.mouth_y - h)) / (h + 0.002);
                let dx = q.x / f.mouth_half_width;
                if dx * dx + dy * dy < 1.0 {
                    return if dy > 0.55 && dx.abs() < 0.8 {
                        Vec3::new(0.92, 0.9, 0.85)
                    } else {
                        Vec3::new(0.25, 0.05, 0.06)
                    };
                }
            }
            look.skin
        }
        Material::Lip => look.lip,
        Material::Eye => Vec3::new(0.95, 0.95, 0.93),
        Material::Lid { edge_y, up } => {
            let near_edge = if up {
                p.y - edge_y < 0.0018 * fig.head_scale
            } else {
                edge_y - p.y < 0.0012 * fig.head_scale
            };
            if near_edge {
                Vec3::new(0.12, 0.08, 0.07)
            } else {
                look.skin * 0.93
            }
        }
        Material::Brow => look.hair * 0.8,
        Material::Hair => {
            let strand =
                ((p.x * 900.0).sin() * 0.5 + (p.x * 330.0 + p.z * 410.0).sin() * 0.5) * 0.08;
            look.hair * (1.0 + strand)
        }
        Material::Top => look.top.colour(p),
        Material::Bottom => look.bottom.colour(p),
        Material::Shoe => Vec3::new(0.15, 0.13, 0.12),
    }
}

/// Colour of the eye's surface at `p` (rest space of the eye joint, centre `c`): sclera,
/// iris, pupil, looking along +z.
pub fn eye_colour(look: &Look, p: Vec3, c: Vec3) -> Vec3 {
    let d = (p - c).normalize_or_zero();
    if d.z > 0.955 {
        Vec3::splat(0.04)
    } else if d.z > 0.84 {
        look.iris
    } else {
        Vec3::new(0.95, 0.95, 0.93)
    }
}
