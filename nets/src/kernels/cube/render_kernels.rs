//! Volume rendering's per-ray kernels: one unit per ray walks that ray's samples (a few
//! dozen), never the batch. Forward gives each sample's weight `T_i alpha_i` and each
//! ray's final transmittance; backward each sample's optical-depth gradient.

use cubecl::prelude::*;

/// `alpha = 1 - exp(-tau)`, by its Taylor series below `small` (no cancellation).
#[cube]
fn alpha(tau: f32, small: f32) -> f32 {
    let mut a = 1.0 - f32::exp(-tau);
    if tau < small {
        a = tau * (1.0 - (0.5 - tau / 6.0) * tau);
    }
    a
}

/// `d alpha / d tau`, of the same branch.
#[cube]
fn alpha_slope(tau: f32, small: f32) -> f32 {
    let mut d = f32::exp(-tau);
    if tau < small {
        d = 1.0 - tau + 0.5 * tau * tau;
    }
    d
}

/// `weights[i] = exp(-sum_{j<i} tau_j) alpha(tau_i)` within each ray, and
/// `t_end[r] = exp(-sum tau)` (1 for a ray without samples).
#[cube(launch)]
pub(crate) fn weights_kernel<I: Int>(
    tau: &Tensor<f32>,
    offsets: &Tensor<I>,
    weights: &mut Tensor<f32>,
    t_end: &mut Tensor<f32>,
    small: f32,
    #[define(I)] _dtype: ElemType,
) {
    let r = ABSOLUTE_POS;
    if r >= t_end.shape(0) {
        terminate!();
    }
    let start = usize::cast_from(offsets[r]);
    let end = usize::cast_from(offsets[r + 1]);
    let mut depth = 0.0f32;
    for i in start..end {
        let t = tau[i];
        weights[i] = f32::exp(-depth) * alpha(t, small);
        depth += t;
    }
    t_end[r] = f32::exp(-depth);
}

/// `d L / d tau_i = g_i T_i alpha'(tau_i) - sum_{k>i} g_k w_k - g_end T_end`, `g` the
/// weights' gradient and `g_end` the final transmittance's. The forward transmittances
/// go into `grad_tau` first (a forward walk) and are read back in a reverse walk that
/// carries the suffix sum: no depth is ever recovered by subtraction.
#[cube(launch)]
pub(crate) fn weights_backward_kernel<I: Int>(
    tau: &Tensor<f32>,
    offsets: &Tensor<I>,
    weights: &Tensor<f32>,
    t_end: &Tensor<f32>,
    grad_weights: &Tensor<f32>,
    grad_t_end: &Tensor<f32>,
    grad_tau: &mut Tensor<f32>,
    small: f32,
    #[define(I)] _dtype: ElemType,
) {
    let r = ABSOLUTE_POS;
    if r >= t_end.shape(0) {
        terminate!();
    }
    let start = usize::cast_from(offsets[r]);
    let end = usize::cast_from(offsets[r + 1]);
    let mut depth = 0.0f32;
    for i in start..end {
        grad_tau[i] = f32::exp(-depth);
        depth += tau[i];
    }
    let mut suffix = grad_t_end[r] * t_end[r];
    for j in 0..end - start {
        let i = end - 1 - j;
        let g = grad_weights[i];
        let before = grad_tau[i];
        grad_tau[i] = g * before * alpha_slope(tau[i], small) - suffix;
        suffix += g * weights[i];
    }
}
