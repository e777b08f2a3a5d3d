//! The mannequin: per-identity proportions (rest joints), looks (skin, hair, clothing
//! patterns) and the primitives of one posed, expressive frame.
//!
//! Every primitive is authored in the T-pose ("rest") space of the joint that carries it
//! and moves rigidly with that joint, so textures evaluated at rest-space coordinates are
//! glued to the limb. Rest space is the SMPL-X convention: metres, y up, the subject faces
//! +z, +x is the subject's left.

use glam::{DVec3, Vec3};

use super::sdf::Shape;
use super::talk::SplitMix;
use talkin_human::body::skeleton::joint::*;
use talkin_human::body::{FrameParams, N_JOINTS, PosedSkeleton, Skeleton};

/// Segmentation labels of the dataset format.
pub mod label {
    pub const BODY: u8 = 1;
    pub const ARMS: u8 = 2;
    pub const HANDS: u8 = 3;
    pub const HEAD: u8 = 4;
}

/// Body measurements of one identity (factors of a 1.7 m adult, shoulder half-width in m).
#[derive(Clone, Copy, Debug)]
pub struct Proportions {
    pub height: f64,
    pub shoulder: f64,
    pub arm: f64,
    pub leg: f64,
    pub head: f64,
    pub hand: f64,
}

/// The proportions of identity `i`: three authored ones, then random variations of them.
pub fn proportions(identity: usize) -> Proportions {
    let base = [
        Proportions {
            height: 0.97,
            shoulder: 0.165,
            arm: 0.97,
            leg: 1.0,
            head: 1.0,
            hand: 0.95,
        },
        Proportions {
            height: 1.07,
            shoulder: 0.198,
            arm: 1.06,
            leg: 1.03,
            head: 1.06,
            hand: 1.08,
        },
        Proportions {
            height: 0.91,
            shoulder: 0.152,
            arm: 0.92,
            leg: 0.96,
            head: 0.95,
            hand: 0.9,
        },
    ];
    let p = base[identity % 3];
    if identity < 3 {
        return p;
    }
    let mut rng = SplitMix::new(0x5eed_1d00 + identity as u64);
    let mut f = |x: f64, spread: f64| x * (1.0 + rng.range(-spread, spread));
    Proportions {
        height: f(p.height, 0.06),
        shoulder: f(p.shoulder, 0.08),
        arm: f(p.arm, 0.05),
        leg: f(p.leg, 0.04),
        head: f(p.head, 0.05),
        hand: f(p.hand, 0.06),
    }
}

/// Left-hand finger knuckles relative to the wrist (index, middle, pinky, ring), segment
/// lengths and radii, for a 1.0 hand. The right hand mirrors x.
const FINGERS: [([f64; 3], [f64; 3], f32); 4] = [
    ([0.088, 0.004, 0.026], [0.038, 0.024, 0.021], 0.0093),
    ([0.093, 0.004, 0.006], [0.042, 0.027, 0.023], 0.0096),
    ([0.080, 0.000, -0.032], [0.030, 0.020, 0.018], 0.0080),
    ([0.089, 0.002, -0.013], [0.038, 0.026, 0.021], 0.0090),
];
/// Left thumb: base (CMC) relative to the wrist, direction, segment lengths, radius.
const THUMB: ([f64; 3], [f64; 3], [f64; 3], f32) = (
    [0.024, -0.012, 0.026],
    [0.72, -0.2, 0.66],
    [0.036, 0.032, 0.026],
    0.0108,
);

/// Rest (T-pose) joints of identity `identity`, in metres, feet near y = 0.
pub fn default_rest_joints(identity: usize) -> Skeleton {
    rest_joints(&proportions(identity))
}

