//! Inverse skinning's blend as CubeCL kernels: one unit per sample walks that sample's
//! candidate bones (a row of the padded `[n, K]` slot table), never the batch.
//!
//! A pair (sample, candidate bone) is five numbers of `pairs` `[m, 5]`: the canonical
//! point where the bone's logit is read (the host's transform of the sample, x y z), the
//! bone (its channel of the volume, exact in f32) and the posed-space prior's logit. The
//! logit is the volume's trilinear read there plus the prior; the weights are a softmax
//! over the sample's pairs, and `x_canonical = sum_b w_b xb_b` with `xb` the
//! differentiable canonical points `[m, 3]`. The volume's corners are the host's
//! (`BlendWeightVolume::pairs`) in f32.

use cubecl::prelude::*;

/// Numbers per pair in the `pairs` tensor.
pub(crate) const PAIR_PARAMS: usize = 5;

/// The volume's grid: its lower corner, vertices per unit length along each axis
/// (`(R - 1) / span`) and vertices per axis `R`: the seven numbers after the pairs.
#[derive(CubeType)]
struct Grid {
    min_x: f32,
    min_y: f32,
    min_z: f32,
    scale_x: f32,
    scale_y: f32,
    scale_z: f32,
    res: u32,
}

/// Numbers of the grid after the pairs.
pub(crate) const GRID_PARAMS: usize = 7;

#[cube]
fn grid_of(pairs: &Tensor<f32>, m: usize) -> Grid {
    let g = m * PAIR_PARAMS;
    Grid {
        min_x: pairs[g],
        min_y: pairs[g + 1],
        min_z: pairs[g + 2],
        scale_x: pairs[g + 3],
        scale_y: pairs[g + 4],
        scale_z: pairs[g + 5],
        res: u32::cast_from(pairs[g + 6]),
    }
}

/// Vertex coordinate and fraction along one axis: `u` clamped to `[0, R - 1]`, the cell
/// `min(floor(u), R - 2)`.
#[derive(CubeType)]
struct Axis {
    cell: u32,
    frac: f32,
}

#[cube]
fn axis_of(x: f32, min: f32, scale: f32, res: u32) -> Axis {
    let top = f32::cast_from(res - 1);
    let u = f32::max(f32::min((x - min) * scale, top), 0.0);
    let mut cell = u32::cast_from(u.floor());
    if cell > res - 2 {
        cell = res - 2;
    }
    Axis {
        cell,
        frac: u - f32::cast_from(cell),
    }
}

#[cube]
fn lerp_weight(frac: f32, upper: u32) -> f32 {
    let mut w = 1.0 - frac;
    if upper == 1 {
        w = frac;
    }
    w
}

/// Pair `p`'s corners: the volume's first row of the cell and the three fractions.
#[derive(CubeType)]
struct Corners {
    x: Axis,
    y: Axis,
    z: Axis,
    bone: u32,
}

#[cube]
fn corners_of(pairs: &Tensor<f32>, p: usize, grid: &Grid) -> Corners {
    let base = p * PAIR_PARAMS;
    Corners {
        x: axis_of(pairs[base], grid.min_x, grid.scale_x, grid.res),
        y: axis_of(pairs[base + 1], grid.min_y, grid.scale_y, grid.res),
        z: axis_of(pairs[base + 2], grid.min_z, grid.scale_z, grid.res),
        bone: u32::cast_from(pairs[base + 3]),
    }
}

/// The volume's index of corner `k` (`(k & 1, k >> 1 & 1, k >> 2)`):
/// `((bone R + z) R + y) R + x`.
#[cube]
fn corner_row(c: &Corners, k: u32, res: u32) -> usize {
    let x = c.x.cell + (k & 1);
    let y = c.y.cell + ((k >> 1) & 1);
    let z = c.z.cell + (k >> 2);
    usize::cast_from(((c.bone * res + z) * res + y) * res + x)
}

#[cube]
fn corner_weight(c: &Corners, k: u32) -> f32 {
    lerp_weight(c.x.frac, k & 1)
        * lerp_weight(c.y.frac, (k >> 1) & 1)
        * lerp_weight(c.z.frac, k >> 2)
}

/// Pair `p`'s logit: the trilinear read of its bone's channel, then its posed prior
/// (in that order: the prior of a bone without a capsule is -1e4, where an f32 holds
/// only a thousandth, so the read is summed first, as on the CPU).
#[cube]
fn pair_logit(volume: &Tensor<f32>, pairs: &Tensor<f32>, p: usize, grid: &Grid) -> f32 {
    let c = corners_of(pairs, p, grid);
    let mut l = 0.0f32;
    #[unroll]
    for k in 0..8u32 {
        l += corner_weight(&c, k) * volume[corner_row(&c, k, grid.res)];
    }
    l + pairs[p * PAIR_PARAMS + 4]
}

