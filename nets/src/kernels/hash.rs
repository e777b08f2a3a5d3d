//! The hash encoding as one fused op on the CPU backend (Flex, with or without autodiff).
//!
//! Composed of tensor ops, the encoding made `[n, L, 8, F]` intermediates (weights,
//! gathered rows, their product and its gradients) and, in backward, a zeroed table-sized
//! tensor for every `select`: ~48% of a training step's CPU time (perf, `fast` preset).
//! Fused, forward interpolates each point's levels in one pass (and, when the points need
//! a gradient, the output's Jacobian by the point, while the rows are in cache); backward
//! writes the table gradient level by level (levels own disjoint rows, so they run in
//! parallel) and the point gradient from that Jacobian. Other backends (wgpu) keep the
//! composed ops in [`super::hash_grid`]; both are tested against the same f64 reference.

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::{Autodiff, Flex};
use burn::prelude::*;
use rayon::prelude::*;

use super::flex_data::{f32_data, flex_tensor};
use crate::profile::{self, Work};

/// Points per parallel task.
const CHUNK: usize = 256;
/// How many points ahead the table rows are prefetched: the fine levels' rows are random
/// in a table larger than the cache, so without it every lookup waits on memory.
const AHEAD: usize = 4;

/// Every point's 8 vertex rows and cell fractions on every level: what forward computed
/// and backward reuses.
#[derive(Debug)]
pub(crate) struct Corners {
    /// Points.
    n: usize,
    /// Cells per axis of each level (as f32: the fractions' derivative scale).
    resolutions: Vec<f32>,
    /// First table row of each level, plus the total.
    offsets: Vec<usize>,
    n_features: usize,
    /// `[n, L, 8]` table rows; corner `k` is `(k & 1, k >> 1 & 1, k >> 2)`.
    rows: Vec<u32>,
    /// `[n, L, 3]` position inside the cell, in [0, 1].
    frac: Vec<f32>,
}

impl Corners {
    /// `unit_points` `[n, 3]` (clamped to [0, 1]); `rows_of(level, c)` gives the table
    /// rows of the 8 vertices of the cell with lower corner `c` (corner `k` at
    /// `c + (k & 1, k >> 1 & 1, k >> 2)`).
    pub(crate) fn new(
        unit_points: &[f32],
        resolutions: &[usize],
        offsets: &[usize],
        n_features: usize,
        rows_of: &(dyn Fn(usize, [u32; 3]) -> [u32; 8] + Sync),
    ) -> Corners {
        let n = unit_points.len() / 3;
        let l = resolutions.len();
        let mut rows = vec![0u32; n * l * 8];
        let mut frac = vec![0f32; n * l * 3];
        rows.par_chunks_mut(CHUNK * l * 8)
            .zip(frac.par_chunks_mut(CHUNK * l * 3))
            .zip(unit_points.par_chunks(CHUNK * 3))
            .for_each(|((rows, frac), points)| {
                for (i, p) in points.chunks_exact(3).enumerate() {
                    for (level, &res) in resolutions.iter().enumerate() {
                        let mut c = [0u32; 3];
                        let at = i * l + level;
                        for a in 0..3 {
                            let q = p[a].clamp(0.0, 1.0) as f64 * res as f64;
                            let cell = q.floor().clamp(0.0, res as f64 - 1.0);
                            c[a] = cell as u32;
                            frac[at * 3 + a] = (q - cell) as f32;
                        }
                        rows[at * 8..at * 8 + 8].copy_from_slice(&rows_of(level, c));
                    }
                }
            });
        Corners {
            n,
            resolutions: resolutions.iter().map(|&r| r as f32).collect(),
            offsets: offsets.to_vec(),
            n_features,
            rows,
            frac,
        }
    }

    fn levels(&self) -> usize {
        self.resolutions.len()
    }

    /// Point-levels: one trilinear blend of 8 table rows each.
    fn lookups(&self) -> f64 {
        (self.n * self.levels()) as f64
    }

    /// Point-levels on the hashed levels (those with the largest table: the fine levels,
    /// whose rows are random in a table larger than the cache); the coarse levels' dense
    /// tables stay in cache.
    fn hashed_lookups(&self) -> f64 {
        let rows: Vec<usize> = self.offsets.windows(2).map(|w| w[1] - w[0]).collect();
        let largest = rows.iter().copied().max().unwrap_or(0);
        (self.n * rows.iter().filter(|&&r| r == largest).count()) as f64
    }

