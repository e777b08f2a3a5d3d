//! A ReLU MLP's CubeCL kernels: the forward and the deltas one unit per row, each weight's
//! gradient as partial sums over chunks of rows (a cube per chunk, through shared memory)
//! and then their sum over the chunks, one unit per weight. None walks the batch.
//!
//! Layouts: the input `x` `[n, d_in]` and the output and its gradient `[n, d_out]` are
//! row-major; the hidden activations (after ReLU) and their deltas (the loss's gradient
//! by the layer's pre-activation) are `[depth, width, n]`, a layer's unit `j` of row `r`
//! at `(layer width + j) n + r`, so the units of a warp (consecutive rows) touch
//! consecutive floats. Weights are burn's `[d_in, d_out]` row-major; the hidden layers
//! after the first are stacked `[depth - 1, width, width]`. A unit's running sums are
//! arrays indexed only by unrolled loops, so they stay in registers.

use cubecl::prelude::*;

/// `out = relu(... relu([x, row] W_first + b_first) W_mid ...) W_last + b_last` with the
/// shared `row` `[1, d_row]` repeated on every row of `x`, keeping every hidden layer's
/// activations in `hidden`; one unit per row. Each cube first folds the row's product
/// and the first bias into one bias in shared memory (`W_first`'s last `d_row` rows).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn forward_kernel(
    x: &Tensor<f32>,
    row: &Tensor<f32>,
    w_first: &Tensor<f32>,
    b_first: &Tensor<f32>,
    w_mid: &Tensor<f32>,
    b_mid: &Tensor<f32>,
    w_last: &Tensor<f32>,
    b_last: &Tensor<f32>,
    hidden: &mut Tensor<f32>,
    out: &mut Tensor<f32>,
    #[comptime] d_in: usize,
    #[comptime] width: usize,
    #[comptime] d_out: usize,
) {
    let n = x.shape(0);
    let d_row = row.shape(1);
    let mut bias = Shared::<[f32]>::new_slice(width);
    let mut j = UNIT_POS as usize;
    while j < width {
        let mut b = 0.0f32;
        for k in 0..d_row {
            b += row[k] * w_first[(d_in + k) * width + j];
        }
        bias[j] = b + b_first[j];
        j += CUBE_DIM as usize;
    }
    sync_cube();
    let r = ABSOLUTE_POS;
    if r >= n {
        terminate!();
    }
    let n_mid = w_mid.shape(0);
    let mut acc = Array::<f32>::new(width);
    #[unroll]
    for j in 0..width {
        acc[j] = bias[j];
    }
    for i in 0..d_in {
        add_scaled(&mut acc, x[r * d_in + i], w_first, i * width, 1, width);
    }
    store_relu(&acc, hidden, r, n, width);
    for m in 0..n_mid {
        let below = m * width * n;
        load(&mut acc, b_mid, m * width, width);
        for i in 0..width {
            let h = hidden[below + i * n + r];
            add_scaled(&mut acc, h, w_mid, (m * width + i) * width, 1, width);
        }
        store_relu(&acc, hidden, below + width * n + r, n, width);
    }
    let top = n_mid * width * n;
    let mut o = Array::<f32>::new(d_out);
    load(&mut o, b_last, 0, d_out);
    for i in 0..width {
        add_scaled(&mut o, hidden[top + i * n + r], w_last, i * d_out, 1, d_out);
    }
    #[unroll]
    for k in 0..d_out {
        out[r * d_out + k] = o[k];
    }
}

/// `acc[k] = t[start + k]` for `k < len`.
#[cube]
fn load(acc: &mut Array<f32>, t: &Tensor<f32>, start: usize, #[comptime] len: usize) {
    #[unroll]
    for k in 0..len {
        acc[k] = t[start + k];
    }
}

/// `acc[k] += a w[start + k step]` for `k < len`: a row (`step` 1) or a column (`step` the
/// row length) of a weight, scaled.
#[cube]
fn add_scaled(
    acc: &mut Array<f32>,
    a: f32,
    w: &Tensor<f32>,
    start: usize,
    step: usize,
    #[comptime] len: usize,
) {
    #[unroll]
    for k in 0..len {
        acc[k] += a * w[start + k * step];
    }
}

