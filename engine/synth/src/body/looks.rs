//! An identity's appearance: skin, hair, lip and iris colours, the clothing patterns
//! (evaluated at rest-space points so they stay glued to the limbs) and the choice of
//! hair style, garment and sleeve.

use glam::Vec3;

use crate::talk::scene_rng;

/// A clothing pattern, evaluated at rest-space points (metres).
#[derive(Clone, Copy, Debug)]
pub enum Pattern {
    Stripes {
        a: Vec3,
        b: Vec3,
        period: f32,
        dir: Vec3,
    },
    Checks {
        a: Vec3,
        b: Vec3,
        cell: f32,
    },
    Dots {
        a: Vec3,
        b: Vec3,
        spacing: f32,
        radius: f32,
    },
    Plaid {
        a: Vec3,
        b: Vec3,
        c: Vec3,
        cell: f32,
    },
}

impl Pattern {
    /// The colour at rest-space point `p` (metres).
    pub fn colour(&self, p: Vec3) -> Vec3 {
        match *self {
            Pattern::Stripes { a, b, period, dir } => {
                if (p.dot(dir) / period).rem_euclid(1.0) < 0.5 {
                    a
                } else {
                    b
                }
            }
            Pattern::Checks { a, b, cell } => {
                let q = (p / cell).floor();
                if (q.x + q.y + q.z).rem_euclid(2.0) < 1.0 {
                    a
                } else {
                    b
                }
            }
            Pattern::Dots {
                a,
                b,
                spacing,
                radius,
            } => {
                let q = p / spacing;
                let f = (q - q.round()) * spacing;
                if f.length() < radius { b } else { a }
            }
            Pattern::Plaid { a, b, c, cell } => {
                let u = (p.x / cell).rem_euclid(1.0);
                let v = (p.y / cell).rem_euclid(1.0);
                let bands = (u < 0.3) as u8 + (v < 0.3) as u8;
                let thin = (u - 0.65).abs() < 0.05 || (v - 0.65).abs() < 0.05;
                if thin {
                    c
                } else {
                    [a, a.lerp(b, 0.5), b][bands as usize]
                }
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HairStyle {
    Bun,
    Ponytail,
}

/// What hangs below the waist or flares off the torso.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Garment {
    Skirt,
    JacketHem,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sleeve {
    /// Short flared sleeve on the upper arm, bare forearm.
    Short,
    /// Long sleeve with a loose cuff at the wrist.
    Cuffed,
    /// Three-quarter sleeve, wide and loose below the elbow.
    Loose,
}

/// An identity's appearance.
#[derive(Clone, Copy, Debug)]
pub struct Look {
    pub skin: Vec3,
    pub hair: Vec3,
    pub lip: Vec3,
    pub iris: Vec3,
    pub top: Pattern,
    pub bottom: Pattern,
    pub hair_style: HairStyle,
    pub garment: Garment,
    pub sleeve: Sleeve,
}

/// A colour from 8-bit components.
const fn rgb(r: u8, g: u8, b: u8) -> Vec3 {
    Vec3::new(r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0)
}

/// The authored looks of identities 0, 1 and 2.
const LOOKS: [Look; 3] = [
    Look {
        skin: rgb(224, 172, 140),
        hair: rgb(62, 40, 28),
        lip: rgb(178, 82, 88),
        iris: rgb(70, 45, 25),
        top: Pattern::Stripes {
            a: rgb(28, 40, 92),
            b: rgb(236, 232, 220),
            period: 0.034,
            dir: Vec3::Y,
        },
        bottom: Pattern::Dots {
            a: rgb(170, 30, 40),
            b: rgb(250, 220, 120),
            spacing: 0.045,
            radius: 0.011,
        },
        hair_style: HairStyle::Bun,
        garment: Garment::Skirt,
        sleeve: Sleeve::Short,
    },
    Look {
        skin: rgb(120, 78, 54),
        hair: rgb(22, 18, 16),
        lip: rgb(120, 58, 56),
        iris: rgb(40, 28, 20),
        top: Pattern::Checks {
            a: rgb(40, 110, 70),
            b: rgb(214, 200, 160),
            cell: 0.04,
        },
        bottom: Pattern::Plaid {
            a: rgb(70, 70, 80),
            b: rgb(140, 140, 150),
            c: rgb(200, 60, 50),
            cell: 0.06,
        },
        hair_style: HairStyle::Ponytail,
        garment: Garment::JacketHem,
        sleeve: Sleeve::Cuffed,
    },
    Look {
        skin: rgb(242, 200, 170),
        hair: rgb(150, 66, 30),
        lip: rgb(200, 90, 100),
        iris: rgb(60, 110, 150),
        top: Pattern::Stripes {
            a: rgb(240, 190, 40),
            b: rgb(90, 40, 120),
            period: 0.028,
            dir: Vec3::new(
                std::f32::consts::FRAC_1_SQRT_2,
                std::f32::consts::FRAC_1_SQRT_2,
                0.0,
            ),
        },
        bottom: Pattern::Checks {
            a: rgb(30, 30, 36),
            b: rgb(230, 230, 235),
            cell: 0.03,
        },
        hair_style: HairStyle::Bun,
        garment: Garment::Skirt,
        sleeve: Sleeve::Loose,
    },
];

/// The look of identity `i`: three authored ones, then recoloured variations.
pub fn look(identity: usize) -> Look {
    let mut l = LOOKS[identity % 3];
    if identity >= 3 {
        let mut rng = scene_rng(0x100c_0000 + identity as u64);
        let mut tint = |c: Vec3| {
            (c * Vec3::new(
                rng.uniform(0.6, 1.3) as f32,
                rng.uniform(0.6, 1.3) as f32,
                rng.uniform(0.6, 1.3) as f32,
            ))
            .min(Vec3::ONE)
        };
        l.skin = tint(l.skin);
        l.hair = tint(l.hair);
        l.top = match l.top {
            Pattern::Stripes { a, b, period, dir } => Pattern::Stripes {
                a: tint(a),
                b: tint(b),
                period,
                dir,
            },
            Pattern::Checks { a, b, cell } => Pattern::Checks {
                a: tint(a),
                b: tint(b),
                cell,
            },
            other => other,
        };
        l.hair_style = if identity.is_multiple_of(2) {
            HairStyle::Ponytail
        } else {
            HairStyle::Bun
        };
    }
    l
}
