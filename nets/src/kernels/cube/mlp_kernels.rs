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

/// `out = relu(... relu(x W_first + b_first) W_mid ...) W_last + b_last`, keeping every
/// hidden layer's activations in `hidden`; one unit per row.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn forward_kernel(
    x: &Tensor<f32>,
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
    let r = ABSOLUTE_POS;
    if r >= n {
        terminate!();
    }
    let n_mid = w_mid.shape(0);
    let mut acc = Array::<f32>::new(width);
    #[unroll]
    for j in 0..width {
        acc[j] = b_first[j];
    }
    for i in 0..d_in {
        let xi = x[r * d_in + i];
        #[unroll]
        for j in 0..width {
            acc[j] += xi * w_first[i * width + j];
        }
    }
    #[unroll]
    for j in 0..width {
        hidden[j * n + r] = f32::max(acc[j], 0.0);
    }
    for m in 0..n_mid {
        let below = m * width * n;
        let above = below + width * n;
        #[unroll]
        for j in 0..width {
            acc[j] = b_mid[m * width + j];
        }
        for i in 0..width {
            let h = hidden[below + i * n + r];
            let w_row = (m * width + i) * width;
            #[unroll]
            for j in 0..width {
                acc[j] += h * w_mid[w_row + j];
            }
        }
        #[unroll]
        for j in 0..width {
            hidden[above + j * n + r] = f32::max(acc[j], 0.0);
        }
    }
    let top = n_mid * width * n;
    let mut o = Array::<f32>::new(d_out);
    #[unroll]
    for k in 0..d_out {
        o[k] = b_last[k];
    }
    for i in 0..width {
        let h = hidden[top + i * n + r];
        #[unroll]
        for k in 0..d_out {
            o[k] += h * w_last[i * d_out + k];
        }
    }
    #[unroll]
    for k in 0..d_out {
        out[r * d_out + k] = o[k];
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
    #[unroll]
    for j in 0..width {
        acc[j] = 0.0;
    }
    for k in 0..d_out {
        let g = grad[r * d_out + k];
        #[unroll]
        for j in 0..width {
            acc[j] += w_last[j * d_out + k] * g;
        }
    }
    store_masked(&acc, hidden, delta, n_mid * width * n + r, n, width);
    for step in 0..n_mid {
        let m = n_mid - 1 - step;
        let above = (m + 1) * width * n;
        #[unroll]
        for i in 0..width {
            acc[i] = 0.0;
        }
        for j in 0..width {
            let d = delta[above + j * n + r];
            #[unroll]
            for i in 0..width {
                acc[i] += w_mid[(m * width + i) * width + j] * d;
            }
        }
        store_masked(&acc, hidden, delta, m * width * n + r, n, width);
    }
    let mut gx = Array::<f32>::new(d_in);
    #[unroll]
    for i in 0..d_in {
        gx[i] = 0.0;
    }
    for j in 0..width {
        let d = delta[j * n + r];
        #[unroll]
        for i in 0..d_in {
            gx[i] += w_first[i * width + j] * d;
        }
    }
    #[unroll]
    for i in 0..d_in {
        grad_x[r * d_in + i] = gx[i];
    }
}

