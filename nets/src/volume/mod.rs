//! Volume rendering of packed samples (flat arrays + per-ray offsets, samples sorted by `t`
//! within each ray).
//!
//! Transmittance is computed in log space: `T_i = exp(-sum_{j<i} tau_j)` with
//! `tau_j = sigma_j * delta_j`, the sum an *exclusive segmented scan* that never leaves its
//! ray. A global cumsum minus each ray's start value would cancel catastrophically (after
//! 100k samples of optical depth ~1 the f32 ulp of the running sum is ~0.01, so every later
//! ray's `T` would be off by a percent; after one ray with sigma = 1e6 it is meaningless).
//! The scan is a Hillis-Steele scan with per-ray masks: `ceil(log2(longest ray))` shifted
//! adds over `[n]`, so it is exact per ray and differentiable with plain tensor ops.
//! Per-sample optical depth is clamped at [`MAX_OPTICAL_DEPTH`] first: `exp(-50) = 2e-22`,
//! so the clamp changes no rendered value by more than that, and it keeps the scan finite
//! even when `sigma * delta` would overflow. `alpha = -expm1(-tau)`, using a cubic Taylor
//! branch for small `tau` where `1 - exp(-tau)` loses all digits.

use crate::error::{NetsError, check_len};
use crate::rows::add_rows;
use crate::util::{floats, ints};
use burn::prelude::*;

mod distortion;
mod hard_surface;
mod thickness;
pub use distortion::distortion;
pub use hard_surface::hard_surface;
pub use thickness::{depth_columns, depth_spread};

/// Per-sample optical depth cap (see the module docs).
pub const MAX_OPTICAL_DEPTH: f32 = 50.0;

/// Below this optical depth `alpha` uses `tau - tau^2/2 + tau^3/6` (error < tau^4/24).
const SMALL_TAU: f32 = 1e-3;

/// The packed sample layout shared by the field and the renderer.
#[derive(Clone, Copy, Debug)]
pub struct RaySamples<'a> {
    /// `[r + 1]`: ray `k` owns samples `offsets[k]..offsets[k + 1]`.
    pub offsets: &'a [usize],
    /// `[n]` interval starts along the ray.
    pub t_start: &'a [f32],
    /// `[n]` interval ends (`t_end < t_start` is treated as zero length).
    pub t_end: &'a [f32],
}

impl RaySamples<'_> {
    /// Number of rays.
    pub fn n_rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Number of samples.
    pub fn n_samples(&self) -> usize {
        self.t_start.len()
    }

    /// Checks offsets and lengths.
    pub fn validate(&self) -> Result<(), NetsError> {
        let n = self.t_start.len();
        check_len("t_end", self.t_end.len(), n)?;
        if self.offsets.is_empty() {
            return Err(NetsError::Offsets("need at least one offset (0)".into()));
        }
        if self.offsets[0] != 0 || *self.offsets.last().unwrap() != n {
            return Err(NetsError::Offsets(format!(
                "must start at 0 and end at the sample count {n}, got {}..{}",
                self.offsets[0],
                self.offsets.last().unwrap()
            )));
        }
        if let Some(k) = self.offsets.windows(2).position(|w| w[1] < w[0]) {
            return Err(NetsError::Offsets(format!("offset {} decreases", k + 1)));
        }
        if self
            .t_start
            .iter()
            .chain(self.t_end)
            .any(|t| !t.is_finite())
        {
            return Err(NetsError::NonFinite {
                what: "t_start/t_end",
            });
        }
        Ok(())
    }

    /// Ray index of every sample. `[n]`
    pub fn ray_indices(&self) -> Vec<i32> {
        let mut out = Vec::with_capacity(self.n_samples());
        for (k, w) in self.offsets.windows(2).enumerate() {
            out.extend(std::iter::repeat_n(k as i32, w[1] - w[0]));
        }
        out
    }
}

