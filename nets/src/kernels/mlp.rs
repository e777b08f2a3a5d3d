//! A small MLP without skips (the `fast` preset's 2x64 nets) as one fused op on the CPU
//! backend (Flex, with or without autodiff).
//!
//! Composed of burn ops, one call of a 2x64 MLP is a dozen autodiff nodes: three matrix
//! products, bias broadcasts, ReLUs and, in backward, their masks, transposes and bias
//! sums, each a fresh tensor. Fused, forward runs each chunk of rows through every layer
//! while it is in cache (a gemm, then bias and ReLU in place) and keeps the hidden
//! activations; backward runs the chain back chunk by chunk, masks by those activations,
//! and sums the chunks' weight gradients in chunk order, so the result never depends on
//! thread timing. MLPs with skips and other backends (wgpu) keep the composed ops in
//! [`crate::mlp`]; the two paths are tested against each other.

use std::sync::Arc;

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

/// Rows per parallel task: a chunk's activations (512 x 64 floats a layer) stay in L2.
const CHUNK: usize = 512;

/// The layers' shapes and host copies of their weights.
#[derive(Debug)]
struct Layers {
    /// `[d_input, width, ..., width, d_output]`: `depth + 2` entries.
    dims: Vec<usize>,
    /// Layer `l`: `[dims[l], dims[l + 1]]`, row-major (burn's `Linear` layout).
    weights: Vec<Vec<f32>>,
    /// Layer `l`: `[dims[l + 1]]`.
    biases: Vec<Vec<f32>>,
}

impl Layers {
    /// Hidden layers.
    fn depth(&self) -> usize {
        self.dims.len() - 2
    }

    fn width(&self) -> usize {
        self.dims[1]
    }

    fn d_out(&self) -> usize {
        self.dims[self.dims.len() - 1]
    }

    /// Floats of one chunk's hidden activations for `rows` rows.
    fn hidden_len(&self, rows: usize) -> usize {
        rows * self.width() * self.depth()
    }

    /// Runs `x` (`[rows, d_input]`) through every layer: hidden activations (after ReLU)
    /// into `hidden` (`[depth][rows, width]`), the output into `out` (`[rows, d_out]`).
    fn forward_chunk(&self, x: &[f32], hidden: &mut [f32], out: &mut [f32]) {
        let rows = out.len() / self.d_out();
        let w = self.width();
        let mut rest = hidden;
        let mut input: &[f32] = x;
        for l in 0..self.depth() {
            let (h, tail) = rest.split_at_mut(rows * w);
            matmul(
                rows,
                self.dims[l],
                w,
                input,
                false,
                &self.weights[l],
                false,
                h,
                false,
            );
            for row in h.chunks_exact_mut(w) {
                for (v, b) in row.iter_mut().zip(&self.biases[l]) {
                    *v = (*v + b).max(0.0);
                }
            }
            input = h;
            rest = tail;
        }
        let last = self.depth();
        let d_out = self.d_out();
        matmul(
            rows,
            w,
            d_out,
            input,
            false,
            &self.weights[last],
            false,
            out,
            false,
        );
        for row in out.chunks_exact_mut(d_out) {
            for (v, b) in row.iter_mut().zip(&self.biases[last]) {
                *v += b;
            }
        }
    }

    /// One chunk's backward: from `grad_out` (`[rows, d_out]`), the chunk's weight and
    /// bias gradients (layer by layer, weights then bias, flattened) and, with `grad_x`,
    /// the input's gradient (`[rows, d_input]`).
    fn backward_chunk(
        &self,
        x: &[f32],
        hidden: &[f32],
        grad_out: &[f32],
        grad_x: Option<&mut [f32]>,
    ) -> Vec<f32> {
        let rows = grad_out.len() / self.d_out();
        let w = self.width();
        let depth = self.depth();
        let mut partial = vec![0f32; self.param_len()];
        let offsets = self.param_offsets();
        let activation = |l: usize| &hidden[l * rows * w..(l + 1) * rows * w];
        // The gradient by the current layer's output, before its ReLU is undone.
        let mut g = grad_out.to_vec();
        let mut grad_x = grad_x;
        for l in (0..=depth).rev() {
            let (d_in, d_o) = (self.dims[l], self.dims[l + 1]);
            if l < depth {
                // Undo the ReLU: no gradient where the activation was clamped.
                for (gv, &h) in g.iter_mut().zip(activation(l)) {
                    if h <= 0.0 {
                        *gv = 0.0;
                    }
                }
            }
            let input = if l == 0 { x } else { activation(l - 1) };
            let (gw, gb) = partial[offsets[l]..offsets[l + 1]].split_at_mut(d_in * d_o);
            matmul(d_in, rows, d_o, input, true, &g, false, gw, false);
            for row in g.chunks_exact(d_o) {
                for (b, v) in gb.iter_mut().zip(row) {
                    *b += v;
                }
            }
            if l > 0 {
                let mut next = vec![0f32; rows * d_in];
                matmul(
                    rows,
                    d_o,
                    d_in,
                    &g,
                    false,
                    &self.weights[l],
                    true,
                    &mut next,
                    false,
                );
                g = next;
            } else if let Some(gx) = grad_x.take() {
                matmul(
                    rows,
                    d_o,
                    d_in,
                    &g,
                    false,
                    &self.weights[0],
                    true,
                    gx,
                    false,
                );
            }
        }
        partial
    }