/// A hidden layer's activations `relu(acc[j])` at `at + j n`.
#[cube]
fn store_relu(
    acc: &Array<f32>,
    hidden: &mut Tensor<f32>,
    at: usize,
    n: usize,
    #[comptime] width: usize,
) {
    #[unroll]
    for j in 0..width {
        hidden[at + j * n] = f32::max(acc[j], 0.0);
    }
}

/// `acc[k] = 0` for `k < len`.
#[cube]
fn zero(acc: &mut Array<f32>, #[comptime] len: usize) {
    #[unroll]
    for k in 0..len {
        acc[k] = 0.0;
    }
}

/// Writes `acc[j]` where the layer's activation is positive and 0 elsewhere (ReLU's
/// backward, as burn's: the gradient passes where the output is above 0) at `at + j n`.
#[cube]
fn store_masked(
    acc: &Array<f32>,
    hidden: &Tensor<f32>,
    delta: &mut Tensor<f32>,
    at: usize,
    n: usize,
    #[comptime] width: usize,
) {
    #[unroll]
    for j in 0..width {
        let p = at + j * n;
        let mut d = 0.0f32;
        if hidden[p] > 0.0 {
            d = acc[j];
        }
        delta[p] = d;
    }
}

/// From the output's gradient `grad` `[n, d_out]`: every hidden layer's delta into `delta`
/// and the input's gradient into `grad_x` `[n, d_in]`; one unit per row.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn delta_kernel(
    grad: &Tensor<f32>,
    w_first: &Tensor<f32>,
    w_mid: &Tensor<f32>,
    w_last: &Tensor<f32>,
    hidden: &Tensor<f32>,
    delta: &mut Tensor<f32>,
    grad_x: &mut Tensor<f32>,
    #[comptime] d_in: usize,
    #[comptime] width: usize,
    #[comptime] d_out: usize,
) {
    let n = grad.shape(0);
    let r = ABSOLUTE_POS;
    if r >= n {
        terminate!();
    }
    let n_mid = w_mid.shape(0);
    let mut acc = Array::<f32>::new(width);
    zero(&mut acc, width);
    for k in 0..d_out {
        add_scaled(&mut acc, grad[r * d_out + k], w_last, k, d_out, width);
    }
    store_masked(&acc, hidden, delta, n_mid * width * n + r, n, width);
    for step in 0..n_mid {
        let m = n_mid - 1 - step;
        let above = (m + 1) * width * n;
        zero(&mut acc, width);
        for j in 0..width {
            let d = delta[above + j * n + r];
            add_scaled(&mut acc, d, w_mid, m * width * width + j, width, width);
        }
        store_masked(&acc, hidden, delta, m * width * n + r, n, width);
    }
    let mut gx = Array::<f32>::new(d_in);
    zero(&mut gx, d_in);
    for j in 0..width {
        add_scaled(&mut gx, delta[j * n + r], w_first, j, width, d_in);
    }
    #[unroll]
    for i in 0..d_in {
        grad_x[r * d_in + i] = gx[i];
    }
}

/// Where layer `l`'s weight and bias gradients start among every layer's entries: the
/// first layer's `(d_in + 1) width` (its weight `[d_in, width]` row-major, then its bias),
/// then each middle layer's `(width + 1) width`, then the last's `(width + 1) d_out`.
#[cube]
fn layer_start(l: usize, #[comptime] d_in: usize, #[comptime] width: usize) -> usize {
    let later = (d_in + 1) * width + (l - 1) * (width + 1) * width;
    select(l > 0, later, 0)
}