/// Per-sample compositing weights of one packed batch; integrates any per-sample feature.
#[derive(Clone, Debug)]
pub struct RenderWeights {
    /// `w_i = T_i * alpha_i`. `[n]`
    pub weights: Tensor<1>,
    /// Transmittance left at the end of each ray, `exp(-sum tau)`. `[r]`
    pub transmittance_end: Tensor<1>,
    ray_of_sample: Option<Tensor<1, Int>>,
    /// On a CubeCL device, the rays' offsets `[r + 1]`: the sums are a device op there.
    #[cfg_attr(not(feature = "wgpu"), allow(dead_code))]
    device_offsets: Option<Tensor<1, Int>>,
    n_rays: usize,
}

impl RenderWeights {
    /// Computes the weights.
    ///
    /// # Shapes
    /// - `sigma`: `[n]`, densities (>= 0)
    pub fn new(sigma: Tensor<1>, samples: &RaySamples) -> Result<Self, NetsError> {
        samples.validate()?;
        let n = samples.n_samples();
        let r = samples.n_rays();
        check_len("sigma", sigma.dims()[0], n)?;
        let device = sigma.device();
        if n == 0 {
            return Ok(Self {
                weights: Tensor::zeros([0], &device),
                transmittance_end: Tensor::ones([r], &device),
                ray_of_sample: None,
                device_offsets: None,
                n_rays: r,
            });
        }
        let delta: Vec<f32> = samples
            .t_start
            .iter()
            .zip(samples.t_end)
            .map(|(a, b)| (b - a).max(0.0))
            .collect();
        let delta = floats(delta, [n], &device);
        let tau = (sigma.clamp_min(0.0) * delta).clamp_max(MAX_OPTICAL_DEPTH); // [n]
        let ray = ints(samples.ray_indices(), &device);
        #[cfg(feature = "wgpu")]
        if !crate::device::is_cpu(&device) {
            // One unit per ray (`kernels::cube::render`) instead of the scan below.
            let offsets: Vec<i32> = samples.offsets.iter().map(|&o| o as i32).collect();
            let offsets = ints(offsets, &device);
            let (weights, transmittance_end) =
                crate::kernels::cube::render::render_weights(tau, offsets.clone(), SMALL_TAU);
            return Ok(Self {
                weights,
                transmittance_end,
                ray_of_sample: Some(ray),
                device_offsets: Some(offsets),
                n_rays: r,
            });
        }
        let depth_before = exclusive_segmented_scan(tau.clone(), samples.offsets); // [n]
        let transmittance = depth_before.neg().exp(); // [n]
        let small = tau.clone().clamp_max(SMALL_TAU);
        let taylor = small.clone()
            * (small.clone().mul_scalar(-1.0 / 6.0).add_scalar(0.5) * small.clone())
                .neg()
                .add_scalar(1.0);
        let direct = tau.clone().neg().exp().neg().add_scalar(1.0);
        let alpha = direct.mask_where(tau.clone().lower_elem(SMALL_TAU), taylor); // [n]
        let total = add_rows(Tensor::<1>::zeros([r], &device), ray.clone(), tau);
        Ok(Self {
            weights: transmittance * alpha,
            transmittance_end: total.neg().exp(),
            ray_of_sample: Some(ray),
            device_offsets: None,
            n_rays: r,
        })
    }

    /// `sum_i w_i * values_i` per ray (zero for rays without samples).
    ///
    /// # Shapes
    /// - `values`: `[n, c]`
    /// - output: `[r, c]`
    pub fn integrate(&self, values: Tensor<2>) -> Tensor<2> {
        let [_, c] = values.dims();
        let device = values.device();
        let Some(ray) = &self.ray_of_sample else {
            return Tensor::zeros([self.n_rays, c], &device);
        };
        if let Some(sums) = self.device_sums(|| values.clone(), ray) {
            return sums;
        }
        add_rows(
            Tensor::<2>::zeros([self.n_rays, c], &device),
            ray.clone(),
            values * self.weights.clone().unsqueeze_dim(1),
        )
    }

    /// `sum_i w_i` per ray. `[r]`
    pub fn opacity(&self) -> Tensor<1> {
        let device = self.weights.device();
        let Some(ray) = &self.ray_of_sample else {
            return Tensor::zeros([self.n_rays], &device);
        };
        if let Some(sums) = self.device_sums(|| floats(vec![1.0], [1, 1], &device), ray) {
            return sums.squeeze_dim::<1>(1);
        }
        add_rows(
            Tensor::<1>::zeros([self.n_rays], &device),
            ray.clone(),
            self.weights.clone(),
        )
    }

