//! The figure's shape language and its interpreter: a primitive written as a table row
//! (carrying joint, shape kind, anchor points as joints plus offsets, lengths scaled by
//! the body, head or hand factor, blend, material, label) and the [`Builder`] that turns
//! rows into one identity's [`Prim`]s, side by side.
//!
//! Each point and length form names the float expression it stands for, and the
//! interpreter evaluates exactly that expression (same operations, same order): the
//! synthetic dataset is byte-identical to the one the hand-written shapes produced, and
//! `a * b * c` is not `a * (b * c)` in f32.

use glam::Vec3;

use super::head_frame::HeadFrame;
use super::{Material, Prim, Proportions};
use crate::sdf::Shape;
use talkin_human::body::skeleton::joint::{HEAD, LEFT_HAND_FIRST};
use talkin_human::body::{N_JOINTS, Skeleton};

/// The joint a row refers to, resolved per side.
#[derive(Clone, Copy, Debug)]
pub(super) enum J {
    /// A joint on the midline, the same on both sides.
    Mid(usize),
    /// The left joint of a pair; on the right side the next one (SMPL-X numbers every
    /// body pair left, right).
    Pair(usize),
    /// The `k`-th joint of this side's hand (index, middle, pinky, ring, thumb; 3 each).
    Digit(usize),
}

/// A length in metres: as authored, or times one of the identity's factors.
#[derive(Clone, Copy, Debug)]
pub(super) enum Len {
    /// `m`.
    M(f32),
    /// `m * height` (the body factor).
    Body(f32),
    /// `m * head`.
    Head(f32),
    /// `m * hand`.
    Hand(f32),
    /// The chest's half-width, which follows the shoulders: `0.09 + shoulder * 0.45`.
    Chest,
}

/// A point in the carrying joint's rest space. `j` is the row's joint position on this
/// side, `along` the unit x vector pointing away from the body on this side.
#[derive(Clone, Copy, Debug)]
pub(super) enum At {
    /// `j`.
    Joint(J),
    /// `j + Vec3(off)`.
    Off(J, [f32; 3]),
    /// `j + along * k`.
    Along(J, f32),
    /// `Vec3(0, j.y + dy, z)`: on the body's axis at the joint's height (skirts, hems).
    Axis(J, Len, f32),
    /// `j + along * k * hand + Vec3(off)` (the palm's centre).
    AlongHand(J, f32, [f32; 3]),
    /// `j + (along * k + Vec3(off)) * hand` (the thenar's base).
    HandOff(J, f32, [f32; 3]),
    /// `head.p(sign * x, y, z)`: the head joint plus an offset times the head factor,
    /// mirrored in x on the right side (`sign` = -1).
    OnHead([f32; 3]),
}

/// The shape kinds of [`Shape`] that tables use, with their points and lengths unevaluated.
#[derive(Clone, Copy, Debug)]
pub(super) enum Form {
    RoundCone { a: At, b: At, ra: Len, rb: Len },
    CappedCone { a: At, b: At, ra: Len, rb: Len },
    Ellipsoid { c: At, r: [Len; 3] },
}

/// One table row: a primitive for any identity and either side.
#[derive(Clone, Copy, Debug)]
pub(super) struct Spec {
    pub joint: J,
    pub form: Form,
    pub blend: f32,
    pub material: Material,
    pub label: u8,
}

/// One identity's rest joints and factors, and the primitives added so far (their order
/// matters: the renderer smooth-unions them in order).
pub(super) struct Builder {
    joints: [Vec3; N_JOINTS],
    body: f32,
    hand: f32,
    chest: f32,
    pub head: HeadFrame,
    pub prims: Vec<Prim>,
}

impl Builder {
    pub fn new(skeleton: &Skeleton, prop: &Proportions) -> Self {
        Self {
            joints: skeleton.rest_joints.map(|x| x.as_vec3()),
            body: prop.height as f32,
            hand: prop.hand as f32,
            chest: 0.09 + prop.shoulder as f32 * 0.45,
            head: HeadFrame::new(skeleton.rest_joints[HEAD], prop.head),
            prims: Vec::with_capacity(96),
        }
    }

    /// Rest position of joint `j`.
    pub fn joint(&self, j: usize) -> Vec3 {
        self.joints[j]
    }

    /// The hand factor.
    pub fn hand(&self) -> f32 {
        self.hand
    }

    /// Adds a primitive built outside the tables.
    pub fn push(&mut self, joint: usize, shape: Shape, blend: f32, material: Material, label: u8) {
        self.prims.push(Prim {
            joint,
            shape,
            blend,
            material,
            label,
        });
    }

    /// Adds the row's primitive on `side` (0 = left, 1 = right; midline rows use 0).
    pub fn add(&mut self, spec: &Spec, side: usize) {
        let shape = match spec.form {
            Form::RoundCone { a, b, ra, rb } => Shape::RoundCone {
                a: self.at(a, side),
                b: self.at(b, side),
                ra: self.len(ra),
                rb: self.len(rb),
            },
            Form::CappedCone { a, b, ra, rb } => Shape::CappedCone {
                a: self.at(a, side),
                b: self.at(b, side),
                ra: self.len(ra),
                rb: self.len(rb),
            },
            Form::Ellipsoid { c, r } => Shape::Ellipsoid {
                c: self.at(c, side),
                r: Vec3::new(self.len(r[0]), self.len(r[1]), self.len(r[2])),
            },
        };
        let joint = self.index(spec.joint, side);
        self.push(joint, shape, spec.blend, spec.material, spec.label);
    }

    /// Adds every row of `specs` on `side`, in order.
    pub fn add_all(&mut self, specs: &[Spec], side: usize) {
        for spec in specs {
            self.add(spec, side);
        }
    }

    fn index(&self, j: J, side: usize) -> usize {
        match j {
            J::Mid(j) => j,
            J::Pair(left) => left + side,
            J::Digit(k) => LEFT_HAND_FIRST + 15 * side + k,
        }
    }

    fn len(&self, l: Len) -> f32 {
        match l {
            Len::M(m) => m,
            Len::Body(m) => m * self.body,
            Len::Head(m) => m * self.head.k,
            Len::Hand(m) => m * self.hand,
            Len::Chest => self.chest,
        }
    }

    fn at(&self, at: At, side: usize) -> Vec3 {
        let sign: f32 = if side == 0 { 1.0 } else { -1.0 };
        let along = Vec3::X * sign;
        let j = |j: J| self.joints[self.index(j, side)];
        match at {
            At::Joint(a) => j(a),
            At::Off(a, off) => j(a) + Vec3::from(off),
            At::Along(a, k) => j(a) + along * k,
            At::Axis(a, dy, z) => Vec3::new(0.0, j(a).y + self.len(dy), z),
            At::AlongHand(a, k, off) => j(a) + along * k * self.hand + Vec3::from(off),
            At::HandOff(a, k, off) => j(a) + (along * k + Vec3::from(off)) * self.hand,
            At::OnHead([x, y, z]) => self.head.p(sign * x, y, z),
        }
    }
}