/// Every layer's weight and bias gradients over one chunk of rows: cube `(c, l)` sums,
/// into entry `layer_start(l) + i d_dim + j` of `partial[c]`, `a[i, r] d[j, r]`
/// (`i < a_dim`, the weight) or `d[j, r]` (`i = a_dim`, the bias) over the chunk's rows
/// `r` in `[c rows, (c + 1) rows)`, where `a` is layer `l`'s input (`x` or a hidden
/// layer) and `d` its delta (a hidden layer's or the output's `grad`). Tiles of `tile`
/// rows go through shared memory (rows of `tile + 1` floats: an odd stride). Each unit
/// keeps `per_unit` blocks of 4 x 4 entries in registers, four consecutive `i` by four
/// `j` strided by the layer's column groups (`ceil(d_dim / 4)`), so that the units of a
/// warp (consecutive column groups) read one input row together and distinct delta rows,
/// in distinct banks: 8 shared reads feed 16 products. `a_rows` and `d_rows` are the
/// widest input (with the bias's row) and delta rounded up to fours, the shared rows kept.
#[cube(launch)]
// Kernel code: `usize::div_ceil` has no cube expansion.
#[allow(clippy::too_many_arguments, clippy::manual_div_ceil)]
pub(crate) fn weight_partial_kernel(
    x: &Tensor<f32>,
    hidden: &Tensor<f32>,
    delta: &Tensor<f32>,
    grad: &Tensor<f32>,
    partial: &mut Tensor<f32>,
    chunk_rows: u32,
    #[comptime] d_in: usize,
    #[comptime] width: usize,
    #[comptime] d_out: usize,
    #[comptime] a_rows: usize,
    #[comptime] d_rows: usize,
    #[comptime] tile: usize,
    #[comptime] units: usize,
    #[comptime] per_unit: usize,
) {
    let stride = tile + 1;
    let n = x.shape(0);
    let last = hidden.shape(0) / width;
    let unit = UNIT_POS_X as usize;
    let c = CUBE_POS_X as usize;
    let l = CUBE_POS_Y as usize;
    let total = partial.shape(1);
    let a_dim = select(l == 0, d_in, width);
    let d_dim = select(l == last, d_out, width);
    // Column groups and blocks of this layer.
    let groups = (d_dim + 3) / 4;
    let blocks = (a_dim + 4) / 4 * groups;
    let out_at = c * total + layer_start(l, d_in, width);
    let first = c * chunk_rows as usize;
    let end = usize::min(first + chunk_rows as usize, n);
    let mut s_a = Shared::<[f32]>::new_slice(a_rows * stride);
    let mut s_d = Shared::<[f32]>::new_slice(d_rows * stride);
    // The bias's input is 1 on every row (rows past the end have a zero delta); the
    // padding rows past it and past the deltas stay 0.
    let mut e = unit;
    while e < a_rows * tile {
        let i = e / tile;
        s_a[i * stride + e % tile] = select(i == a_dim, 1.0f32, 0.0f32);
        e += units;
    }
    let mut e = unit;
    while e < d_rows * tile {
        s_d[(e / tile) * stride + e % tile] = 0.0f32;
        e += units;
    }
    sync_cube();
    let mut acc = Array::<f32>::new(per_unit * 16);
    zero(&mut acc, per_unit * 16);
    let mut start = first;
    while start < end {
        // Consecutive units read consecutive floats: along a row of `x` or `grad`, along
        // the rows of a hidden layer.
        let mut e = unit;
        while e < a_dim * tile {
            let mut v = 0.0f32;
            if l == 0 {
                let (i, t) = (e % a_dim, e / a_dim);
                if start + t < end {
                    v = x[(start + t) * d_in + i];
                }
                s_a[i * stride + t] = v;
            } else {
                let (i, t) = (e / tile, e % tile);
                if start + t < end {
                    v = hidden[((l - 1) * width + i) * n + start + t];
                }
                s_a[i * stride + t] = v;
            }
            e += units;
        }
        let mut e = unit;
        while e < d_dim * tile {
            let mut v = 0.0f32;
            if l == last {
                let (j, t) = (e % d_dim, e / d_dim);
                if start + t < end {
                    v = grad[(start + t) * d_out + j];
                }
                s_d[j * stride + t] = v;
            } else {
                let (j, t) = (e / tile, e % tile);
                if start + t < end {
                    v = delta[(l * width + j) * n + start + t];
                }
                s_d[j * stride + t] = v;
            }
            e += units;
        }
        sync_cube();
        #[unroll]
        for q in 0..per_unit {
            let block = unit + q * units;
            if block < blocks {
                let a_row = (block / groups) * 4 * stride;
                let d_row = (block % groups) * stride;
                let d_step = groups * stride;
                for t in 0..tile {
                    let mut av = Array::<f32>::new(4usize);
                    let mut dv = Array::<f32>::new(4usize);
                    #[unroll]
                    for k in 0..4 {
                        av[k] = s_a[a_row + k * stride + t];
                        dv[k] = s_d[d_row + k * d_step + t];
                    }
                    #[unroll]
                    for ki in 0..4 {
                        #[unroll]
                        for kj in 0..4 {
                            acc[q * 16 + ki * 4 + kj] += av[ki] * dv[kj];
                        }
                    }
                }
            }
        }
        sync_cube();
        start += tile;
    }
    #[unroll]
    for q in 0..per_unit {
        let block = unit + q * units;
        if block < blocks {
            let i0 = (block / groups) * 4;
            let j0 = block % groups;
            #[unroll]
            for ki in 0..4 {
                #[unroll]
                for kj in 0..4 {
                    let i = i0 + ki;
                    let j = j0 + kj * groups;
                    if i <= a_dim && j < d_dim {
                        partial[out_at + i * d_dim + j] = acc[q * 16 + ki * 4 + kj];
                    }
                }
            }
        }
    }
}