    /// On a CubeCL device, `sum_i w_i values_i` per ray as one device op
    /// (`kernels::cube::ray_sums`; `values()` `[n, c]` or one shared row `[1, c]`);
    /// elsewhere `None`.
    #[cfg_attr(not(feature = "wgpu"), allow(unused_variables))]
    fn device_sums(
        &self,
        values: impl FnOnce() -> Tensor<2>,
        ray: &Tensor<1, Int>,
    ) -> Option<Tensor<2>> {
        #[cfg(feature = "wgpu")]
        if let Some(offsets) = &self.device_offsets {
            return Some(crate::kernels::cube::ray_sums::ray_sums(
                self.weights.clone(),
                values(),
                offsets.clone(),
                ray.clone(),
            ));
        }
        None
    }
}

/// Exclusive scan of `x` within each ray (Hillis-Steele with per-ray masks).
///
/// # Shapes
/// - `x`: `[n]`, output `[n]`
pub fn exclusive_segmented_scan(x: Tensor<1>, offsets: &[usize]) -> Tensor<1> {
    let n = x.dims()[0];
    let device = x.device();
    let mut start = vec![0usize; n];
    let mut longest = 0;
    for w in offsets.windows(2) {
        start[w[0]..w[1]].fill(w[0]);
        longest = longest.max(w[1] - w[0]);
    }
    // Mask: sample i may add the value `shift` places back iff that is in its own ray.
    let mask = |shift: usize| {
        let m: Vec<f32> = (0..n)
            .map(|i| (i >= start[i] + shift) as u8 as f32)
            .collect();
        floats(m, [n], &device)
    };
    let shifted = |t: Tensor<1>, shift: usize| {
        if shift >= n {
            Tensor::zeros([n], &device)
        } else {
            Tensor::cat(
                vec![Tensor::zeros([shift], &device), t.narrow(0, 0, n - shift)],
                0,
            )
        }
    };
    // Shift by one (exclusive), then an inclusive scan of the shifted values.
    let mut acc = shifted(x, 1) * mask(1); // [n]
    let mut shift = 1;
    while shift < longest {
        acc = acc.clone() + shifted(acc, shift) * mask(shift);
        shift *= 2;
    }
    acc
}

/// An owned packed layout (e.g. the hand-routed subset of a batch).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OwnedRaySamples {
    /// `[r + 1]`
    pub offsets: Vec<usize>,
    /// `[n]`
    pub t_start: Vec<f32>,
    /// `[n]`
    pub t_end: Vec<f32>,
}

impl OwnedRaySamples {
    /// Borrowed view.
    pub fn view(&self) -> RaySamples<'_> {
        RaySamples {
            offsets: &self.offsets,
            t_start: &self.t_start,
            t_end: &self.t_end,
        }
    }

    /// The samples `subset` (sorted ascending sample indices) of `samples`, keeping every
    /// ray (rays may end up empty) and the order along each ray.
    pub fn subset(samples: &RaySamples, subset: &[usize]) -> Self {
        let mut out = Self {
            offsets: Vec::with_capacity(samples.n_rays() + 1),
            t_start: subset.iter().map(|&i| samples.t_start[i]).collect(),
            t_end: subset.iter().map(|&i| samples.t_end[i]).collect(),
        };
        out.offsets.push(0);
        let mut cursor = 0;
        for w in samples.offsets.windows(2) {
            while cursor < subset.len() && subset[cursor] < w[1] {
                cursor += 1;
            }
            out.offsets.push(cursor);
        }
        out
    }
}

/// Per-ray results of volume rendering.
#[derive(Clone, Debug)]
pub struct RenderedRays {
    /// Accumulated colour (no background). `[r, 3]`
    pub rgb: Tensor<2>,
    /// Accumulated segmentation logits. `[r, 5]` (or whatever width was rendered)
    pub seg_logits: Tensor<2>,
    /// `sum w_i`. `[r]`
    pub opacity: Tensor<1>,
    /// Expected depth `sum w_i t_mid_i` (not normalised by opacity). `[r]`
    pub depth: Tensor<1>,
}

