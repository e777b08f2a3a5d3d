//! Routed rows' kernels: one unit per element of the batch's `[n, c]` tensor, never a loop.
//!
//! `slot[i]` is the part's row of sample `i` (`h`, the part's row count, for a sample
//! that is not a candidate); a candidate is routed when its label is the part's.

use cubecl::prelude::*;

/// `out[i] = values[slot[i]]` for a routed sample, `base[i]` otherwise.
#[cube(launch)]
pub(crate) fn replace_kernel<I: Int>(
    base: &Tensor<f32>,
    values: &Tensor<f32>,
    slot: &Tensor<I>,
    labels: &Tensor<I>,
    out: &mut Tensor<f32>,
    label: i32,
    #[define(I)] _dtype: ElemType,
) {
    let pos = ABSOLUTE_POS;
    if pos >= out.len() {
        terminate!();
    }
    let columns = base.shape(1);
    let (i, c) = (pos / columns, pos % columns);
    let k = usize::cast_from(slot[i]);
    let mut v = base[pos];
    if k < values.shape(0) && i32::cast_from(labels[i]) == label {
        v = values[k * columns + c];
    }
    out[pos] = v;
}

/// The output's gradient to the base's (0 on routed samples) and the part's rows' (0 on
/// a candidate the label turned away). Every part row is one sample's slot, so each of
/// its elements is written exactly once.
#[cube(launch)]
pub(crate) fn replace_backward_kernel<I: Int>(
    grad: &Tensor<f32>,
    slot: &Tensor<I>,
    labels: &Tensor<I>,
    grad_base: &mut Tensor<f32>,
    grad_values: &mut Tensor<f32>,
    label: i32,
    #[define(I)] _dtype: ElemType,
) {
    let pos = ABSOLUTE_POS;
    if pos >= grad.len() {
        terminate!();
    }
    let columns = grad.shape(1);
    let (i, c) = (pos / columns, pos % columns);
    let k = usize::cast_from(slot[i]);
    let g = grad[pos];
    let candidate = k < grad_values.shape(0);
    let routed = candidate && i32::cast_from(labels[i]) == label;
    grad_base[pos] = select(routed, 0.0f32, g);
    if candidate {
        grad_values[k * columns + c] = select(routed, g, 0.0f32);
    }
}