    /// Offsets of each layer's block (weights, then bias) in a flattened gradient.
    fn param_offsets(&self) -> Vec<usize> {
        let mut offsets = vec![0];
        for l in 0..self.dims.len() - 1 {
            let len = self.dims[l] * self.dims[l + 1] + self.dims[l + 1];
            offsets.push(offsets[l] + len);
        }
        offsets
    }

    fn param_len(&self) -> usize {
        *self.param_offsets().last().unwrap_or(&0)
    }

    /// Multiply-adds of one row through every layer.
    fn macs_per_row(&self) -> usize {
        self.dims.windows(2).map(|d| d[0] * d[1]).sum()
    }
}

/// `out = a b` (or `out += a b` with `accumulate`) for row-major `a` (`[m, k]`, or its
/// transpose stored as `[k, m]` with `a_t`) and `b` (`[k, n]`, or `[n, k]` with `b_t`).
#[allow(clippy::too_many_arguments)]
fn matmul(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    a_t: bool,
    b: &[f32],
    b_t: bool,
    out: &mut [f32],
    accumulate: bool,
) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && out.len() >= m * n,
        "matmul: operands shorter than their shapes"
    );
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            out[..m * n].fill(0.0);
        }
        return;
    }
    // (column stride, row stride) of each operand, in elements.
    let (a_cs, a_rs) = if a_t {
        (m as isize, 1)
    } else {
        (1, k as isize)
    };
    let (b_cs, b_rs) = if b_t {
        (k as isize, 1)
    } else {
        (1, n as isize)
    };
    #[allow(unsafe_code)]
    // SAFETY: the assert above keeps every element the strides address inside its slice:
    // `a` spans `m * k` elements whether read as `[m, k]` or as the transpose of `[k, m]`,
    // `b` likewise `k * n`, `out` `m * n`; `out` is a unique borrow, so it aliases neither
    // input.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
            a.as_ptr(),
            a_cs,
            a_rs,
            b.as_ptr(),
            b_cs,
            b_rs,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// What backward needs: the layers, the input and the hidden activations.
#[derive(Debug)]
struct Saved {
    layers: Layers,
    n: usize,
    x: Vec<f32>,
    /// Chunk-major: chunk `c`'s `[depth][rows, width]` block starts at
    /// `c * hidden_len(CHUNK)`.
    hidden: Vec<f32>,
}

/// Forward over all rows: the output `[n, d_out]` and, with `keep`, the hidden
/// activations (chunk-major, see [`Saved::hidden`]).
fn forward_all(layers: &Layers, x: &[f32], n: usize, keep: bool) -> (Vec<f32>, Vec<f32>) {
    let kept = if keep { layers.hidden_len(n) } else { 0 };
    let work = Work {
        flops: 2.0 * n as f64 * layers.macs_per_row() as f64,
        bytes: 4.0 * (n * (layers.dims[0] + layers.d_out()) + kept + layers.param_len()) as f64,
        gathered: 0.0,
    };
    profile::timed_work("kernel: MLP forward", work, || {
        forward_rows(layers, x, n, keep)
    })
}

