//! The hash encoding's CubeCL kernels: forward, the table's gradient and the points'
//! gradient. Every unit works on one (point, level) or one point; none walks the batch.
//!
//! A level is five numbers of the `levels` tensor (f32, every value below 2^24 so exact):
//! cells per axis, first table row, rows, vertices per axis (0 on a hashed level) and the
//! identity's block shift of a dense level. The indexing is `hash_grid::CellRows`' in u32
//! arithmetic (a hashed level's products wrap, as they do on the host).

use cubecl::prelude::*;

use crate::encoding::hash_primes::PRIMES;

const P0: u32 = PRIMES[0];
const P1: u32 = PRIMES[1];
const P2: u32 = PRIMES[2];
/// Numbers per level in the `levels` tensor.
pub(crate) const LEVEL_PARAMS: usize = 5;

/// One level's numbers (see the module docs).
#[derive(CubeType)]
struct Level {
    /// Cells per axis.
    res: f32,
    offset: u32,
    size: u32,
    /// Vertices per axis on a dense level, 0 on a hashed one.
    res1: u32,
    shift: u32,
}

#[cube]
fn level_of(levels: &Tensor<f32>, level: usize) -> Level {
    let base = level * LEVEL_PARAMS;
    Level {
        res: levels[base],
        offset: u32::cast_from(levels[base + 1]),
        size: u32::cast_from(levels[base + 2]),
        res1: u32::cast_from(levels[base + 3]),
        shift: u32::cast_from(levels[base + 4]),
    }
}

/// One level's cell of a point: lower corner and the fraction inside the cell, per axis.
#[derive(CubeType)]
struct Cell {
    x: u32,
    y: u32,
    z: u32,
    fx: f32,
    fy: f32,
    fz: f32,
}

/// The cell of point `p` (`points` `[n, 3]`) on level `lv`.
#[cube]
fn cell_of(points: &Tensor<f32>, p: usize, lv: &Level) -> Cell {
    let res = lv.res;
    let (qx, qy, qz) = (
        points[p * 3] * res,
        points[p * 3 + 1] * res,
        points[p * 3 + 2] * res,
    );
    let top = res - 1.0;
    let cx = f32::max(f32::min(qx.floor(), top), 0.0);
    let cy = f32::max(f32::min(qy.floor(), top), 0.0);
    let cz = f32::max(f32::min(qz.floor(), top), 0.0);
    Cell {
        x: u32::cast_from(cx),
        y: u32::cast_from(cy),
        z: u32::cast_from(cz),
        fx: qx - cx,
        fy: qy - cy,
        fz: qz - cz,
    }
}

/// First table element of corner `k` (`(k & 1, k >> 1 & 1, k >> 2)`) of cell `c`: its row
/// times `n_features`. Hashed unless the level has vertices per axis; the dense index
/// wraps once at most.
#[cube]
fn corner_base(c: &Cell, lv: &Level, k: u32, id_hash: u32, #[comptime] n_features: usize) -> usize {
    let (x, y, z) = (c.x + (k & 1), c.y + ((k >> 1) & 1), c.z + (k >> 2));
    let h = (x * P0) ^ (y * P1) ^ (z * P2) ^ id_hash;
    let mut local = h & (lv.size - 1);
    if lv.res1 > 0 {
        local = x + lv.res1 * (y + lv.res1 * z) + lv.shift;
        if local >= lv.size {
            local -= lv.size;
        }
    }
    usize::cast_from(lv.offset + local) * n_features
}

/// Trilinear weight of corner `k` of cell `c`.
#[cube]
fn corner_weight(c: &Cell, k: u32) -> f32 {
    axis_weight(c.fx, k & 1) * axis_weight(c.fy, (k >> 1) & 1) * axis_weight(c.fz, k >> 2)
}

#[cube]
fn axis_weight(f: f32, d: u32) -> f32 {
    let mut w = 1.0 - f;
    if d == 1 {
        w = f;
    }
    w
}

/// d(axis weight)/d(fraction): +1 for the upper vertex, -1 for the lower.
#[cube]
fn axis_sign(d: u32) -> f32 {
    f32::cast_from(2 * d) - 1.0
}