    /// [`Corners::interpolate`]'s work: 8 rows a point-level (gathered on the hashed
    /// levels), their weights and blend (and the Jacobian's three derivatives of each),
    /// the corners read and the output written.
    fn interpolate_work(&self, jacobian: bool) -> Work {
        let (k, f) = (self.lookups(), self.n_features as f64);
        let row = 4.0 * f;
        let per = 8.0 * (2.0 + 2.0 * f) + if jacobian { 8.0 * (6.0 + 6.0 * f) } else { 0.0 };
        let streamed = k * (8.0 * 4.0 + 3.0 * 4.0 + row * if jacobian { 4.0 } else { 1.0 });
        Work {
            flops: k * per,
            bytes: streamed + k * 8.0 * row,
            gathered: self.hashed_lookups() * 8.0 * row,
        }
    }

    /// [`Corners::table_grad`]'s work: the table-sized gradient zeroed, then per
    /// point-level 8 weights and 8 rows read, added to and written back (at random on
    /// the hashed levels).
    fn table_grad_work(&self) -> Work {
        let (k, f) = (self.lookups(), self.n_features as f64);
        let row = 4.0 * f;
        let table = *self.offsets.last().unwrap_or(&0) as f64 * row;
        Work {
            flops: k * 8.0 * (2.0 + 2.0 * f),
            bytes: table + k * (8.0 * 4.0 + 3.0 * 4.0 + row) + k * 8.0 * 2.0 * row,
            gathered: self.hashed_lookups() * 8.0 * 2.0 * row,
        }
    }

    /// [`Corners::point_grad`]'s work: the output gradient against the Jacobian.
    fn point_grad_work(&self) -> Work {
        let lf = self.lookups() * self.n_features as f64;
        Work {
            flops: lf * 6.0,
            bytes: lf * 4.0 * 4.0 + self.n as f64 * 12.0,
            gathered: 0.0,
        }
    }

    /// `[n, L F]`: per point and level, the trilinear blend of its 8 rows of `table`; with
    /// `jacobian`, also `[n, L F, 3]`: each output's derivative by the point, taken here
    /// while the rows are in cache so that backward never reads the table again.
    pub(crate) fn interpolate(&self, table: &[f32], jacobian: bool) -> (Vec<f32>, Vec<f32>) {
        let (l, f) = (self.levels(), self.n_features);
        let mut out = vec![0f32; self.n * l * f];
        let mut jac = vec![0f32; if jacobian { self.n * l * f * 3 } else { 0 }];
        let work = |chunk: usize, out: &mut [f32], jac: &mut [f32]| {
            for (i, out) in out.chunks_exact_mut(l * f).enumerate() {
                let p = chunk * CHUNK + i;
                if let Some(ahead) = self.rows.get((p + AHEAD) * l * 8..(p + AHEAD + 1) * l * 8) {
                    // x-neighbours share a cache line: one hint per pair.
                    for &row in ahead.iter().step_by(2) {
                        prefetch(table, row as usize * f);
                    }
                }
                if f == 2 {
                    let jac = jacobian.then(|| &mut jac[i * l * 6..(i + 1) * l * 6]);
                    self.levels_f2(table, p, out, jac);
                    continue;
                }
                for level in 0..l {
                    let at = p * l + level;
                    let t = &self.frac[at * 3..at * 3 + 3];
                    let w = weights(t);
                    let rows = &self.rows[at * 8..at * 8 + 8];
                    let out = &mut out[level * f..(level + 1) * f];
                    for (k, &wk) in w.iter().enumerate() {
                        let row = rows[k] as usize * f;
                        for (o, v) in out.iter_mut().zip(&table[row..row + f]) {
                            *o += wk * v;
                        }
                    }
                    if jacobian {
                        let dw = weight_derivatives(t);
                        let res = self.resolutions[level];
                        let base = (i * l + level) * f * 3;
                        let jac = &mut jac[base..base + f * 3];
                        for (k, dwk) in dw.iter().enumerate() {
                            let row = rows[k] as usize * f;
                            for (j, &v) in table[row..row + f].iter().enumerate() {
                                for a in 0..3 {
                                    jac[j * 3 + a] += res * dwk[a] * v;
                                }
                            }
                        }
                    }
                }
            }
        };
        if jacobian {
            out.par_chunks_mut(CHUNK * l * f)
                .zip(jac.par_chunks_mut(CHUNK * l * f * 3))
                .enumerate()
                .for_each(|(chunk, (out, jac))| work(chunk, out, jac));
        } else {
            out.par_chunks_mut(CHUNK * l * f)
                .enumerate()
                .for_each(|(chunk, out)| work(chunk, out, &mut []));
        }
        (out, jac)
    }