fn forward_rows(layers: &Layers, x: &[f32], n: usize, keep: bool) -> (Vec<f32>, Vec<f32>) {
    let (d_in, d_out) = (layers.dims[0], layers.d_out());
    let mut out = vec![0f32; n * d_out];
    if keep {
        let mut hidden = vec![0f32; layers.hidden_len(n)];
        out.par_chunks_mut(CHUNK * d_out)
            .zip(hidden.par_chunks_mut(layers.hidden_len(CHUNK)))
            .zip(x.par_chunks(CHUNK * d_in))
            .for_each(|((out, hidden), x)| layers.forward_chunk(x, hidden, out));
        (out, hidden)
    } else {
        out.par_chunks_mut(CHUNK * d_out)
            .zip(x.par_chunks(CHUNK * d_in))
            .for_each(|(out, x)| {
                let mut hidden = vec![0f32; layers.hidden_len(out.len() / d_out)];
                layers.forward_chunk(x, &mut hidden, out);
            });
        (out, Vec::new())
    }
}

#[derive(Debug)]
struct MlpBackward;

impl<const N: usize> Backward<Flex, N> for MlpBackward {
    type State = Arc<Saved>;

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<Flex>(&ops.node);
        let saved = ops.state;
        let layers = &saved.layers;
        let grad = f32_data(&grad).expect("the MLP's gradient is f32 like its output");
        let (d_in, n) = (layers.dims[0], saved.n);
        let [x_node, rest @ ..] = ops.parents.as_slice() else {
            unreachable!("an MLP op has at least its input as a parent")
        };
        // Weight gradients and, where the input is tracked, the input's: two products a
        // layer (the first layer's input gradient only when asked for).
        let macs = layers.macs_per_row() as f64;
        let first = (layers.dims[0] * layers.dims[1]) as f64;
        let input_macs = if x_node.is_some() { macs } else { macs - first };
        let work = Work {
            flops: 2.0 * n as f64 * (macs + input_macs),
            bytes: 4.0
                * (n * (2 * d_in + layers.d_out())
                    + layers.hidden_len(n)
                    + layers.param_len() * n.div_ceil(CHUNK)) as f64,
            gathered: 0.0,
        };
        let (grad_x, total) = profile::timed_work("kernel: MLP backward", work, || {
            chain_back(&saved, &grad, x_node.is_some())
        });
        if let Some(node) = x_node {
            grads.register::<Flex>(node.id, flex_tensor(grad_x, [n, d_in]));
        }
        // Parents after the input: weight 0, bias 0, weight 1, bias 1, ...
        let offsets = layers.param_offsets();
        for (i, node) in rest.iter().enumerate() {
            let Some(node) = node else { continue };
            let l = i / 2;
            let (rows, cols) = (layers.dims[l], layers.dims[l + 1]);
            let block = &total[offsets[l]..offsets[l + 1]];
            let (values, shape) = if i % 2 == 0 {
                (block[..rows * cols].to_vec(), [rows, cols])
            } else {
                (block[rows * cols..].to_vec(), [1, cols])
            };
            grads.register::<Flex>(node.id, flex_tensor(values, shape));
        }
    }
}

/// The input's gradient `[n, d_in]` (empty without `with_input`) and the parameters'
/// gradients, flat in [`Layers::param_offsets`]'s layout, for the output gradient `grad`.
fn chain_back(saved: &Saved, grad: &[f32], with_input: bool) -> (Vec<f32>, Vec<f32>) {
    let layers = &saved.layers;
    let (d_in, n) = (layers.dims[0], saved.n);
    let mut grad_x = vec![0f32; if with_input { n * d_in } else { 0 }];
    let hidden_chunk = layers.hidden_len(CHUNK);
    let chunks: Vec<usize> = (0..n.div_ceil(CHUNK)).collect();
    let partials: Vec<Vec<f32>> = if with_input {
        grad_x
            .par_chunks_mut(CHUNK * d_in)
            .zip(chunks.par_iter())
            .map(|(gx, &c)| chunk_backward(saved, c, hidden_chunk, grad, Some(gx)))
            .collect()
    } else {
        chunks
            .par_iter()
            .map(|&c| chunk_backward(saved, c, hidden_chunk, grad, None))
            .collect()
    };
    // Summed in chunk order: the same bits whatever thread ran which chunk.
    let mut total = vec![0f32; layers.param_len()];
    for p in &partials {
        for (t, v) in total.iter_mut().zip(p) {
            *t += v;
        }
    }
    (grad_x, total)
}

