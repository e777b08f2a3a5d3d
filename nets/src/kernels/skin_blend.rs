//! Inverse skinning's blend as one fused op on the CPU backend (Flex, with or without
//! autodiff): each (sample, bone) pair's logit read from the weight volume, the softmax
//! over a sample's candidates and the blend of their canonical points.
//!
//! Composed of burn ops (the reference in [`crate::skinning`]), the blend is a dozen
//! autodiff nodes: a `select` of eight volume rows a pair, whose backward zeroes a
//! volume-sized tensor (55 x 32^3 floats with finger bones) before adding into it, the
//! corner products and sums, and four `select_assign`s for the softmax's max, its sum
//! and the blend, each with a fresh tensor in both directions. Fused, forward takes a
//! sample's pairs in one pass and keeps their softmax weights; backward gives each pair's
//! logit gradient from them (`dl_j = a_j (g . x_j - g . x)`) and adds it into the
//! volume's eight corners in pair order, so the result never depends on thread timing.

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use burn::tensor::TensorData;
use rayon::prelude::*;

use super::flex_data::{f32_data, flex_tensor};
use crate::profile::{self, Work};

/// Samples per parallel task.
const CHUNK: usize = 1024;

/// The host columns of a blend's pairs, in sample order (what the CPU's pair layout
/// wrote).
#[derive(Debug)]
pub(crate) struct BlendPairs {
    /// `[n + 1]`: sample `s`'s pairs are `start[s]..start[s + 1]`; none is empty.
    pub start: Vec<usize>,
    /// `[m * 8]` volume rows where each pair's logit is read.
    pub rows: Vec<i32>,
    /// `[m * 8]` their trilinear weights.
    pub weights: Vec<f32>,
    /// `[m]` the posed-space prior's logit of each pair.
    pub posed: Vec<f32>,
}

impl BlendPairs {
    /// The columns for pairs whose samples are `sample` (ascending, every one of the `n`
    /// samples present).
    pub(crate) fn new(
        sample: &[i32],
        n: usize,
        rows: Vec<i32>,
        weights: Vec<f32>,
        posed: Vec<f32>,
    ) -> BlendPairs {
        let mut start = vec![0usize; n + 1];
        for &s in sample {
            start[s as usize + 1] += 1;
        }
        for s in 0..n {
            start[s + 1] += start[s];
        }
        BlendPairs {
            start,
            rows,
            weights,
            posed,
        }
    }

    fn n(&self) -> usize {
        self.start.len() - 1
    }

    fn m(&self) -> usize {
        self.posed.len()
    }

    /// Pair `j`'s logit: its eight corners of `volume`, then the prior.
    #[inline]
    fn logit(&self, volume: &[f32], j: usize) -> f32 {
        let mut l = 0.0f32;
        for k in 8 * j..8 * j + 8 {
            l += volume[self.rows[k] as usize] * self.weights[k];
        }
        l + self.posed[j]
    }

    /// `([n, 3] blended points, [m] softmax weights)` of the pairs' points `xb` `[m, 3]`.
    fn forward(&self, volume: &[f32], xb: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let n = self.n();
        let mut out = vec![0f32; 3 * n];
        let mut a = vec![0f32; self.m()];
        // Cut the pairs' weights at the tasks' first samples.
        let mut tasks = Vec::with_capacity(n.div_ceil(CHUNK));
        let mut rest = &mut a[..];
        for (c, out) in out.chunks_mut(3 * CHUNK).enumerate() {
            let first = c * CHUNK;
            let last = first + out.len() / 3;
            let head;
            (head, rest) = rest.split_at_mut(self.start[last] - self.start[first]);
            tasks.push((first, out, head));
        }
        tasks.into_par_iter().for_each(|(first, out, a)| {
            let base = self.start[first];
            for (i, x) in out.chunks_exact_mut(3).enumerate() {
                let pairs = self.start[first + i]..self.start[first + i + 1];
                let mut max = f32::NEG_INFINITY;
                for j in pairs.clone() {
                    let l = self.logit(volume, j);
                    a[j - base] = l;
                    max = max.max(l);
                }
                let mut denom = 0.0f32;
                for j in pairs.clone() {
                    let e = (a[j - base] - max).exp();
                    a[j - base] = e;
                    denom += e;
                }
                let mut blended = [0f32; 3];
                for j in pairs {
                    let w = a[j - base] / denom;
                    a[j - base] = w;
                    for d in 0..3 {
                        blended[d] += xb[3 * j + d] * w;
                    }
                }
                x.copy_from_slice(&blended);
            }
        });
        (out, a)
    }

    /// `[m]` each pair's logit gradient and, when `want_points`, `[m, 3]` its point's,
    /// for the output gradient `grad` `[n, 3]`.
    fn pair_grads(
        &self,
        grad: &[f32],
        out: &[f32],
        a: &[f32],
        xb: &[f32],
        want_points: bool,
    ) -> (Vec<f32>, Vec<f32>) {
        let m = self.m();
        let mut dl = vec![0f32; m];
        let mut dx = vec![0f32; if want_points { 3 * m } else { 0 }];
        let n = self.n();
        let mut tasks = Vec::with_capacity(n.div_ceil(CHUNK));
        let (mut rest_l, mut rest_x) = (&mut dl[..], &mut dx[..]);
        for first in (0..n).step_by(CHUNK) {
            let last = (first + CHUNK).min(n);
            let k = self.start[last] - self.start[first];
            let (l, x);
            (l, rest_l) = rest_l.split_at_mut(k);
            (x, rest_x) = rest_x.split_at_mut(if want_points { 3 * k } else { 0 });
            tasks.push((first..last, l, x));
        }
        tasks.into_par_iter().for_each(|(samples, dl, dx)| {
            let base = self.start[samples.start];
            for s in samples {
                let g = &grad[3 * s..3 * s + 3];
                let g_out: f32 = (0..3).map(|d| g[d] * out[3 * s + d]).sum();
                for j in self.start[s]..self.start[s + 1] {
                    let g_x: f32 = (0..3).map(|d| g[d] * xb[3 * j + d]).sum();
                    dl[j - base] = a[j] * (g_x - g_out);
                    if want_points {
                        for d in 0..3 {
                            dx[3 * (j - base) + d] = a[j] * g[d];
                        }
                    }
                }
            }
        });
        (dl, dx)
    }

