//! The body below the head as tables of shapes: torso, legs, neck, the garment, arms,
//! sleeves and hands, with the few choices the look makes between rows.

use super::measures::{FINGERS, THUMB};
use super::shapes::At::{Along, AlongHand, Axis, HandOff, Joint, Off};
use super::shapes::J::{Digit, Mid, Pair};
use super::shapes::Len::{Body, Chest, Hand, M};
use super::shapes::{Builder, Form, Spec};
use super::{Garment, Material, Sleeve, label};
use crate::sdf::Shape;
use talkin_human::body::skeleton::joint::*;

/// Hips, belly and chest; the chest's width follows the shoulders.
pub(super) const TORSO: [Spec; 3] = [
    Spec {
        joint: Mid(PELVIS),
        form: Form::Ellipsoid {
            c: Off(Mid(PELVIS), [0.0, -0.02, 0.0]),
            r: [Body(0.16), Body(0.12), Body(0.11)],
        },
        blend: 0.0,
        material: Material::Bottom,
        label: label::BODY,
    },
    Spec {
        joint: Mid(SPINE1),
        form: Form::Ellipsoid {
            c: Off(Mid(SPINE1), [0.0, 0.05, 0.0]),
            r: [Body(0.14), Body(0.13), Body(0.1)],
        },
        blend: 0.05,
        material: Material::Top,
        label: label::BODY,
    },
    Spec {
        joint: Mid(SPINE3),
        form: Form::Ellipsoid {
            c: Off(Mid(SPINE3), [0.0, 0.03, 0.012]),
            r: [Chest, Body(0.15), Body(0.105)],
        },
        blend: 0.06,
        material: Material::Top,
        label: label::BODY,
    },
];

/// Per side: the collar (shoulder pad), thigh, shin and shoe.
pub(super) const COLLAR_AND_LEG: [Spec; 4] = [
    Spec {
        joint: Pair(LEFT_COLLAR),
        form: Form::RoundCone {
            a: Off(Pair(LEFT_COLLAR), [0.0, 0.0, 0.0]),
            b: Joint(Pair(LEFT_SHOULDER)),
            ra: Body(0.06),
            rb: Body(0.055),
        },
        blend: 0.05,
        material: Material::Top,
        label: label::BODY,
    },
    Spec {
        joint: Pair(LEFT_HIP),
        form: Form::RoundCone {
            a: Joint(Pair(LEFT_HIP)),
            b: Joint(Pair(LEFT_KNEE)),
            ra: Body(0.085),
            rb: Body(0.058),
        },
        blend: 0.03,
        material: Material::Bottom,
        label: label::BODY,
    },
    Spec {
        joint: Pair(LEFT_KNEE),
        form: Form::RoundCone {
            a: Joint(Pair(LEFT_KNEE)),
            b: Joint(Pair(LEFT_ANKLE)),
            ra: Body(0.056),
            rb: Body(0.04),
        },
        blend: 0.01,
        material: Material::Skin,
        label: label::BODY,
    },
    Spec {
        joint: Pair(LEFT_ANKLE),
        form: Form::RoundCone {
            a: Joint(Pair(LEFT_ANKLE)),
            b: Joint(Pair(LEFT_FOOT)),
            ra: Body(0.042),
            rb: Body(0.038),
        },
        blend: 0.01,
        material: Material::Shoe,
        label: label::BODY,
    },
];

pub(super) const NECK_ROW: Spec = Spec {
    joint: Mid(NECK),
    form: Form::RoundCone {
        a: Off(Mid(NECK), [0.0, -0.04, 0.0]),
        b: Off(Mid(HEAD), [0.0, 0.03, 0.0]),
        ra: Body(0.052),
        rb: Body(0.046),
    },
    blend: 0.03,
    material: Material::Skin,
    label: label::BODY,
};

// The hems sit `0.42 * s` (`0.13 * s`) below the pelvis: `y + (-0.42 * s)` is the same
// f32 as `y - 0.42 * s`, so `Body(-0.42)` keeps the hand-written value.
const SKIRT: Spec = Spec {
    joint: Mid(PELVIS),
    form: Form::CappedCone {
        a: Axis(Mid(PELVIS), M(0.02), 0.0),
        b: Axis(Mid(PELVIS), Body(-0.42), 0.02),
        ra: Body(0.165),
        rb: Body(0.29),
    },
    blend: 0.03,
    material: Material::Bottom,
    label: label::BODY,
};

const JACKET_HEM: Spec = Spec {
    joint: Mid(SPINE1),
    form: Form::CappedCone {
        a: Axis(Mid(SPINE1), M(0.03), 0.0),
        b: Axis(Mid(PELVIS), Body(-0.13), 0.01),
        ra: Body(0.15),
        rb: Body(0.215),
    },
    blend: 0.03,
    material: Material::Top,
    label: label::BODY,
};

/// The loose cone that hangs below the waist or flares off the torso.
pub(super) fn garment(garment: Garment) -> &'static Spec {
    match garment {
        Garment::Skirt => &SKIRT,
        Garment::JacketHem => &JACKET_HEM,
    }
}