impl RenderedRays {
    /// Colour over a constant background: `C + (1 - opacity) * bg`. `[r, 3]`
    pub fn rgb_over(&self, background: [f32; 3]) -> Tensor<2> {
        let device = self.rgb.device();
        self.rgb_over_tensor(floats(background.to_vec(), [1, 3], &device))
    }

    /// Colour over per-ray backgrounds: `C + (1 - opacity) * bg`.
    ///
    /// # Shapes
    /// - `background`: `[r, 3]` or `[1, 3]`; output `[r, 3]`
    pub fn rgb_over_tensor(&self, background: Tensor<2>) -> Tensor<2> {
        let clear = self
            .opacity
            .clone()
            .neg()
            .add_scalar(1.0)
            .unsqueeze_dim::<2>(1); // [r, 1]
        self.rgb.clone() + clear * background
    }
}

fn midpoints(samples: &RaySamples, device: &Device) -> Tensor<2> {
    let mid: Vec<f32> = samples
        .t_start
        .iter()
        .zip(samples.t_end)
        .map(|(a, b)| 0.5 * (a + b))
        .collect();
    let n = mid.len();
    floats(mid, [n, 1], device)
}

/// Renders a packed batch.
///
/// # Shapes
/// - `sigma`: `[n]`, `rgb`: `[n, 3]`, `seg_logits`: `[n, c]`
/// - outputs: see [`RenderedRays`] (`r = samples.n_rays()`)
pub fn render_packed(
    sigma: Tensor<1>,
    rgb: Tensor<2>,
    seg_logits: Tensor<2>,
    samples: &RaySamples,
) -> Result<RenderedRays, NetsError> {
    let weights = RenderWeights::new(sigma, samples)?;
    render_weighted(&weights, rgb, seg_logits, samples)
}

/// [`render_packed`] with the batch's compositing weights already computed (they also
/// give the [`distortion`]).
pub fn render_weighted(
    weights: &RenderWeights,
    rgb: Tensor<2>,
    seg_logits: Tensor<2>,
    samples: &RaySamples,
) -> Result<RenderedRays, NetsError> {
    let n = samples.n_samples();
    check_len("rgb rows", rgb.dims()[0], n)?;
    check_len("seg_logits rows", seg_logits.dims()[0], n)?;
    check_len("weights", weights.weights.dims()[0], n)?;
    let device = rgb.device();
    Ok(RenderedRays {
        rgb: weights.integrate(rgb),
        seg_logits: weights.integrate(seg_logits),
        opacity: weights.opacity(),
        depth: weights
            .integrate(midpoints(samples, &device))
            .squeeze_dim::<1>(1),
    })
}

/// Composites a sparse set of samples (the hands) in front of an already rendered
/// background (the body): `C = sum_front w_i c_i + T_end * C_behind`, and the same for
/// opacity and depth. The behind segmentation is kept as is. This is the paper's "the
/// body's accumulated colour is the hands' background at the last point of the ray".
///
/// # Shapes
/// - `sigma`: `[h]`, `rgb`: `[h, 3]` for the samples of `front` (same ray count as `behind`)
pub fn render_in_front(
    sigma: Tensor<1>,
    rgb: Tensor<2>,
    front: &RaySamples,
    behind: &RenderedRays,
) -> Result<RenderedRays, NetsError> {
    check_len("rgb rows", rgb.dims()[0], front.n_samples())?;
    check_len("rays", front.n_rays(), behind.opacity.dims()[0])?;
    let device = rgb.device();
    let weights = RenderWeights::new(sigma, front)?;
    let t_end = weights.transmittance_end.clone(); // [r]
    let t_end2 = t_end.clone().unsqueeze_dim::<2>(1); // [r, 1]
    Ok(RenderedRays {
        rgb: weights.integrate(rgb) + t_end2 * behind.rgb.clone(),
        seg_logits: behind.seg_logits.clone(),
        opacity: weights.opacity() + t_end.clone() * behind.opacity.clone(),
        depth: weights
            .integrate(midpoints(front, &device))
            .squeeze_dim::<1>(1)
            + t_end * behind.depth.clone(),
    })
}

#[cfg(test)]
mod tests;
