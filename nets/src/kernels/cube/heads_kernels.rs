//! A net output's columns through their activation: forward one unit per element taken,
//! backward one unit per element of the whole output (zero outside the columns).
//!
//! `activation`: 0 none, 1 softplus `max(x, 0) + ln(1 + exp(-|x|))`, 2 sigmoid in burn's
//! form `exp(-ln(1 + exp(-x)))`.

use cubecl::prelude::*;

/// Softplus as `util::softplus` composes it.
#[cube]
fn softplus(x: f32) -> f32 {
    f32::max(x, 0.0) + f32::log1p(f32::exp(-f32::abs(x)))
}

/// The logistic function as burn composes it.
#[cube]
fn sigmoid(x: f32) -> f32 {
    f32::exp(-f32::log1p(f32::exp(-x)))
}

/// `out[i, j] = act(raw[i, start + j])` for the `count = out.shape(1)` columns.
#[cube(launch)]
pub(crate) fn heads_kernel(raw: &Tensor<f32>, out: &mut Tensor<f32>, start: u32, activation: u32) {
    let pos = ABSOLUTE_POS;
    if pos >= out.len() {
        terminate!();
    }
    let count = out.shape(1);
    let (i, j) = (pos / count, pos % count);
    let x = raw[i * raw.shape(1) + start as usize + j];
    let mut y = x;
    if activation == 1 {
        y = softplus(x);
    } else if activation == 2 {
        y = sigmoid(x);
    }
    out[pos] = y;
}

/// The whole output's gradient `[n, k]`: `grad` times the activation's slope in the
/// columns taken, 0 elsewhere. Softplus's slope is the logistic function, in the form
/// that never overflows; the sigmoid's `s (1 - s)`, burn's.
#[cube(launch)]
pub(crate) fn heads_backward_kernel(
    raw: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_raw: &mut Tensor<f32>,
    start: u32,
    activation: u32,
) {
    let pos = ABSOLUTE_POS;
    if pos >= grad_raw.len() {
        terminate!();
    }
    let k = raw.shape(1);
    let count = grad.shape(1);
    let (i, c) = (pos / k, pos % k);
    let first = start as usize;
    let mut g = 0.0f32;
    if c >= first && c < first + count {
        g = grad[i * count + c - first];
        let x = raw[pos];
        if activation == 1 {
            // The composed ops' slope: `[x >= 0] - sign(x) e / (1 + e)`, `e = exp(-|x|)`;
            // the logistic function but at exactly 0, where it is 1 (the CPU's too).
            let e = f32::exp(-f32::abs(x));
            let tail = e / (1.0 + e);
            let mut slope = tail;
            if x > 0.0 {
                slope = 1.0 - tail;
            } else if x == 0.0 {
                slope = 1.0;
            }
            g *= slope;
        } else if activation == 2 {
            let s = sigmoid(x);
            g *= s * (1.0 - s);
        }
    }
    grad_raw[pos] = g;
}
