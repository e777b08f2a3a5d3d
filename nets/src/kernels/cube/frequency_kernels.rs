//! The frequency encoding's kernels: one unit per (point, coordinate), never a loop over
//! the batch. A row of the output is `[x, w_k sin(2^k x) (band-major), w_k cos(2^k x)
//! (band-major)]`, `d (1 + 2 L)` wide.

use cubecl::prelude::*;

/// The encoding of `x` `[n, d]` with band weights `window` `[L]`.
#[cube(launch)]
pub(crate) fn frequency_kernel(x: &Tensor<f32>, window: &Tensor<f32>, out: &mut Tensor<f32>) {
    let pos = ABSOLUTE_POS;
    if pos >= x.len() {
        terminate!();
    }
    let d = x.shape(1);
    let bands = window.shape(0);
    let (i, a) = (pos / d, pos % d);
    let row = i * d * (1 + 2 * bands);
    let v = x[pos];
    out[row + a] = v;
    let mut frequency = 1.0f32;
    for k in 0..bands {
        let angle = v * frequency;
        let w = window[k];
        out[row + d + k * d + a] = f32::sin(angle) * w;
        out[row + d + (bands + k) * d + a] = f32::cos(angle) * w;
        frequency *= 2.0;
    }
}

/// The input's gradient `[n, d]` for the output's `grad`, from the forward output `out`:
/// the derivative of `w sin(2^k x)` is `2^k` times the windowed cosine `out` holds (and
/// of the cosine minus `2^k` times the sine), so no trigonometry.
#[cube(launch)]
pub(crate) fn frequency_backward_kernel(
    grad: &Tensor<f32>,
    out: &Tensor<f32>,
    grad_x: &mut Tensor<f32>,
) {
    let pos = ABSOLUTE_POS;
    if pos >= grad_x.len() {
        terminate!();
    }
    let d = grad_x.shape(1);
    let bands = (out.shape(1) / d - 1) / 2;
    let (i, a) = (pos / d, pos % d);
    let row = i * out.shape(1);
    let mut sum = grad[row + a];
    let mut frequency = 1.0f32;
    for k in 0..bands {
        let (i_sin, i_cos) = (row + d + k * d + a, row + d + (bands + k) * d + a);
        sum += frequency * (grad[i_sin] * out[i_cos] - grad[i_cos] * out[i_sin]);
        frequency *= 2.0;
    }
    grad_x[pos] = sum;
}