/// A sample's softmax over its pairs, in one pass: the largest logit, the sum of
/// `exp(l - max)` and the blend's unnormalised sum.
#[derive(CubeType)]
struct Softmax {
    max: f32,
    sum: f32,
    x: f32,
    y: f32,
    z: f32,
}

#[cube]
fn softmax_of<I: Int>(
    volume: &Tensor<f32>,
    xb: &Tensor<f32>,
    pairs: &Tensor<f32>,
    slots: &Tensor<I>,
    s: usize,
    grid: &Grid,
) -> Softmax {
    let m = xb.shape(0);
    let k = slots.shape(1);
    // Below any logit a volume holds; exp(max - l) of it is 0.
    let mut max = f32::new(-3.0e38);
    let mut sum = 0.0f32;
    let mut x = 0.0f32;
    let mut y = 0.0f32;
    let mut z = 0.0f32;
    for j in 0..k {
        let p = usize::cast_from(slots[s * k + j]);
        if p < m {
            let l = pair_logit(volume, pairs, p, grid);
            if l > max {
                // Rescale what was summed against the old maximum.
                let r = f32::exp(max - l);
                sum *= r;
                x *= r;
                y *= r;
                z *= r;
                max = l;
            }
            let e = f32::exp(l - max);
            sum += e;
            x += e * xb[p * 3];
            y += e * xb[p * 3 + 1];
            z += e * xb[p * 3 + 2];
        }
    }
    Softmax { max, sum, x, y, z }
}

/// `out[s] = sum_j w_j xb[slot(s, j)]`, one unit per sample.
#[cube(launch)]
pub(crate) fn blend_kernel<I: Int>(
    volume: &Tensor<f32>,
    xb: &Tensor<f32>,
    pairs: &Tensor<f32>,
    slots: &Tensor<I>,
    out: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let s = ABSOLUTE_POS;
    if s >= slots.shape(0) {
        terminate!();
    }
    let grid = grid_of(pairs, xb.shape(0));
    let sm = softmax_of::<I>(volume, xb, pairs, slots, s, &grid);
    let inv = 1.0 / sm.sum;
    out[s * 3] = sm.x * inv;
    out[s * 3 + 1] = sm.y * inv;
    out[s * 3 + 2] = sm.z * inv;
}

/// The blend's backward, one unit per sample: `d xb_j = w_j g` (each pair is one
/// sample's, so written once) and `d l_j = w_j (g . xb_j - g . x)`, spread over the
/// pair's eight volume corners by atomic float adds (into a zeroed volume gradient).
#[cube(launch)]
pub(crate) fn blend_backward_kernel<I: Int>(
    volume: &Tensor<f32>,
    xb: &Tensor<f32>,
    pairs: &Tensor<f32>,
    slots: &Tensor<I>,
    grad_out: &Tensor<f32>,
    grad_volume: &mut Tensor<Atomic<f32>>,
    grad_xb: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let s = ABSOLUTE_POS;
    if s >= slots.shape(0) {
        terminate!();
    }
    let grid = grid_of(pairs, xb.shape(0));
    let m = xb.shape(0);
    let k = slots.shape(1);
    let sm = softmax_of::<I>(volume, xb, pairs, slots, s, &grid);
    let inv = 1.0 / sm.sum;
    let (gx, gy, gz) = (grad_out[s * 3], grad_out[s * 3 + 1], grad_out[s * 3 + 2]);
    let g_dot_x = (gx * sm.x + gy * sm.y + gz * sm.z) * inv;
    for j in 0..k {
        let p = usize::cast_from(slots[s * k + j]);
        if p < m {
            let w = f32::exp(pair_logit(volume, pairs, p, &grid) - sm.max) * inv;
            grad_xb[p * 3] = w * gx;
            grad_xb[p * 3 + 1] = w * gy;
            grad_xb[p * 3 + 2] = w * gz;
            let g_dot_xb = gx * xb[p * 3] + gy * xb[p * 3 + 1] + gz * xb[p * 3 + 2];
            let dl = w * (g_dot_xb - g_dot_x);
            let c = corners_of(pairs, p, &grid);
            #[unroll]
            for corner in 0..8u32 {
                grad_volume[corner_row(&c, corner, grid.res)]
                    .fetch_add(corner_weight(&c, corner) * dl);
            }
        }
    }
}