/// One layer's weight and bias gradients over one chunk of rows per cube: entry
/// `i d_dim + j` of `partial[c]` sums `a[i, r] d[j, r]` (`i < a_dim`, the weight) or
/// `d[j, r]` (`i = a_dim`, the bias) over rows `r` in `[c rows, (c + 1) rows)`. Tiles of
/// `tile` rows go through shared memory (rows of `tile + 1` floats: an odd stride, so the
/// units of a warp reading consecutive `j` hit different banks); each unit keeps
/// `per_unit` entries (`unit + q units`) in registers. Element `(i, r)` of the input `a`
/// is at `a_base + i a_si + r a_sr`, element `(j, r)` of the delta `d` at
/// `d_base + j d_sj + r d_sr`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn weight_partial_kernel(
    a: &Tensor<f32>,
    d: &Tensor<f32>,
    partial: &mut Tensor<f32>,
    a_base: u32,
    a_si: u32,
    a_sr: u32,
    d_base: u32,
    d_sj: u32,
    d_sr: u32,
    n: u32,
    chunk_rows: u32,
    #[comptime] a_dim: usize,
    #[comptime] d_dim: usize,
    #[comptime] tile: usize,
    #[comptime] units: usize,
    #[comptime] per_unit: usize,
) {
    let stride = tile + 1;
    let entries = (a_dim + 1) * d_dim;
    let unit = UNIT_POS_X as usize;
    let c = CUBE_POS_X as usize;
    let first = c * chunk_rows as usize;
    let end = usize::min(first + chunk_rows as usize, n as usize);
    let (a_base, a_si, a_sr) = (a_base as usize, a_si as usize, a_sr as usize);
    let (d_base, d_sj, d_sr) = (d_base as usize, d_sj as usize, d_sr as usize);
    let mut s_a = Shared::<[f32]>::new_slice((a_dim + 1) * stride);
    let mut s_d = Shared::<[f32]>::new_slice(d_dim * stride);
    // The bias's input: 1 on every row (rows past the end have a zero delta).
    let mut t = unit;
    while t < tile {
        s_a[a_dim * stride + t] = 1.0;
        t += units;
    }
    let mut acc = Array::<f32>::new(per_unit);
    #[unroll]
    for q in 0..per_unit {
        acc[q] = 0.0;
    }
    let mut start = first;
    while start < end {
        // Consecutive units take consecutive rows where the layout runs along rows,
        // consecutive columns where it runs along them.
        let mut e = unit;
        while e < a_dim * tile {
            let mut i = e / tile;
            let mut t = e % tile;
            if a_si == 1 {
                i = e % a_dim;
                t = e / a_dim;
            }
            let r = start + t;
            let mut v = 0.0f32;
            if r < end {
                v = a[a_base + i * a_si + r * a_sr];
            }
            s_a[i * stride + t] = v;
            e += units;
        }
        let mut e = unit;
        while e < d_dim * tile {
            let mut j = e / tile;
            let mut t = e % tile;
            if d_sj == 1 {
                j = e % d_dim;
                t = e / d_dim;
            }
            let r = start + t;
            let mut v = 0.0f32;
            if r < end {
                v = d[d_base + j * d_sj + r * d_sr];
            }
            s_d[j * stride + t] = v;
            e += units;
        }
        sync_cube();
        #[unroll]
        for q in 0..per_unit {
            let entry = unit + q * units;
            if entry < entries {
                let i = entry / d_dim;
                let j = entry % d_dim;
                let mut s = 0.0f32;
                for t in 0..tile {
                    s += s_a[i * stride + t] * s_d[j * stride + t];
                }
                acc[q] += s;
            }
        }
        sync_cube();
        start += tile;
    }
    #[unroll]
    for q in 0..per_unit {
        let entry = unit + q * units;
        if entry < entries {
            partial[c * entries + entry] = acc[q];
        }
    }
}

/// The chunks' partial sums of one layer (`partial` `[chunks, (a_dim + 1) d_dim]`) summed
/// in chunk order, one unit per entry: the weight's gradient into `w_grad` from `w_at`,
/// the bias's into `b_grad` from `b_at`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn weight_sum_kernel(
    partial: &Tensor<f32>,
    w_grad: &mut Tensor<f32>,
    b_grad: &mut Tensor<f32>,
    w_at: u32,
    b_at: u32,
    chunks: u32,
    #[comptime] a_dim: usize,
    #[comptime] d_dim: usize,
) {
    let entries = (a_dim + 1) * d_dim;
    let e = ABSOLUTE_POS;
    if e >= entries {
        terminate!();
    }
    let mut s = 0.0f32;
    for c in 0..chunks as usize {
        s += partial[c * entries + e];
    }
    if e < a_dim * d_dim {
        w_grad[w_at as usize + e] = s;
    } else {
        b_grad[b_at as usize + e - a_dim * d_dim] = s;
    }
}