/// Rest joints from measurements.
pub fn rest_joints(p: &Proportions) -> Skeleton {
    let s = p.height;
    let mut j = [DVec3::ZERO; N_JOINTS];
    let hip_y = 0.88 * s * p.leg;
    j[PELVIS] = DVec3::new(0.0, hip_y + 0.07 * s, 0.0);
    j[LEFT_HIP] = DVec3::new(0.085 * s, hip_y, 0.0);
    j[RIGHT_HIP] = DVec3::new(-0.085 * s, hip_y, 0.0);
    j[SPINE1] = j[PELVIS] + DVec3::new(0.0, 0.10 * s, -0.012);
    j[SPINE2] = j[SPINE1] + DVec3::new(0.0, 0.13 * s, 0.004);
    j[SPINE3] = j[SPINE2] + DVec3::new(0.0, 0.06 * s, 0.01);
    j[NECK] = j[SPINE3] + DVec3::new(0.0, 0.2 * s, -0.02);
    j[HEAD] = j[NECK] + DVec3::new(0.0, 0.08 * s, 0.015);
    for (side, sign) in [(0usize, 1.0f64), (1, -1.0)] {
        let m = |v: DVec3| DVec3::new(v.x * sign, v.y, v.z);
        j[LEFT_KNEE + side] = m(DVec3::new(0.09 * s, hip_y - 0.40 * s * p.leg, 0.01));
        j[LEFT_ANKLE + side] = m(DVec3::new(0.085 * s, hip_y - 0.80 * s * p.leg, -0.03));
        j[LEFT_FOOT + side] = m(DVec3::new(0.10 * s, 0.02, 0.10));
        let shoulder_y = j[SPINE3].y + 0.16 * s;
        j[LEFT_COLLAR + side] = m(DVec3::new(0.075 * s, j[SPINE3].y + 0.14 * s, -0.005));
        j[LEFT_SHOULDER + side] = m(DVec3::new(p.shoulder, shoulder_y, -0.015));
        let elbow_x = p.shoulder + 0.27 * p.arm;
        j[LEFT_ELBOW + side] = m(DVec3::new(elbow_x, shoulder_y, -0.025));
        let wrist = m(DVec3::new(elbow_x + 0.24 * p.arm, shoulder_y, -0.015));
        j[LEFT_WRIST + side] = wrist;
        let first = LEFT_HAND_FIRST + 15 * side;
        for (f, (knuckle, lengths, _)) in FINGERS.iter().enumerate() {
            let mut at = wrist + m(DVec3::from(*knuckle) * p.hand);
            for (k, &len) in lengths.iter().enumerate() {
                j[first + 3 * f + k] = at;
                at += m(DVec3::X) * len * p.hand;
            }
        }
        let (base, dir, lengths, _) = THUMB;
        let dir = m(DVec3::from(dir).normalize());
        let mut at = wrist + m(DVec3::from(base) * p.hand);
        for (k, &len) in lengths.iter().enumerate() {
            j[first + 12 + k] = at;
            at += dir * len * p.hand;
        }
    }
    let head = HeadFrame::new(j[HEAD], p.head);
    j[JAW] = head.at(0.0, 0.06, 0.0);
    for (eye, sign) in [(LEFT_EYE, 1.0f32), (RIGHT_EYE, -1.0)] {
        j[eye] = head.eye_centre(sign).as_dvec3();
    }
    Skeleton { rest_joints: j }
}

/// Face layout in the head's rest space: offsets from the head joint, scaled by the head
/// factor.
#[derive(Clone, Copy, Debug)]
struct HeadFrame {
    joint: Vec3,
    k: f32,
}

impl HeadFrame {
    const CENTRE: Vec3 = Vec3::new(0.0, 0.095, 0.012);
    const RADII: Vec3 = Vec3::new(0.077, 0.102, 0.093);
    const EYE_Y: f32 = 0.1;
    const MOUTH_Y: f32 = 0.045;
    const EYE_X: f32 = 0.031;
    const EYE_R: f32 = 0.0125;

    fn new(joint: DVec3, k: f64) -> Self {
        Self {
            joint: joint.as_vec3(),
            k: k as f32,
        }
    }
    fn at(&self, x: f32, y: f32, z: f32) -> DVec3 {
        (self.joint + Vec3::new(x, y, z) * self.k).as_dvec3()
    }
    fn p(&self, x: f32, y: f32, z: f32) -> Vec3 {
        self.joint + Vec3::new(x, y, z) * self.k
    }
    /// z (unscaled offset) of the head ellipsoid's front surface at (x, y).
    fn front(x: f32, y: f32) -> f32 {
        let d = Vec3::new(x, y - Self::CENTRE.y, 0.0) / Self::RADII;
        Self::CENTRE.z + Self::RADII.z * (1.0 - d.x * d.x - d.y * d.y).max(0.0).sqrt()
    }
    fn eye_centre(&self, sign: f32) -> Vec3 {
        let x = sign * Self::EYE_X;
        self.p(
            x,
            Self::EYE_Y,
            Self::front(x, Self::EYE_Y) - Self::EYE_R + 0.0035,
        )
    }
}

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