    /// [`Corners::interpolate`]'s work for point `p` with two features a level (both
    /// presets' width): the same operations in the same order, so the same bits, with
    /// each level's 8 rows read once into registers and no per-feature loops. `out`:
    /// `[L 2]`, `jac`: `[L 2, 3]` (both zeroed).
    #[inline]
    fn levels_f2(&self, table: &[f32], p: usize, out: &mut [f32], mut jac: Option<&mut [f32]>) {
        let l = self.levels();
        for level in 0..l {
            let at = p * l + level;
            let t = &self.frac[at * 3..at * 3 + 3];
            let w = weights(t);
            let rows = &self.rows[at * 8..at * 8 + 8];
            let mut v = [[0f32; 2]; 8];
            let mut o = [0f32; 2];
            for k in 0..8 {
                let row = rows[k] as usize * 2;
                let r = &table[row..row + 2];
                v[k] = [r[0], r[1]];
                o[0] += w[k] * v[k][0];
                o[1] += w[k] * v[k][1];
            }
            out[level * 2..level * 2 + 2].copy_from_slice(&o);
            if let Some(jac) = jac.as_deref_mut() {
                let dw = weight_derivatives(t);
                let res = self.resolutions[level];
                let mut d = [0f32; 6];
                for k in 0..8 {
                    for j in 0..2 {
                        for a in 0..3 {
                            d[j * 3 + a] += res * dw[k][a] * v[k][j];
                        }
                    }
                }
                jac[level * 6..level * 6 + 6].copy_from_slice(&d);
            }
        }
    }

    /// `[entries, F]`: the table's gradient for the output gradient `grad` `[n, L F]`.
    /// Each level's rows are a disjoint block, filled by its own task.
    pub(crate) fn table_grad(&self, grad: &[f32]) -> Vec<f32> {
        let (l, f) = (self.levels(), self.n_features);
        let total = *self.offsets.last().unwrap_or(&0);
        let mut out = vec![0f32; total * f];
        let mut blocks = Vec::with_capacity(l);
        let mut rest = out.as_mut_slice();
        for level in 0..l {
            let len = (self.offsets[level + 1] - self.offsets[level]) * f;
            let (block, tail) = rest.split_at_mut(len);
            blocks.push((level, block));
            rest = tail;
        }
        blocks.into_par_iter().for_each(|(level, block)| {
            let first = self.offsets[level];
            for p in 0..self.n {
                let at = p * l + level;
                if let Some(ahead) = self
                    .rows
                    .get((at + AHEAD * l) * 8..(at + AHEAD * l) * 8 + 8)
                {
                    for &row in ahead.iter().step_by(2) {
                        prefetch(block, (row as usize - first) * f);
                    }
                }
                let g = &grad[p * l * f + level * f..p * l * f + (level + 1) * f];
                if g.iter().all(|&v| v == 0.0) {
                    continue;
                }
                let w = weights(&self.frac[at * 3..at * 3 + 3]);
                if let &[g0, g1] = g {
                    // Two features (both presets): no per-feature loop.
                    for (k, &wk) in w.iter().enumerate() {
                        let row = (self.rows[at * 8 + k] as usize - first) * 2;
                        let d = &mut block[row..row + 2];
                        d[0] += wk * g0;
                        d[1] += wk * g1;
                    }
                    continue;
                }
                for (k, &wk) in w.iter().enumerate() {
                    let row = (self.rows[at * 8 + k] as usize - first) * f;
                    for (d, &gv) in block[row..row + f].iter_mut().zip(g) {
                        *d += wk * gv;
                    }
                }
            }
        });
        out
    }

    /// `[n, 3]`: the points' gradient for the output gradient `grad` `[n, L F]`, from the
    /// Jacobian `[n, L F, 3]` that [`Corners::interpolate`] made.
    pub(crate) fn point_grad(&self, grad: &[f32], jacobian: &[f32]) -> Vec<f32> {
        let lf = self.levels() * self.n_features;
        let mut out = vec![0f32; self.n * 3];
        out.par_chunks_mut(CHUNK * 3)
            .zip(grad.par_chunks(CHUNK * lf))
            .zip(jacobian.par_chunks(CHUNK * lf * 3))
            .for_each(|((out, grad), jac)| {
                for ((out, g), j) in out
                    .chunks_exact_mut(3)
                    .zip(grad.chunks_exact(lf))
                    .zip(jac.chunks_exact(lf * 3))
                {
                    for (gv, ja) in g.iter().zip(j.chunks_exact(3)) {
                        for a in 0..3 {
                            out[a] += gv * ja[a];
                        }
                    }
                }
            });
        out
    }
}

