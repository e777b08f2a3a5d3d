//! Volume rendering's per-ray sums: forward one unit per ray and column walks that ray's
//! samples in order (a few dozen, never the batch); backward one unit per sample.
//!
//! `values` has a row per sample, or one row that every sample shares (`rows == 1`).

use cubecl::prelude::*;

/// `out[r, c] = sum_{i in ray r} weights[i] * values[i, c]`, in sample order from 0
/// (the CPU's order); 0 for a ray without samples.
#[cube(launch)]
pub(crate) fn ray_sums_kernel<I: Int>(
    weights: &Tensor<f32>,
    values: &Tensor<f32>,
    offsets: &Tensor<I>,
    out: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let pos = ABSOLUTE_POS;
    if pos >= out.len() {
        terminate!();
    }
    let columns = values.shape(1);
    let (r, c) = (pos / columns, pos % columns);
    let shared = values.shape(0) == 1;
    let start = usize::cast_from(offsets[r]);
    let end = usize::cast_from(offsets[r + 1]);
    let mut sum = 0.0f32;
    for i in start..end {
        let row = select(shared, 0, i);
        sum += weights[i] * values[row * columns + c];
    }
    out[pos] = sum;
}

/// For the sums' gradient `grad` `[r, c]`: `grad_values[i, c] = weights[i] g[ray_i, c]`
/// (per sample, also for a shared row: the caller sums those) and
/// `grad_weights[i] = sum_c values[i, c] g[ray_i, c]`.
#[cube(launch)]
pub(crate) fn ray_sums_backward_kernel<I: Int>(
    weights: &Tensor<f32>,
    values: &Tensor<f32>,
    ray: &Tensor<I>,
    grad: &Tensor<f32>,
    grad_weights: &mut Tensor<f32>,
    grad_values: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i >= weights.len() {
        terminate!();
    }
    let columns = values.shape(1);
    let row = select(values.shape(0) == 1, 0, i);
    let r = usize::cast_from(ray[i]);
    let w = weights[i];
    let mut gw = 0.0f32;
    for c in 0..columns {
        let g = grad[r * columns + c];
        grad_values[i * columns + c] = w * g;
        gw += values[row * columns + c] * g;
    }
    grad_weights[i] = gw;
}