/// The look of identity `i`: three authored ones, then recoloured variations.
pub fn look(identity: usize) -> Look {
    let rgb = |r: u8, g: u8, b: u8| Vec3::new(r as f32, g as f32, b as f32) / 255.0;
    let looks = [
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
    let mut l = looks[identity % 3];
    if identity >= 3 {
        let mut rng = SplitMix::new(0x100c_0000 + identity as u64);
        let mut tint = |c: Vec3| {
            (c * Vec3::new(
                rng.range(0.6, 1.3) as f32,
                rng.range(0.6, 1.3) as f32,
                rng.range(0.6, 1.3) as f32,
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

fn v(x: DVec3) -> Vec3 {
    x.as_vec3()
}

/// Builds the primitives of identity `look`/`prop` for one frame's expression and jaw.
pub fn figure(
    skeleton: &Skeleton,
    prop: &Proportions,
    look: &Look,
    params: &FrameParams,
) -> Figure {
    let j = skeleton.rest_joints.map(v);
    let s = prop.height as f32;
    let mut prims = Vec::with_capacity(96);
    let mut add = |joint: usize, shape: Shape, blend: f32, material: Material, label: u8| {
        prims.push(Prim {
            joint,
            shape,
            blend,
            material,
            label,
        });
    };
    let rc = |a: Vec3, b: Vec3, ra: f32, rb: f32| Shape::RoundCone { a, b, ra, rb };
    let el = |c: Vec3, r: Vec3| Shape::Ellipsoid { c, r };

    // Torso and hips.
    add(
        PELVIS,
        el(
            j[PELVIS] + Vec3::new(0.0, -0.02, 0.0),
            Vec3::new(0.16, 0.12, 0.11) * s,
        ),
        0.0,
        Material::Bottom,
        label::BODY,
    );
    add(
        SPINE1,
        el(
            j[SPINE1] + Vec3::new(0.0, 0.05, 0.0),
            Vec3::new(0.14, 0.13, 0.1) * s,
        ),
        0.05,
        Material::Top,
        label::BODY,
    );
    let chest_w = 0.09 + prop.shoulder as f32 * 0.45;
    add(
        SPINE3,
        el(
            j[SPINE3] + Vec3::new(0.0, 0.03, 0.012),
            Vec3::new(chest_w, 0.15 * s, 0.105 * s),
        ),
        0.06,
        Material::Top,
        label::BODY,
    );
    for side in 0..2 {
        add(
            LEFT_COLLAR + side,
            rc(
                j[LEFT_COLLAR + side] + Vec3::new(0.0, 0.0, 0.0),
                j[LEFT_SHOULDER + side],
                0.06 * s,
                0.055 * s,
            ),
            0.05,
            Material::Top,
            label::BODY,
        );
        add(
            LEFT_HIP + side,
            rc(
                j[LEFT_HIP + side],
                j[LEFT_KNEE + side],
                0.085 * s,
                0.058 * s,
            ),
            0.03,
            Material::Bottom,
            label::BODY,
        );
        add(
            LEFT_KNEE + side,
            rc(
                j[LEFT_KNEE + side],
                j[LEFT_ANKLE + side],
                0.056 * s,
                0.04 * s,
            ),
            0.01,
            Material::Skin,
            label::BODY,
        );
        add(
            LEFT_ANKLE + side,
            rc(
                j[LEFT_ANKLE + side],
                j[LEFT_FOOT + side],
                0.042 * s,
                0.038 * s,
            ),
            0.01,
            Material::Shoe,
            label::BODY,
        );
    }
    add(
        NECK,
        rc(
            j[NECK] + Vec3::new(0.0, -0.04, 0.0),
            j[HEAD] + Vec3::new(0.0, 0.03, 0.0),
            0.052 * s,
            0.046 * s,
        ),
        0.03,
        Material::Skin,
        label::BODY,
    );
    match look.garment {
        Garment::Skirt => {
            let top = Vec3::new(0.0, j[PELVIS].y + 0.02, 0.0);
            let hem = Vec3::new(0.0, j[PELVIS].y - 0.42 * s, 0.02);
            add(
                PELVIS,
                Shape::CappedCone {
                    a: top,
                    b: hem,
                    ra: 0.165 * s,
                    rb: 0.29 * s,
                },
                0.03,
                Material::Bottom,
                label::BODY,
            );
        }
        Garment::JacketHem => {
            let top = Vec3::new(0.0, j[SPINE1].y + 0.03, 0.0);
            let hem = Vec3::new(0.0, j[PELVIS].y - 0.13 * s, 0.01);
            add(
                SPINE1,
                Shape::CappedCone {
                    a: top,
                    b: hem,
                    ra: 0.15 * s,
                    rb: 0.215 * s,
                },
                0.03,
                Material::Top,
                label::BODY,
            );
        }
    }

    // Arms, sleeves, hands.
    for side in 0..2 {
        let sign = if side == 0 { 1.0 } else { -1.0 };
        let (sh, el_j, wr) = (LEFT_SHOULDER + side, LEFT_ELBOW + side, LEFT_WRIST + side);
        let along = Vec3::X * sign;
        add(
            sh,
            rc(j[sh], j[el_j], 0.05 * s, 0.041 * s),
            0.03,
            Material::Top,
            label::ARMS,
        );
        let forearm = if look.sleeve == Sleeve::Short {
            Material::Skin
        } else {
            Material::Top
        };
        add(
            el_j,
            rc(j[el_j], j[wr], 0.04 * s, 0.029 * s),
            0.02,
            forearm,
            label::ARMS,
        );
        let cone = |a: Vec3, b: Vec3, ra: f32, rb: f32| Shape::CappedCone { a, b, ra, rb };
        match look.sleeve {
            Sleeve::Short => add(
                sh,
                cone(
                    j[sh] + along * 0.07,
                    j[sh] + along * 0.17,
                    0.056 * s,
                    0.066 * s,
                ),
                0.01,
                Material::Top,
                label::ARMS,
            ),
            Sleeve::Cuffed => add(
                el_j,
                cone(
                    j[wr] - along * 0.08,
                    j[wr] - along * 0.015,
                    0.036 * s,
                    0.052 * s,
                ),
                0.01,
                Material::Top,
                label::ARMS,
            ),
            Sleeve::Loose => add(
                el_j,
                cone(
                    j[el_j] + along * 0.01,
                    j[el_j] + along * 0.14,
                    0.047 * s,
                    0.074 * s,
                ),
                0.01,
                Material::Top,
                label::ARMS,
            ),
        }
        // Palm, thenar, fingers (3 segments each plus the thumb).
        let h = prop.hand as f32;
        let first = LEFT_HAND_FIRST + 15 * side;
        add(
            wr,
            el(
                j[wr] + along * 0.052 * h + Vec3::new(0.0, 0.0, -0.003),
                Vec3::new(0.05, 0.016, 0.042) * h,
            ),
            0.012,
            Material::Skin,
            label::HANDS,
        );
        add(
            wr,
            rc(
                j[wr] + (along * 0.015 + Vec3::new(0.0, -0.004, 0.008)) * h,
                j[first + 12],
                0.017 * h,
                0.013 * h,
            ),
            0.01,
            Material::Skin,
            label::HANDS,
        );
        let mut finger = |chain: usize, radius: f32| {
            let joints = [
                first + 3 * chain,
                first + 3 * chain + 1,
                first + 3 * chain + 2,
            ];
            let tip = j[joints[2]] + (j[joints[2]] - j[joints[1]]) * 0.9;
            let ends = [j[joints[1]], j[joints[2]], tip];
            for k in 0..3 {
                let r0 = radius * 0.92f32.powi(k as i32) * h;
                add(
                    joints[k],
                    rc(j[joints[k]], ends[k], r0, r0 * 0.92),
                    if k == 0 { 0.008 } else { 0.002 },
                    Material::Skin,
                    label::HANDS,
                );
            }
        };
        for (f, (_, _, radius)) in FINGERS.iter().enumerate() {
            finger(f, *radius);
        }
        finger(4, THUMB.3);
    }

    // Head.
    let head = HeadFrame::new(skeleton.rest_joints[HEAD], prop.head);
    let e = params.expression.map(|x| x.clamp(-3.0, 3.0) as f32);
    let hk = head.k;
    add(
        HEAD,
        el(
            head.p(0.0, 0.0, 0.0) + HeadFrame::CENTRE * hk,
            HeadFrame::RADII * hk,
        ),
        0.03,
        Material::Face,
        label::HEAD,
    );
    add(
        JAW,
        el(head.p(0.0, 0.012, 0.056), Vec3::new(0.046, 0.03, 0.04) * hk),
        0.022,
        Material::Face,
        label::HEAD,
    );
    let eye_y = HeadFrame::EYE_Y;
    // Nose and ears.
    add(
        HEAD,
        rc(
            head.p(0.0, eye_y - 0.006, HeadFrame::front(0.0, eye_y) - 0.006),
            head.p(
                0.0,
                eye_y - 0.036,
                HeadFrame::front(0.0, eye_y - 0.036) + 0.016,
            ),
            0.006 * hk,
            0.0105 * hk,
        ),
        0.012,
        Material::Face,
        label::HEAD,
    );
    for sign in [1.0f32, -1.0] {
        add(
            HEAD,
            el(
                head.p(sign * 0.077, eye_y - 0.012, 0.002),
                Vec3::new(0.011, 0.026, 0.016) * hk,
            ),
            0.006,
            Material::Face,
            label::HEAD,
        );
        // Cheeks: smile (0) raises them, puff (6) grows them.
        let cy = HeadFrame::MOUTH_Y + 0.022 + 0.004 * e[0];
        let cx = sign * 0.042;
        let grow = (1.0 + 0.2 * e[6] + 0.06 * e[0]).clamp(0.6, 1.6);
        add(
            HEAD,
            el(
                head.p(cx, cy, HeadFrame::front(cx, cy) - 0.017),
                Vec3::new(0.02, 0.017, 0.015) * hk * grow,
            ),
            0.014,
            Material::Face,
            label::HEAD,
        );
    }

    // Eyes, lids (blink/squint 3), brows (raise 1, furrow 2, asymmetry 9).
    let open = (1.0 - 0.45 * e[3]).clamp(0.0, 1.25);
    for (eye, sign) in [(LEFT_EYE, 1.0f32), (RIGHT_EYE, -1.0)] {
        let c = j[eye];
        let r = HeadFrame::EYE_R * hk;
        add(
            eye,
            Shape::Ellipsoid {
                c,
                r: Vec3::splat(r),
            },
            0.0,
            Material::Eye,
            label::HEAD,
        );
        let lid_r = Vec3::splat(r * 1.1);
        let upper = c.y + (-0.95 + 1.75 * open.min(1.0) + 0.2 * (open - 1.0).max(0.0)) * r;
        let lower = c.y - 0.72 * r;
        add(
            HEAD,
            Shape::CutEllipsoid {
                c,
                r: lid_r,
                n: Vec3::NEG_Y,
                d: -upper,
            },
            0.0,
            Material::Lid {
                edge_y: upper,
                up: true,
            },
            label::HEAD,
        );
        add(
            HEAD,
            Shape::CutEllipsoid {
                c,
                r: lid_r,
                n: Vec3::Y,
                d: lower,
            },
            0.0,
            Material::Lid {
                edge_y: lower,
                up: false,
            },
            label::HEAD,
        );
        let raise = 0.008 * e[1] + 0.005 * sign * e[9];
        let inner_x = sign * (0.013 - 0.003 * e[2].max(0.0));
        let inner_y = eye_y + 0.027 + raise - 0.005 * e[2];
        let outer_x = sign * 0.048;
        let outer_y = eye_y + 0.025 + raise * 0.8;
        let brow = |x: f32, y: f32| head.p(x, y, HeadFrame::front(x, y) + 0.0005);
        add(
            HEAD,
            rc(
                brow(inner_x, inner_y),
                brow(outer_x, outer_y),
                0.0048 * hk,
                0.0036 * hk,
            ),
            0.0,
            Material::Brow,
            label::HEAD,
        );
    }

    // Mouth: smile (0) and smirk (7) lift the corners, width (4) and pucker (5) move
    // them, upper-lip raise (8); the lower lip rides on the jaw.
    let jaw_open = (params.jaw_pose.x as f32).clamp(-0.1, 0.8);
    let mouth_y = HeadFrame::MOUTH_Y;
    let half_w = (0.024 * (1.0 + 0.16 * e[4] - 0.2 * e[5].max(0.0))).clamp(0.012, 0.036);
    let pucker = 0.006 * e[5].max(0.0);
    let mz = |x: f32, y: f32| HeadFrame::front(x, y) + pucker;
    let corner_y = |sign: f32| mouth_y + 0.006 * e[0] + 0.005 * sign * e[7];
    let upper_mid = mouth_y + 0.0045 + 0.003 * e[8];
    let lower_mid = mouth_y - 0.0055;
    let lip_r = 0.0052 * hk;
    for sign in [1.0f32, -1.0] {
        let cx = sign * half_w;
        let corner = head.p(cx, corner_y(sign), mz(cx, corner_y(sign)) - 0.004);
        add(
            HEAD,
            rc(
                corner,
                head.p(0.0, upper_mid, mz(0.0, upper_mid) + 0.002),
                lip_r * 0.7,
                lip_r,
            ),
            0.004,
            Material::Lip,
            label::HEAD,
        );
        add(
            JAW,
            rc(
                corner,
                head.p(0.0, lower_mid, mz(0.0, lower_mid) + 0.001),
                lip_r * 0.7,
                lip_r * 1.15,
            ),
            0.004,
            Material::Lip,
            label::HEAD,
        );
    }
    let face = FaceState {
        mouth_open: 0.1 * jaw_open.max(0.0).sin() + 0.002 * e[8].max(0.0),
        mouth_half_width: half_w,
        mouth_y,
        mouth_z: mz(0.0, mouth_y),
    };

    // Hair: a cap cut off above the face, plus a bun or a ponytail.
    let c = HeadFrame::CENTRE;
    let n = Vec3::new(0.0, -0.25, 1.0).normalize();
    let cut_at = head.p(0.0, c.y + 0.05, c.z + 0.03);
    let cap_r = (HeadFrame::RADII + Vec3::new(0.011, 0.01, 0.01)) * hk;
    add(
        HEAD,
        Shape::CutEllipsoid {
            c: head.p(c.x, c.y + 0.008, c.z - 0.008),
            r: cap_r,
            n,
            d: n.dot(cut_at),
        },
        0.0,
        Material::Hair,
        label::HEAD,
    );
    match look.hair_style {
        // A bun on the crown: a bump on the silhouette.
        HairStyle::Bun => add(
            HEAD,
            el(
                head.p(0.0, c.y + 0.095, c.z - 0.072),
                Vec3::new(0.05, 0.047, 0.05) * hk,
            ),
            0.02,
            Material::Hair,
            label::HEAD,
        ),
        // A side ponytail hanging behind the left ear, beside the neck.
        HairStyle::Ponytail => add(
            HEAD,
            rc(
                head.p(0.045, c.y + 0.01, c.z - 0.08),
                head.p(0.095, c.y - 0.18, c.z - 0.13),
                0.036 * hk,
                0.02 * hk,
            ),
            0.02,
            Material::Hair,
            label::HEAD,
        ),
    }
    Figure {
        prims,
        face,
        look: *look,
        head_joint: head.joint,
        head_scale: hk,
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identities_differ_and_hands_follow_the_smplx_convention() {
        let a = default_rest_joints(0).rest_joints;
        let b = default_rest_joints(1).rest_joints;
        let height = |j: &[DVec3; N_JOINTS]| j[HEAD].y - j[LEFT_ANKLE].y;
        let shoulders = |j: &[DVec3; N_JOINTS]| j[LEFT_SHOULDER].x - j[RIGHT_SHOULDER].x;
        assert!(height(&b) > height(&a) + 0.05);
        assert!(shoulders(&b) > shoulders(&a) + 0.04);
        for j in [a, b, default_rest_joints(5).rest_joints] {
            // +x is the subject's left; fingers point away from the body; the thumb sits on
            // the front (+z) side of the palm in the T-pose with palms down.
            assert!(j[LEFT_WRIST].x > j[LEFT_ELBOW].x && j[RIGHT_WRIST].x < j[RIGHT_ELBOW].x);
            for (wrist, first, sign) in [
                (LEFT_WRIST, LEFT_HAND_FIRST, 1.0),
                (RIGHT_WRIST, RIGHT_HAND_FIRST, -1.0),
            ] {
                for f in 0..5 {
                    for k in 0..3 {
                        assert!((j[first + 3 * f + k].x - j[wrist].x) * sign > 0.0);
                    }
                }
                let thumb = j[first + 12];
                assert!(
                    thumb.z > j[first + 3].z && thumb.z > j[first + 9].z,
                    "thumb in front"
                );
                assert!(j[first].z > j[first + 6].z, "index in front of the pinky");
            }
            assert!(j[LEFT_EYE].x > 0.0 && j[LEFT_EYE].z > j[HEAD].z);
        }
    }

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
}