/// The chunks' partial sums (`partial` `[chunks, entries]`, laid out as
/// [`layer_start`] says) summed in chunk order, one unit per entry, each into its
/// gradient: the first layer's weight and bias, the stacked middle layers', the last's.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn weight_sum_kernel(
    partial: &Tensor<f32>,
    w_first: &mut Tensor<f32>,
    b_first: &mut Tensor<f32>,
    w_mid: &mut Tensor<f32>,
    b_mid: &mut Tensor<f32>,
    w_last: &mut Tensor<f32>,
    b_last: &mut Tensor<f32>,
    #[comptime] d_in: usize,
    #[comptime] width: usize,
    #[comptime] d_out: usize,
) {
    let chunks = partial.shape(0);
    let total = partial.shape(1);
    let e = ABSOLUTE_POS;
    if e >= total {
        terminate!();
    }
    let mut s = 0.0f32;
    for c in 0..chunks {
        s += partial[c * total + e];
    }
    let first = (d_in + 1) * width;
    let middle = (width + 1) * width;
    let n_mid = w_mid.shape(0);
    if e < first {
        if e < d_in * width {
            w_first[e] = s;
        } else {
            b_first[e - d_in * width] = s;
        }
    } else if e < first + n_mid * middle {
        let m = (e - first) / middle;
        let k = (e - first) % middle;
        if k < width * width {
            w_mid[m * width * width + k] = s;
        } else {
            b_mid[m * width + k - width * width] = s;
        }
    } else {
        let k = e - first - n_mid * middle;
        if k < width * d_out {
            w_last[k] = s;
        } else {
            b_last[k - width * d_out] = s;
        }
    }
}

/// The shared row's gradients from the first layer's bias gradient `b_grad` (`[1, width]`,
/// the sum of the first layer's deltas over every row): `W_first`'s row part
/// `row^T b_grad` into `w_grad`'s last `d_row` rows, and `b_grad W_row^T` into `row_grad`
/// `[1, d_row]`; one unit per entry.
#[cube(launch)]
pub(crate) fn row_grad_kernel(
    row: &Tensor<f32>,
    w_first: &Tensor<f32>,
    b_grad: &Tensor<f32>,
    w_grad: &mut Tensor<f32>,
    row_grad: &mut Tensor<f32>,
    #[comptime] d_in: usize,
    #[comptime] width: usize,
) {
    let d_row = row.shape(1);
    let u = ABSOLUTE_POS;
    if u < d_row * width {
        let k = u / width;
        let j = u % width;
        w_grad[(d_in + k) * width + j] = row[k] * b_grad[j];
    } else if u < d_row * width + d_row {
        let k = u - d_row * width;
        let mut s = 0.0f32;
        for j in 0..width {
            s += w_first[(d_in + k) * width + j] * b_grad[j];
        }
        row_grad[k] = s;
    }
}