/// `out[p, level F + j] = sum_k w_k table[row_k, j]`, one unit per (point, level); each
/// output is summed in a register and written once.
#[cube(launch)]
pub(crate) fn encode_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    levels: &Tensor<f32>,
    out: &mut Tensor<f32>,
    id_hash: u32,
    #[comptime] n_levels: usize,
    #[comptime] n_features: usize,
) {
    if ABSOLUTE_POS >= points.shape(0) * n_levels {
        terminate!();
    }
    let p = ABSOLUTE_POS / n_levels;
    let level = ABSOLUTE_POS % n_levels;
    let lv = level_of(levels, level);
    let c = cell_of(points, p, &lv);
    let out_base = p * n_levels * n_features + level * n_features;
    #[unroll]
    for j in 0..n_features {
        let mut acc = 0.0f32;
        #[unroll]
        for k in 0..8u32 {
            let row = corner_base(&c, &lv, k, id_hash, n_features);
            acc += corner_weight(&c, k) * table[row + j];
        }
        out[out_base + j] = acc;
    }
}

/// The table's gradient: every (point, level) adds `w_k grad[p, level, j]` to its 8 rows
/// with atomic float adds (into a zeroed `[rows, F]`).
#[cube(launch)]
pub(crate) fn table_grad_kernel(
    points: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<f32>,
    table_grad: &mut Tensor<Atomic<f32>>,
    id_hash: u32,
    #[comptime] n_levels: usize,
    #[comptime] n_features: usize,
) {
    if ABSOLUTE_POS >= points.shape(0) * n_levels {
        terminate!();
    }
    let p = ABSOLUTE_POS / n_levels;
    let level = ABSOLUTE_POS % n_levels;
    let lv = level_of(levels, level);
    let c = cell_of(points, p, &lv);
    let g_base = p * n_levels * n_features + level * n_features;
    #[unroll]
    for k in 0..8u32 {
        let row = corner_base(&c, &lv, k, id_hash, n_features);
        let w = corner_weight(&c, k);
        #[unroll]
        for j in 0..n_features {
            table_grad[row + j].fetch_add(w * grad[g_base + j]);
        }
    }
}

/// The points' gradient, one unit per point over its levels: `d out / d p` is the
/// cell's resolution times the weights' derivative by the fraction (the cell's corner is
/// piecewise constant, as in the composed ops).
#[cube(launch)]
pub(crate) fn point_grad_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<f32>,
    point_grad: &mut Tensor<f32>,
    id_hash: u32,
    #[comptime] n_levels: usize,
    #[comptime] n_features: usize,
) {
    let p = ABSOLUTE_POS;
    if p >= points.shape(0) {
        terminate!();
    }
    let mut gx = 0.0f32;
    let mut gy = 0.0f32;
    let mut gz = 0.0f32;
    for level in 0..n_levels {
        let lv = level_of(levels, level);
        let c = cell_of(points, p, &lv);
        let g_base = p * n_levels * n_features + level * n_features;
        let mut lx = 0.0f32;
        let mut ly = 0.0f32;
        let mut lz = 0.0f32;
        #[unroll]
        for k in 0..8u32 {
            let row = corner_base(&c, &lv, k, id_hash, n_features);
            // sum_j grad[p, level, j] table[row, j]: how much this corner's weight matters.
            let mut s = 0.0f32;
            #[unroll]
            for j in 0..n_features {
                s += grad[g_base + j] * table[row + j];
            }
            let (dx, dy, dz) = (k & 1, (k >> 1) & 1, k >> 2);
            let wx = axis_weight(c.fx, dx);
            let wy = axis_weight(c.fy, dy);
            let wz = axis_weight(c.fz, dz);
            lx += s * axis_sign(dx) * wy * wz;
            ly += s * axis_sign(dy) * wx * wz;
            lz += s * axis_sign(dz) * wx * wy;
        }
        // The fraction moves `res` per unit of the point.
        gx += lv.res * lx;
        gy += lv.res * ly;
        gz += lv.res * lz;
    }
    point_grad[p * 3] = gx;
    point_grad[p * 3 + 1] = gy;
    point_grad[p * 3 + 2] = gz;
}
