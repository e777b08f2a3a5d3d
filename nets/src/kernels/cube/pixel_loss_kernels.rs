//! The pixel loss's per-ray terms: one unit per ray (its three colours and a handful of
//! label logits), never a loop over the batch.
//!
//! Per ray: the squared error of the colour over the background
//! `sum_c (rgb_c + (1 - o) bg_c - target_c)^2`, the labels' cross-entropy
//! `logsumexp(l) - l[label]` (shifted by the largest logit), and the silhouette term
//! `(o s - p s)^2` (`s` the ray's silhouette weight, `p` 1 on the person's labels).

use cubecl::prelude::*;

/// Channel `c` of ray `r`'s colour over the background, less the truth.
#[cube]
fn colour_error(
    rgb: &Tensor<f32>,
    target: &Tensor<f32>,
    background: &Tensor<f32>,
    clear: f32,
    r: usize,
    c: usize,
) -> f32 {
    rgb[r * 3 + c] + clear * background[c] - target[r * 3 + c]
}

/// The largest of the logits in `row..row + classes`.
#[cube]
fn top_logit(seg: &Tensor<f32>, row: usize, classes: usize) -> f32 {
    let mut top = seg[row];
    for j in 1..classes {
        top = f32::max(top, seg[row + j]);
    }
    top
}

/// `sum_j exp(l_j - top)` over the logits in `row..row + classes`.
#[cube]
fn shifted_exp_sum(seg: &Tensor<f32>, row: usize, classes: usize, top: f32) -> f32 {
    let mut total = 0.0f32;
    for j in 0..classes {
        total += f32::exp(seg[row + j] - top);
    }
    total
}

/// The silhouette's gap `o s - p s`, `p` 1 on the person's labels (> 0).
#[cube]
fn silhouette_gap(o: f32, s: f32, label: usize) -> f32 {
    let person = select(label > 0, 1.0f32, 0.0f32);
    o * s - person * s
}

/// `terms[r] = [squared error, cross-entropy, silhouette term]`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_terms_kernel<I: Int>(
    rgb: &Tensor<f32>,
    opacity: &Tensor<f32>,
    seg: &Tensor<f32>,
    target: &Tensor<f32>,
    labels: &Tensor<I>,
    sure: &Tensor<f32>,
    background: &Tensor<f32>,
    terms: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let r = ABSOLUTE_POS;
    if r >= opacity.len() {
        terminate!();
    }
    let o = opacity[r];
    let clear = 1.0 - o;
    let mut squared = 0.0f32;
    for c in 0..3usize {
        let d = colour_error(rgb, target, background, clear, r, c);
        squared += d * d;
    }
    let classes = seg.shape(1);
    let row = r * classes;
    let label = usize::cast_from(labels[r]);
    let top = top_logit(seg, row, classes);
    let total = shifted_exp_sum(seg, row, classes, top);
    let a = silhouette_gap(o, sure[r], label);
    terms[r * 3] = squared;
    terms[r * 3 + 1] = top + f32::ln(total) - seg[row + label];
    terms[r * 3 + 2] = a * a;
}

/// The colour's, opacity's and logits' gradients for the terms' gradient `grad` `[r, 3]`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_terms_backward_kernel<I: Int>(
    rgb: &Tensor<f32>,
    opacity: &Tensor<f32>,
    seg: &Tensor<f32>,
    target: &Tensor<f32>,
    labels: &Tensor<I>,
    sure: &Tensor<f32>,
    background: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_rgb: &mut Tensor<f32>,
    grad_opacity: &mut Tensor<f32>,
    grad_seg: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let r = ABSOLUTE_POS;
    if r >= opacity.len() {
        terminate!();
    }
    let (g_squared, g_entropy, g_mask) = (grad[r * 3], grad[r * 3 + 1], grad[r * 3 + 2]);
    let o = opacity[r];
    let clear = 1.0 - o;
    let mut g_o = 0.0f32;
    for c in 0..3usize {
        let g = g_squared * 2.0 * colour_error(rgb, target, background, clear, r, c);
        grad_rgb[r * 3 + c] = g;
        g_o -= g * background[c];
    }
    let label = usize::cast_from(labels[r]);
    let s = sure[r];
    grad_opacity[r] = g_o + g_mask * 2.0 * silhouette_gap(o, s, label) * s;
    let classes = seg.shape(1);
    let row = r * classes;
    let top = top_logit(seg, row, classes);
    let total = shifted_exp_sum(seg, row, classes, top);
    for j in 0..classes {
        let p = f32::exp(seg[row + j] - top) / total;
        grad_seg[row + j] = g_entropy * (p - select(j == label, 1.0f32, 0.0f32));
    }
}
