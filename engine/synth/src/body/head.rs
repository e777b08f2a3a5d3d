//! The head: its layout (offsets from the head joint, scaled by the head factor), the
//! parts that follow the expression coefficients and the jaw (cheeks, lids, brows, lips,
//! the painted mouth's state) and the hair. Static parts are table rows; see the crate
//! docs for what each coefficient does.

use glam::Vec3;

use super::head_frame::HeadFrame;
use super::shapes::At::OnHead;
use super::shapes::J::Mid;
use super::shapes::Len::Head;
use super::shapes::{Builder, Form, Spec};
use super::{FaceState, HairStyle, Material, label};
use crate::sdf::Shape;
use talkin_human::body::N_EXPRESSION;
use talkin_human::body::skeleton::joint::{HEAD, JAW, LEFT_EYE, RIGHT_EYE};

const JAW_ROW: Spec = Spec {
    joint: Mid(JAW),
    form: Form::Ellipsoid {
        c: OnHead([0.0, 0.012, 0.056]),
        r: [Head(0.046), Head(0.03), Head(0.04)],
    },
    blend: 0.022,
    material: Material::Face,
    label: label::HEAD,
};

/// Per side (x mirrored), carried by the head.
const EAR: Spec = Spec {
    joint: Mid(HEAD),
    form: Form::Ellipsoid {
        c: OnHead([0.077, HeadFrame::EYE_Y - 0.012, 0.002]),
        r: [Head(0.011), Head(0.026), Head(0.016)],
    },
    blend: 0.006,
    material: Material::Face,
    label: label::HEAD,
};

const C: Vec3 = HeadFrame::CENTRE;

/// A bun on the crown: a bump on the silhouette.
const BUN: Spec = Spec {
    joint: Mid(HEAD),
    form: Form::Ellipsoid {
        c: OnHead([0.0, C.y + 0.095, C.z - 0.072]),
        r: [Head(0.05), Head(0.047), Head(0.05)],
    },
    blend: 0.02,
    material: Material::Hair,
    label: label::HEAD,
};

/// A side ponytail hanging behind the left ear, beside the neck.
const PONYTAIL: Spec = Spec {
    joint: Mid(HEAD),
    form: Form::RoundCone {
        a: OnHead([0.045, C.y + 0.01, C.z - 0.08]),
        b: OnHead([0.095, C.y - 0.18, C.z - 0.13]),
        ra: Head(0.036),
        rb: Head(0.02),
    },
    blend: 0.02,
    material: Material::Hair,
    label: label::HEAD,
};

/// Skull, jaw, nose, ears and cheeks: smile (0) raises the cheeks, puff (6) grows them.
pub(super) fn face(b: &mut Builder, e: &[f32; N_EXPRESSION]) {
    let head = b.head;
    let hk = head.k;
    let skull = Shape::Ellipsoid {
        c: head.p(0.0, 0.0, 0.0) + HeadFrame::CENTRE * hk,
        r: HeadFrame::RADII * hk,
    };
    b.push(HEAD, skull, 0.03, Material::Face, label::HEAD);
    b.add(&JAW_ROW, 0);
    let eye_y = HeadFrame::EYE_Y;
    let nose = Shape::RoundCone {
        a: head.p(0.0, eye_y - 0.006, HeadFrame::front(0.0, eye_y) - 0.006),
        b: head.p(
            0.0,
            eye_y - 0.036,
            HeadFrame::front(0.0, eye_y - 0.036) + 0.016,
        ),
        ra: 0.006 * hk,
        rb: 0.0105 * hk,
    };
    b.push(HEAD, nose, 0.012, Material::Face, label::HEAD);
    for (side, sign) in [(0, 1.0f32), (1, -1.0)] {
        b.add(&EAR, side);
        let cy = HeadFrame::MOUTH_Y + 0.022 + 0.004 * e[0];
        let cx = sign * 0.042;
        let grow = (1.0 + 0.2 * e[6] + 0.06 * e[0]).clamp(0.6, 1.6);
        let cheek = Shape::Ellipsoid {
            c: head.p(cx, cy, HeadFrame::front(cx, cy) - 0.017),
            r: Vec3::new(0.02, 0.017, 0.015) * hk * grow,
        };
        b.push(HEAD, cheek, 0.014, Material::Face, label::HEAD);
    }
}

/// Eyeballs, lids (blink/squint 3) and brows (raise 1, furrow 2, asymmetry 9).
pub(super) fn eyes(b: &mut Builder, e: &[f32; N_EXPRESSION]) {
    let hk = b.head.k;
    let open = (1.0 - 0.45 * e[3]).clamp(0.0, 1.25);
    for (eye, sign) in [(LEFT_EYE, 1.0f32), (RIGHT_EYE, -1.0)] {
        let c = b.joint(eye);
        let r = HeadFrame::EYE_R * hk;
        let ball = Shape::Ellipsoid {
            c,
            r: Vec3::splat(r),
        };
        b.push(eye, ball, 0.0, Material::Eye, label::HEAD);
        lids(b, c, r, open);
        brow(b, sign, e);
    }
}