/// Backward of chunk `c`.
fn chunk_backward(
    saved: &Saved,
    c: usize,
    hidden_chunk: usize,
    grad: &[f32],
    grad_x: Option<&mut [f32]>,
) -> Vec<f32> {
    let layers = &saved.layers;
    let (d_in, d_out) = (layers.dims[0], layers.d_out());
    let start = c * CHUNK;
    let rows = CHUNK.min(saved.n - start);
    let x = &saved.x[start * d_in..(start + rows) * d_in];
    let hidden = &saved.hidden[c * hidden_chunk..c * hidden_chunk + layers.hidden_len(rows)];
    let g = &grad[start * d_out..(start + rows) * d_out];
    layers.backward_chunk(x, hidden, g, grad_x)
}

/// `x` (`[n, d_input]`) through a ReLU MLP without skips as one op, when every tensor
/// lives on Flex (with or without autodiff) as f32; `None` otherwise (the caller composes
/// tensor ops). `params` are, layer by layer, the weight `[d_in, d_out]` and the bias
/// `[1, d_out]` (the first layer's bias may carry a shared condition row's product).
pub(crate) fn forward(x: &Tensor<2>, params: &[Tensor<2>]) -> Option<Tensor<2>> {
    match params.len() {
        4 => forward_n::<5>(x, params),
        6 => forward_n::<7>(x, params),
        8 => forward_n::<9>(x, params),
        10 => forward_n::<11>(x, params),
        _ => None,
    }
}

fn forward_n<const N: usize>(x: &Tensor<2>, params: &[Tensor<2>]) -> Option<Tensor<2>> {
    let all: Vec<&Tensor<2>> = std::iter::once(x).chain(params).collect();
    let shapes: Vec<[usize; 2]> = all.iter().map(|t| t.dims()).collect();
    let n = shapes[0][0];
    let tracked: Option<Vec<_>> = all
        .iter()
        .map(|t| (*t).clone().try_into_primitive::<Autodiff<Flex>>().ok())
        .collect();
    if let Some(tracked) = tracked {
        let nodes: [_; N] = tracked
            .iter()
            .map(|t| t.node())
            .collect::<Vec<_>>()
            .try_into()
            .ok()?;
        let prims: Vec<_> = tracked.into_iter().map(|t| t.into_primitive()).collect();
        let layers = layers(&prims, &shapes)?;
        let x = f32_data(&prims[0])?.into_owned();
        let d_out = layers.d_out();
        let out = match MlpBackward
            .prepare::<NoCheckpointing>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (out, hidden) = forward_all(&layers, &x, n, true);
                let saved = Saved {
                    layers,
                    n,
                    x,
                    hidden,
                };
                prep.finish(Arc::new(saved), flex_tensor(out, [n, d_out]))
            }
            OpsKind::UnTracked(prep) => {
                let (out, _) = forward_all(&layers, &x, n, false);
                prep.finish(flex_tensor(out, [n, d_out]))
            }
        };
        return Some(Tensor::from_primitive::<Autodiff<Flex>>(out));
    }
    let prims: Option<Vec<_>> = all
        .iter()
        .map(|t| (*t).clone().try_into_primitive::<Flex>().ok())
        .collect();
    let prims = prims?;
    let layers = layers(&prims, &shapes)?;
    let (out, _) = forward_all(&layers, &f32_data(&prims[0])?, n, false);
    Some(Tensor::from_primitive::<Flex>(flex_tensor(
        out,
        [n, layers.d_out()],
    )))
}

/// The layers from `[x, w0, b0, w1, b1, ...]` Flex primitives and their shapes; `None`
/// for other dtypes, mismatched shapes or unequal hidden widths.
fn layers(prims: &[FlexTensor], shapes: &[[usize; 2]]) -> Option<Layers> {
    let mut dims = vec![shapes[0][1]];
    let (mut weights, mut biases) = (Vec::new(), Vec::new());
    for (pair, shape) in prims[1..].chunks_exact(2).zip(shapes[1..].chunks_exact(2)) {
        let [rows, cols] = shape[0];
        if rows != *dims.last()? || shape[1] != [1, cols] {
            return None;
        }
        dims.push(cols);
        weights.push(f32_data(&pair[0])?.into_owned());
        biases.push(f32_data(&pair[1])?.into_owned());
    }
    let hidden = &dims[1..dims.len() - 1];
    if hidden.is_empty() || hidden.iter().any(|&w| w != hidden[0]) {
        return None;
    }
    Some(Layers {
        dims,
        weights,
        biases,
    })
}