    /// `[volume_len]` the volume's gradient from the pairs' logit gradients `dl`, added
    /// in pair order.
    fn volume_grad(&self, dl: &[f32], volume_len: usize) -> Vec<f32> {
        let mut dv = vec![0f32; volume_len];
        for (j, &g) in dl.iter().enumerate() {
            for k in 8 * j..8 * j + 8 {
                dv[self.rows[k] as usize] += self.weights[k] * g;
            }
        }
        dv
    }

    fn forward_work(&self) -> Work {
        let m = self.m() as f64;
        Work {
            flops: m * (16.0 + 10.0),
            bytes: m * (8.0 * 12.0 + 4.0 * 8.0) + 12.0 * self.n() as f64,
            gathered: m * 8.0 * 4.0,
        }
    }

    fn backward_work(&self, want_points: bool) -> Work {
        let m = self.m() as f64;
        let points = if want_points { 12.0 } else { 0.0 };
        Work {
            flops: m * (8.0 + 16.0 + if want_points { 3.0 } else { 0.0 }),
            bytes: m * (8.0 * 16.0 + 20.0 + points),
            gathered: m * 8.0 * 8.0,
        }
    }
}

#[derive(Debug)]
struct BlendBackward;

/// What backward reads: the pairs, the forward's output and softmax weights, the pairs'
/// points and the volume's length.
type BlendState = (
    Arc<BlendPairs>,
    FlexTensor,
    Arc<Vec<f32>>,
    FlexTensor,
    usize,
);

impl Backward<Flex, 2> for BlendBackward {
    type State = BlendState;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [volume_node, point_node] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let (pairs, out, a, xb, volume_len) = ops.state;
        let grad = f32_data(&grad).expect("the blend's gradient is f32 like its output");
        let out = f32_data(&out).expect("the blend's output is f32");
        let xb = f32_data(&xb).expect("the pairs' points are f32");
        let want_points = point_node.is_some();
        let work = pairs.backward_work(want_points);
        let (dl, dx) = profile::timed_work("kernel: skinning blend backward", work, || {
            pairs.pair_grads(&grad, &out, &a, &xb, want_points)
        });
        if let Some(node) = point_node {
            grads.register::<Flex>(node.id, flex_tensor(dx, [pairs.m(), 3]));
        }
        if let Some(node) = volume_node {
            let dv = profile::timed("kernel: skinning blend backward (volume)", || {
                pairs.volume_grad(&dl, volume_len)
            });
            let dv = FlexTensor::from_data(TensorData::new(dv, [volume_len]));
            grads.register::<Flex>(node.id, dv);
        }
    }
}

/// `x_canonical` `[n, 3]`: each sample's candidates' points `xb` `[m, 3]` blended by the
/// softmax of their logits read from `volume` `[V]` at `pairs`, as one op when both live
/// on Flex (with or without autodiff) as f32; the pairs handed back otherwise (the
/// caller composes tensor ops).
pub(crate) fn blend(
    volume: &Tensor<1>,
    xb: &Tensor<2>,
    pairs: BlendPairs,
) -> Result<Tensor<2>, BlendPairs> {
    let n = pairs.n();
    let forward = |pairs: &BlendPairs, volume: &FlexTensor, xb: &FlexTensor| {
        let (volume, xb) = (f32_data(volume)?, f32_data(xb)?);
        let work = pairs.forward_work();
        Some(profile::timed_work(
            "kernel: skinning blend forward",
            work,
            || pairs.forward(&volume, &xb),
        ))
    };
    if let (Ok(v), Ok(x)) = (
        volume.clone().try_into_primitive::<Autodiff<Flex>>(),
        xb.clone().try_into_primitive::<Autodiff<Flex>>(),
    ) {
        let (v_node, x_node) = (v.node(), x.node());
        let (v, x) = (v.into_primitive(), x.into_primitive());
        let Some((out, a)) = forward(&pairs, &v, &x) else {
            return Err(pairs);
        };
        let volume_len = volume.dims()[0];
        let out = flex_tensor(out, [n, 3]);
        let out = match BlendBackward
            .prepare::<NoCheckpointing>([v_node, x_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(
                (Arc::new(pairs), out.clone(), Arc::new(a), x, volume_len),
                out,
            ),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        return Ok(Tensor::from_primitive::<Autodiff<Flex>>(out));
    }
    let (Ok(v), Ok(x)) = (
        volume.clone().try_into_primitive::<Flex>(),
        xb.clone().try_into_primitive::<Flex>(),
    ) else {
        return Err(pairs);
    };
    match forward(&pairs, &v, &x) {
        Some((out, _)) => Ok(Tensor::from_primitive::<Flex>(flex_tensor(out, [n, 3]))),
        None => Err(pairs),
    }
}