/// The upper and lower lid of the eye at `c` with radius `r`, the upper one lowered as
/// `open` goes from 1 (open) to 0 (closed).
fn lids(b: &mut Builder, c: Vec3, r: f32, open: f32) {
    let lid_r = Vec3::splat(r * 1.1);
    let upper = c.y + (-0.95 + 1.75 * open.min(1.0) + 0.2 * (open - 1.0).max(0.0)) * r;
    let lower = c.y - 0.72 * r;
    let upper_lid = Shape::CutEllipsoid {
        c,
        r: lid_r,
        n: Vec3::NEG_Y,
        d: -upper,
    };
    let material = Material::Lid {
        edge_y: upper,
        up: true,
    };
    b.push(HEAD, upper_lid, 0.0, material, label::HEAD);
    let lower_lid = Shape::CutEllipsoid {
        c,
        r: lid_r,
        n: Vec3::Y,
        d: lower,
    };
    let material = Material::Lid {
        edge_y: lower,
        up: false,
    };
    b.push(HEAD, lower_lid, 0.0, material, label::HEAD);
}

/// The brow above the eye on side `sign`, lying on the head's front surface.
fn brow(b: &mut Builder, sign: f32, e: &[f32; N_EXPRESSION]) {
    let head = b.head;
    let eye_y = HeadFrame::EYE_Y;
    let raise = 0.008 * e[1] + 0.005 * sign * e[9];
    let inner_x = sign * (0.013 - 0.003 * e[2].max(0.0));
    let inner_y = eye_y + 0.027 + raise - 0.005 * e[2];
    let outer_x = sign * 0.048;
    let outer_y = eye_y + 0.025 + raise * 0.8;
    let on_face = |x: f32, y: f32| head.p(x, y, HeadFrame::front(x, y) + 0.0005);
    let shape = Shape::RoundCone {
        a: on_face(inner_x, inner_y),
        b: on_face(outer_x, outer_y),
        ra: 0.0048 * head.k,
        rb: 0.0036 * head.k,
    };
    b.push(HEAD, shape, 0.0, Material::Brow, label::HEAD);
}

/// Lips and the painted opening: smile (0) and smirk (7) lift the corners, width (4) and
/// pucker (5) move them, upper-lip raise (8); the lower lip rides on the jaw, which
/// opens with `jaw_x > 0`.
pub(super) fn mouth(b: &mut Builder, e: &[f32; N_EXPRESSION], jaw_x: f64) -> FaceState {
    let head = b.head;
    let jaw_open = (jaw_x as f32).clamp(-0.1, 0.8);
    let mouth_y = HeadFrame::MOUTH_Y;
    let half_w = (0.024 * (1.0 + 0.16 * e[4] - 0.2 * e[5].max(0.0))).clamp(0.012, 0.036);
    let pucker = 0.006 * e[5].max(0.0);
    let mz = |x: f32, y: f32| HeadFrame::front(x, y) + pucker;
    let corner_y = |sign: f32| mouth_y + 0.006 * e[0] + 0.005 * sign * e[7];
    let upper_mid = mouth_y + 0.0045 + 0.003 * e[8];
    let lower_mid = mouth_y - 0.0055;
    let lip_r = 0.0052 * head.k;
    for sign in [1.0f32, -1.0] {
        let cx = sign * half_w;
        let corner = head.p(cx, corner_y(sign), mz(cx, corner_y(sign)) - 0.004);
        let upper = Shape::RoundCone {
            a: corner,
            b: head.p(0.0, upper_mid, mz(0.0, upper_mid) + 0.002),
            ra: lip_r * 0.7,
            rb: lip_r,
        };
        b.push(HEAD, upper, 0.004, Material::Lip, label::HEAD);
        let lower = Shape::RoundCone {
            a: corner,
            b: head.p(0.0, lower_mid, mz(0.0, lower_mid) + 0.001),
            ra: lip_r * 0.7,
            rb: lip_r * 1.15,
        };
        b.push(JAW, lower, 0.004, Material::Lip, label::HEAD);
    }
    FaceState {
        mouth_open: 0.1 * jaw_open.max(0.0).sin() + 0.002 * e[8].max(0.0),
        mouth_half_width: half_w,
        mouth_y,
        mouth_z: mz(0.0, mouth_y),
    }
}

/// A cap cut off above the face, plus a bun or a ponytail.
pub(super) fn hair(b: &mut Builder, style: HairStyle) {
    let head = b.head;
    let n = Vec3::new(0.0, -0.25, 1.0).normalize();
    let cut_at = head.p(0.0, C.y + 0.05, C.z + 0.03);
    let cap = Shape::CutEllipsoid {
        c: head.p(C.x, C.y + 0.008, C.z - 0.008),
        r: (HeadFrame::RADII + Vec3::new(0.011, 0.01, 0.01)) * head.k,
        n,
        d: n.dot(cut_at),
    };
    b.push(HEAD, cap, 0.0, Material::Hair, label::HEAD);
    let style = match style {
        HairStyle::Bun => &BUN,
        HairStyle::Ponytail => &PONYTAIL,
    };
    b.add(style, 0);
}
