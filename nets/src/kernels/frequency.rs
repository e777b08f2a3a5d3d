//! The frequency encoding as one fused op on the CPU backend (Flex, with or without
//! autodiff).
//!
//! Composed of tensor ops, the encoding evaluates `sin` and `cos` of every band in forward
//! and both again in backward (the derivative of each is the other), ~4% of a training
//! step in `sinf`/`cosf` (perf, `fast` preset, D_nr and D_hands). Fused, forward takes one
//! `sin_cos` per coordinate in f64 and doubles the angle band by band
//! (`sin 2a = 2 sin a cos a`, `cos 2a = cos^2 a - sin^2 a`; f64 keeps the six doublings
//! below f32 rounding), and backward needs no trigonometry at all: the derivative of the
//! windowed `w sin(2^k x)` is `2^k` times the windowed cosine the output already holds.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use rayon::prelude::*;

use super::flex_data::{f32_data, flex_tensor};
use crate::profile::{self, Work};

/// Rows per parallel task.
const CHUNK: usize = 512;

/// `[n, d (1 + 2 L)]`: per row `[x, w_k sin(2^k x) (band-major), w_k cos(2^k x)
/// (band-major)]` for the `[n, d]` row-major `x` and band weights `window` (`L` of them).
fn forward_rows(x: &[f32], d: usize, window: &[f32]) -> Vec<f32> {
    let (values, l) = (x.len() as f64, window.len() as f64);
    let work = Work {
        flops: values * (20.0 + 8.0 * l),
        bytes: 4.0 * values * (2.0 + 2.0 * l),
        gathered: 0.0,
    };
    profile::timed_work("kernel: frequency forward", work, || {
        forward_bands(x, d, window)
    })
}

fn forward_bands(x: &[f32], d: usize, window: &[f32]) -> Vec<f32> {
    let l = window.len();
    let width = d * (1 + 2 * l);
    let n = x.len() / d;
    let mut out = vec![0f32; n * width];
    out.par_chunks_mut(CHUNK * width)
        .zip(x.par_chunks(CHUNK * d))
        .for_each(|(out, x)| {
            for (row, x) in out.chunks_exact_mut(width).zip(x.chunks_exact(d)) {
                let (raw, bands) = row.split_at_mut(d);
                let (sin, cos) = bands.split_at_mut(l * d);
                raw.copy_from_slice(x);
                for (a, &xa) in x.iter().enumerate() {
                    let (mut s, mut c) = (xa as f64).sin_cos();
                    for (k, &w) in window.iter().enumerate() {
                        sin[k * d + a] = w * s as f32;
                        cos[k * d + a] = w * c as f32;
                        (s, c) = (2.0 * s * c, (c - s) * (c + s));
                    }
                }
            }
        });
    out
}

/// `[n, d]`: the input's gradient for the output gradient `grad` `[n, d (1 + 2 L)]`,
/// from the forward output `out` (same shape).
fn input_grad(grad: &[f32], out: &[f32], d: usize, l: usize) -> Vec<f32> {
    let width = d * (1 + 2 * l);
    let n = grad.len() / width;
    let mut dx = vec![0f32; n * d];
    dx.par_chunks_mut(CHUNK * d)
        .zip(grad.par_chunks(CHUNK * width))
        .zip(out.par_chunks(CHUNK * width))
        .for_each(|((dx, grad), out)| {
            for ((dx, g), o) in dx
                .chunks_exact_mut(d)
                .zip(grad.chunks_exact(width))
                .zip(out.chunks_exact(width))
            {
                for a in 0..d {
                    let mut sum = g[a];
                    let mut f = 1.0f32;
                    for k in 0..l {
                        let (i_sin, i_cos) = (d + k * d + a, d + (l + k) * d + a);
                        sum += f * (g[i_sin] * o[i_cos] - g[i_cos] * o[i_sin]);
                        f *= 2.0;
                    }
                    dx[a] = sum;
                }
            }
        });
    dx
}

#[derive(Debug)]
struct FrequencyBackward;

impl Backward<Flex, 1> for FrequencyBackward {
    /// The forward output (sharing its buffer), the input's shape and the band count.
    type State = (FlexTensor, [usize; 2], usize);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let Some(node) = x_node else {
            return;
        };
        let (out, [n, d], l) = ops.state;
        let grad = f32_data(&grad).expect("the encoding's gradient is f32 like its output");
        let out = f32_data(&out).expect("the forward output is f32");
        let values = (n * d) as f64;
        let work = Work {
            flops: values * (1.0 + 6.0 * l as f64),
            bytes: 4.0 * values * (2.0 + 4.0 * l as f64),
            gathered: 0.0,
        };
        let dx = profile::timed_work("kernel: frequency backward", work, || {
            input_grad(&grad, &out, d, l)
        });
        grads.register::<Flex>(node.id, flex_tensor(dx, [n, d]));
    }
}

/// The encoding of `x` `[n, d]` (`d > 0`) with band weights `window` as one op, when `x`
/// lives on Flex (with or without autodiff) as f32; `None` otherwise (the caller composes
/// tensor ops).
pub(crate) fn encode(x: &Tensor<2>, window: &[f32]) -> Option<Tensor<2>> {
    let [n, d] = x.dims();
    if d == 0 {
        return None; // nothing to encode; the composed ops handle the empty shape
    }
    let l = window.len();
    let width = d * (1 + 2 * l);
    if let Ok(x) = x.clone().try_into_primitive::<Autodiff<Flex>>() {
        let node = x.node();
        let x = x.into_primitive();
        let out = forward_rows(&f32_data(&x)?, d, window);
        let tensor = flex_tensor(out, [n, width]);
        let tensor = match FrequencyBackward
            .prepare::<NoCheckpointing>([node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((tensor.clone(), [n, d], l), tensor),
            OpsKind::UnTracked(prep) => prep.finish(tensor),
        };
        return Some(Tensor::from_primitive::<Autodiff<Flex>>(tensor));
    }
    let x = x.clone().try_into_primitive::<Flex>().ok()?;
    let out = forward_rows(&f32_data(&x)?, d, window);
    Some(Tensor::from_primitive::<Flex>(flex_tensor(out, [n, width])))
}
