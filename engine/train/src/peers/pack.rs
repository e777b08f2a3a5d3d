//! A step's gradients, pose gradients, loss and shared values as one flat `f32` buffer, in
//! the field's parameter order, and back: what the peers all-reduce.
//!
//! Each parameter takes a presence slot and its values. A peer whose rays never reached a
//! parameter (a hand net, say) has no gradient for it and writes 0 there; after the sum
//! the parameter has a gradient when any peer had one, as in the single process whose
//! batch is the peers' union (Adam skips a parameter without a gradient but moves one
//! with a zero gradient by its momentum, so "absent" is not "zero").

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use talkin_nets::field::leaves::zero_grads;
use talkin_nets::{PoseGrads, TalkinField};

/// The slots after the gradients.
pub(crate) const LOSS: usize = 0;
pub(crate) const MSE: usize = 1;
/// Peer 0's training clock (the others write 0).
pub(crate) const CLOCK: usize = 2;
/// Values every peer must hold alike (each writes its own; the sum is `size` times it).
pub(crate) const AGREE: usize = 3;
pub(crate) const N_AGREE: usize = 2;
/// 1 from each peer asked to stop (a signal): the run stops after this step on every
/// peer when any was asked.
pub(crate) const STOP: usize = AGREE + N_AGREE;
const N_TAIL: usize = STOP + 1;

/// Where each part of the buffer lies, for one field and pose size.
#[derive(Clone, Debug)]
pub(crate) struct Layout {
    /// Gradient slots: a presence flag and the values of every parameter.
    pub grads: usize,
    /// Pose-gradient slots (0 without pose refinement).
    pub pose: usize,
    pose_dim: usize,
}

impl Layout {
    pub fn new(field: &TalkinField, pose: bool) -> Layout {
        struct Count(usize);
        impl ModuleVisitor for Count {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                self.0 += 1 + param.val().shape().num_elements();
            }
        }
        let mut count = Count(0);
        field.visit(&mut count);
        let pose_dim = field.pose_dim();
        Layout {
            grads: count.0,
            pose: if pose {
                flat_pose(&zero_grads(pose_dim), &zero_grads(pose_dim)).len()
            } else {
                0
            },
            pose_dim,
        }
    }

    pub fn len(&self) -> usize {
        self.grads + self.pose + N_TAIL
    }

    /// The tail's slots (loss, MSE, clock, agreement).
    pub fn tail(&self) -> std::ops::Range<usize> {
        self.grads + self.pose..self.len()
    }

    /// Writes `grads` and `pose` into `buf` (length [`Layout::len`]); the tail is the
    /// caller's.
    pub fn pack(
        &self,
        field: &TalkinField,
        grads: &GradientsParams,
        pose: Option<&PoseGrads>,
        buf: &mut [f32],
    ) {
        struct Pack<'a> {
            grads: &'a GradientsParams,
            buf: &'a mut [f32],
            at: usize,
        }
        impl ModuleVisitor for Pack<'_> {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let n = param.val().shape().num_elements();
                let slot = &mut self.buf[self.at..self.at + 1 + n];
                match self.grads.get::<D>(param.id) {
                    Some(g) => {
                        let values = g.try_to_vec_as::<f32>().unwrap_or_default();
                        slot[0] = 1.0;
                        if values.len() == n {
                            slot[1..].copy_from_slice(&values);
                        } else {
                            slot[1..].fill(f32::NAN);
                        }
                    }
                    None => slot.fill(0.0),
                }
                self.at += 1 + n;
            }
        }
        let mut pack = Pack {
            grads,
            buf: &mut buf[..self.grads],
            at: 0,
        };
        field.visit(&mut pack);
        if self.pose > 0 {
            let template = zero_grads(self.pose_dim);
            let flat = flat_pose(pose.unwrap_or(&template), &template);
            buf[self.grads..self.grads + self.pose].copy_from_slice(&flat);
        }
    }

    /// The gradients and pose gradients `buf` holds (summed over the peers).
    pub fn unpack(&self, field: &TalkinField, buf: &[f32]) -> (GradientsParams, Option<PoseGrads>) {
        struct Unpack<'a> {
            buf: &'a [f32],
            at: usize,
            grads: GradientsParams,
        }
        impl ModuleVisitor for Unpack<'_> {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let val = param.val();
                let shape = val.shape();
                let n = shape.num_elements();
                let slot = &self.buf[self.at..self.at + 1 + n];
                if slot[0] > 0.0 {
                    let device = val.device().inner();
                    let g =
                        Tensor::<D>::from_data(TensorData::new(slot[1..].to_vec(), shape), &device);
                    self.grads.register::<D>(param.id, g);
                }
                self.at += 1 + n;
            }
        }
        let mut unpack = Unpack {
            buf: &buf[..self.grads],
            at: 0,
            grads: GradientsParams::new(),
        };
        field.visit(&mut unpack);
        let pose = (self.pose > 0).then(|| {
            let mut p = zero_grads(self.pose_dim);
            unflat_pose(&buf[self.grads..self.grads + self.pose], &mut p);
            p
        });
        (unpack.grads, pose)
    }
}

/// A pose gradient's values in one order, each part at `template`'s size (a part a peer
/// left empty is zeros).
fn flat_pose(p: &PoseGrads, template: &PoseGrads) -> Vec<f32> {
    fn sized(v: &mut Vec<f32>, part: &[f32], n: usize) {
        v.extend((0..n).map(|i| part.get(i).copied().unwrap_or(0.0)));
    }
    let mut v = Vec::new();
    let rows: Vec<f32> = p.canonical_from_posed.iter().flatten().copied().collect();
    let n_rows = template.canonical_from_posed.len() * talkin_nets::field::leaves::TRANSFORM_ROWS;
    sized(&mut v, &rows, n_rows);
    for (part, t) in [
        (&p.body_pose, &template.body_pose),
        (&p.expression, &template.expression),
        (&p.jaw, &template.jaw),
        (&p.hand_pose, &template.hand_pose),
    ] {
        sized(&mut v, part, t.len());
    }
    v
}

/// The inverse of [`flat_pose`] into `p` (sized as the template it was flattened from).
fn unflat_pose(v: &[f32], p: &mut PoseGrads) {
    let mut it = v.iter().copied();
    for row in &mut p.canonical_from_posed {
        row.iter_mut().for_each(|x| *x = it.next().unwrap_or(0.0));
    }
    for part in [
        &mut p.body_pose,
        &mut p.expression,
        &mut p.jaw,
        &mut p.hand_pose,
    ] {
        part.iter_mut().for_each(|x| *x = it.next().unwrap_or(0.0));
    }
}