const UPPER_ARM: Spec = Spec {
    joint: Pair(LEFT_SHOULDER),
    form: Form::RoundCone {
        a: Joint(Pair(LEFT_SHOULDER)),
        b: Joint(Pair(LEFT_ELBOW)),
        ra: Body(0.05),
        rb: Body(0.041),
    },
    blend: 0.03,
    material: Material::Top,
    label: label::ARMS,
};

/// Sleeved; bare skin under a short sleeve.
const FOREARM: Spec = Spec {
    joint: Pair(LEFT_ELBOW),
    form: Form::RoundCone {
        a: Joint(Pair(LEFT_ELBOW)),
        b: Joint(Pair(LEFT_WRIST)),
        ra: Body(0.04),
        rb: Body(0.029),
    },
    blend: 0.02,
    material: Material::Top,
    label: label::ARMS,
};

/// A flared sleeve end on the upper arm.
const SHORT_SLEEVE: Spec = Spec {
    joint: Pair(LEFT_SHOULDER),
    form: Form::CappedCone {
        a: Along(Pair(LEFT_SHOULDER), 0.07),
        b: Along(Pair(LEFT_SHOULDER), 0.17),
        ra: Body(0.056),
        rb: Body(0.066),
    },
    blend: 0.01,
    material: Material::Top,
    label: label::ARMS,
};

// A loose cuff just before the wrist: `j - along * 0.08` is the same f32 as
// `j + along * -0.08`.
const CUFFED_SLEEVE: Spec = Spec {
    joint: Pair(LEFT_ELBOW),
    form: Form::CappedCone {
        a: Along(Pair(LEFT_WRIST), -0.08),
        b: Along(Pair(LEFT_WRIST), -0.015),
        ra: Body(0.036),
        rb: Body(0.052),
    },
    blend: 0.01,
    material: Material::Top,
    label: label::ARMS,
};

/// A wide three-quarter sleeve below the elbow.
const LOOSE_SLEEVE: Spec = Spec {
    joint: Pair(LEFT_ELBOW),
    form: Form::CappedCone {
        a: Along(Pair(LEFT_ELBOW), 0.01),
        b: Along(Pair(LEFT_ELBOW), 0.14),
        ra: Body(0.047),
        rb: Body(0.074),
    },
    blend: 0.01,
    material: Material::Top,
    label: label::ARMS,
};

/// The palm and the thenar (the thumb's ball), carried by the wrist.
const PALM: [Spec; 2] = [
    Spec {
        joint: Pair(LEFT_WRIST),
        form: Form::Ellipsoid {
            c: AlongHand(Pair(LEFT_WRIST), 0.052, [0.0, 0.0, -0.003]),
            r: [Hand(0.05), Hand(0.016), Hand(0.042)],
        },
        blend: 0.012,
        material: Material::Skin,
        label: label::HANDS,
    },
    Spec {
        joint: Pair(LEFT_WRIST),
        form: Form::RoundCone {
            a: HandOff(Pair(LEFT_WRIST), 0.015, [0.0, -0.004, 0.008]),
            b: Joint(Digit(12)),
            ra: Hand(0.017),
            rb: Hand(0.013),
        },
        blend: 0.01,
        material: Material::Skin,
        label: label::HANDS,
    },
];

/// One side's arm: upper arm, forearm, sleeve, palm, thenar, fingers and thumb.
pub(super) fn arm(b: &mut Builder, sleeve: Sleeve, side: usize) {
    b.add(&UPPER_ARM, side);
    let forearm = if sleeve == Sleeve::Short {
        Material::Skin
    } else {
        Material::Top
    };
    b.add(
        &Spec {
            material: forearm,
            ..FOREARM
        },
        side,
    );
    let sleeve = match sleeve {
        Sleeve::Short => &SHORT_SLEEVE,
        Sleeve::Cuffed => &CUFFED_SLEEVE,
        Sleeve::Loose => &LOOSE_SLEEVE,
    };
    b.add(sleeve, side);
    b.add_all(&PALM, side);
    let first = LEFT_HAND_FIRST + 15 * side;
    for (f, (_, _, radius)) in FINGERS.iter().enumerate() {
        finger(b, first, f, *radius);
    }
    finger(b, first, 4, THUMB.3);
}

/// Three tapering segments of digit `chain` (the thumb is 4), the last one reaching past
/// its joint to the tip; sizes come from the `FINGERS` and `THUMB` tables.
fn finger(b: &mut Builder, first: usize, chain: usize, radius: f32) {
    let h = b.hand();
    let joints = [
        first + 3 * chain,
        first + 3 * chain + 1,
        first + 3 * chain + 2,
    ];
    let j = joints.map(|k| b.joint(k));
    let tip = j[2] + (j[2] - j[1]) * 0.9;
    let ends = [j[1], j[2], tip];
    for k in 0..3 {
        let r0 = radius * 0.92f32.powi(k as i32) * h;
        b.push(
            joints[k],
            Shape::RoundCone {
                a: j[k],
                b: ends[k],
                ra: r0,
                rb: r0 * 0.92,
            },
            if k == 0 { 0.008 } else { 0.002 },
            Material::Skin,
            label::HANDS,
        );
    }
}