/// Hints the CPU to start loading `slice[i]` into cache; no effect on any result.
#[inline(always)]
fn prefetch<T>(slice: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < slice.len() {
        #[allow(unsafe_code)]
        // SAFETY: the pointer lies inside `slice`, and a prefetch is only a cache hint: it
        // never faults and reads nothing the program sees.
        unsafe {
            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                slice.as_ptr().add(i) as *const i8,
            );
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (slice, i);
}

/// Trilinear weights of the 8 corners for cell fractions `t`.
#[inline]
fn weights(t: &[f32]) -> [f32; 8] {
    let mut w = [0f32; 8];
    for (k, wk) in w.iter_mut().enumerate() {
        let pick = |a: usize| {
            if (k >> a) & 1 == 1 { t[a] } else { 1.0 - t[a] }
        };
        *wk = pick(0) * pick(1) * pick(2);
    }
    w
}

/// d(weight of corner k) / d t[a] for the 8 corners.
#[inline]
fn weight_derivatives(t: &[f32]) -> [[f32; 3]; 8] {
    let mut dw = [[0f32; 3]; 8];
    for (k, dk) in dw.iter_mut().enumerate() {
        let factor = |a: usize| {
            if (k >> a) & 1 == 1 { t[a] } else { 1.0 - t[a] }
        };
        let sign = |a: usize| if (k >> a) & 1 == 1 { 1.0 } else { -1.0 };
        dk[0] = sign(0) * factor(1) * factor(2);
        dk[1] = sign(1) * factor(0) * factor(2);
        dk[2] = sign(2) * factor(0) * factor(1);
    }
    dw
}

#[derive(Debug)]
struct HashEncodeBackward;

impl Backward<Flex, 2> for HashEncodeBackward {
    /// The corners and, when the points need a gradient, the encoding's Jacobian.
    type State = (Arc<Corners>, Arc<Vec<f32>>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [table_node, point_node] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let (corners, jacobian) = ops.state;
        let grad = f32_data(&grad).expect("the encoding's gradient is f32 like its output");
        if let Some(node) = point_node {
            let work = corners.point_grad_work();
            let d = profile::timed_work("kernel: hash backward (points)", work, || {
                corners.point_grad(&grad, &jacobian)
            });
            grads.register::<Flex>(node.id, flex_tensor(d, [corners.n, 3]));
        }
        if let Some(node) = table_node {
            let work = corners.table_grad_work();
            let d = profile::timed_work("kernel: hash backward (table)", work, || {
                corners.table_grad(&grad)
            });
            let rows = *corners.offsets.last().unwrap_or(&0);
            grads.register::<Flex>(node.id, flex_tensor(d, [rows, corners.n_features]));
        }
    }
}

/// The corners of `points` and their interpolation of `table` (with the Jacobian when
/// `jacobian`), timed as the encoding's forward.
fn encode_timed(
    points: &[f32],
    table: &[f32],
    jacobian: bool,
    corners: impl FnOnce(&[f32]) -> Corners,
) -> (Corners, (Vec<f32>, Vec<f32>)) {
    if !profile::enabled() {
        let c = corners(points);
        let out = c.interpolate(table, jacobian);
        return (c, out);
    }
    let c = profile::timed("kernel: hash forward (corners)", || corners(points));
    let work = c.interpolate_work(jacobian);
    let out = profile::timed_work("kernel: hash forward (lookup)", work, || {
        c.interpolate(table, jacobian)
    });
    (c, out)
}

/// The encoding of `unit_points` `[n, 3]` with `table` `[entries, F]` as one op, when both
/// live on Flex (with or without autodiff) as f32; `None` otherwise (the caller composes
/// tensor ops). `corners` builds the lookup from the host points.
pub(crate) fn encode(
    table: &Tensor<2>,
    unit_points: &Tensor<2>,
    corners: impl FnOnce(&[f32]) -> Corners,
) -> Option<Tensor<2>> {
    if let (Ok(t), Ok(x)) = (
        table.clone().try_into_primitive::<Autodiff<Flex>>(),
        unit_points.clone().try_into_primitive::<Autodiff<Flex>>(),
    ) {
        let (t_node, x_node) = (t.node(), x.node());
        let points_tracked = x.is_tracked();
        let (t, x) = (t.into_primitive(), x.into_primitive());
        let (corners, (out, jacobian)) =
            encode_timed(&f32_data(&x)?, &f32_data(&t)?, points_tracked, corners);
        let corners = Arc::new(corners);
        let out = flex_tensor(out, [corners.n, corners.levels() * corners.n_features]);
        let out = match HashEncodeBackward
            .prepare::<NoCheckpointing>([t_node, x_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((corners, Arc::new(jacobian)), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        return Some(Tensor::from_primitive::<Autodiff<Flex>>(out));
    }
    let t = table.clone().try_into_primitive::<Flex>().ok()?;
    let x = unit_points.clone().try_into_primitive::<Flex>().ok()?;
    let (corners, (out, _)) = encode_timed(&f32_data(&x)?, &f32_data(&t)?, false, corners);
    let out = flex_tensor(out, [corners.n, corners.levels() * corners.n_features]);
    Some(Tensor::from_primitive::<Flex>(out))
}
