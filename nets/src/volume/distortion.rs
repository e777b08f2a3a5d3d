//! Mip-NeRF 360's distortion loss on packed samples: per ray
//! `sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 delta_i` (`m` the interval midpoints,
//! `delta` their lengths, metres). It is small when a ray's weight sits in one short
//! stretch (a surface) and large when it is spread along the ray (a cloud).
//!
//! Within a ray the samples are sorted by `t`, so the double sum is
//! `2 sum_i w_i (m_i W_i - S_i)` with `W_i`, `S_i` the exclusive in-ray sums of `w` and
//! `w m`: two segmented scans, linear in the samples.

use burn::prelude::*;

use super::{RaySamples, RenderWeights, exclusive_segmented_scan};
use crate::error::{NetsError, check_len};
use crate::util::floats;

/// The distortion of every ray of a packed batch (0 for a ray without samples), from the
/// batch's compositing `weights` (the render's own: nothing is composited twice).
///
/// # Shapes
/// - output `[r]`
pub fn distortion(weights: &RenderWeights, samples: &RaySamples) -> Result<Tensor<1>, NetsError> {
    let n = samples.n_samples();
    let w = weights.weights.clone(); // [n]
    check_len("weights", w.dims()[0], n)?;
    if n == 0 {
        return Ok(weights.opacity());
    }
    let device = w.device();
    let (mid, delta): (Vec<f32>, Vec<f32>) = samples
        .t_start
        .iter()
        .zip(samples.t_end)
        .map(|(&a, &b)| (0.5 * (a + b), (b - a).max(0.0)))
        .unzip();
    let mid = floats(mid, [n], &device);
    let delta = floats(delta, [n], &device);
    let w_before = exclusive_segmented_scan(w.clone(), samples.offsets);
    let wm_before = exclusive_segmented_scan(w.clone() * mid.clone(), samples.offsets);
    // What multiplies each sample's own weight, 2 (m_i W_i - S_i) + w_i delta_i / 3: the
    // render's per-ray weighted sum adds them up.
    let per_weight =
        (mid * w_before - wm_before).mul_scalar(2.0) + (w * delta).mul_scalar(1.0 / 3.0);
    Ok(weights
        .integrate(per_weight.unsqueeze_dim::<2>(1))
        .squeeze_dim::<1>(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The double sum as written, in f64.
    fn reference(sigma: &[f32], samples: &RaySamples) -> Vec<f64> {
        samples
            .offsets
            .windows(2)
            .map(|o| {
                let (mut t_acc, mut w) = (0.0f64, Vec::new());
                for i in o[0]..o[1] {
                    let d = f64::from(samples.t_end[i] - samples.t_start[i]);
                    let a = 1.0 - (-f64::from(sigma[i]) * d).exp();
                    w.push(((-t_acc).exp() * a, d));
                    t_acc += f64::from(sigma[i]) * d;
                }
                let m = |i: usize| 0.5 * f64::from(samples.t_start[i] + samples.t_end[i]);
                let mut sum = 0.0;
                for (a, i) in (o[0]..o[1]).enumerate() {
                    for (b, j) in (o[0]..o[1]).enumerate() {
                        sum += w[a].0 * w[b].0 * (m(i) - m(j)).abs();
                    }
                    sum += w[a].0 * w[a].0 * w[a].1 / 3.0;
                }
                sum
            })
            .collect()
    }

    #[test]
    fn matches_the_double_sum_and_prefers_a_surface() {
        let device = Device::flex();
        // Ray 0: a cloud, its weight a quarter in each of four samples over 0.4 m; ray 1:
        // empty; ray 2: one dense sample (a surface); ray 3: a huge density behind a thin
        // one.
        let owned = crate::volume::OwnedRaySamples {
            offsets: vec![0, 4, 4, 7, 9],
            t_start: vec![0.0, 0.1, 0.2, 0.3, 0.0, 0.1, 0.2, 1.0, 1.1],
            t_end: vec![0.1, 0.2, 0.3, 0.4, 0.1, 0.2, 0.3, 1.1, 1.2],
        };
        let sigma = [
            2.876_821, 4.054_651, 6.931_472, 100.0, 0.0, 80.0, 0.0, 0.5, 1e9,
        ];
        let weights =
            RenderWeights::new(Tensor::<1>::from_floats(sigma, &device), &owned.view()).unwrap();
        let got = distortion(&weights, &owned.view())
            .unwrap()
            .try_to_vec_as::<f32>()
            .unwrap();
        let want = reference(&sigma, &owned.view());
        assert_eq!(got.len(), 4);
        for (g, w) in got.iter().zip(&want) {
            assert!((f64::from(*g) - w).abs() < 1e-5, "{got:?} against {want:?}");
        }
        assert_eq!(got[1], 0.0);
        assert!(
            got[0] > 3.0 * got[2],
            "a cloud must cost more than a surface: {got:?}"
        );
        assert!(got.iter().all(|v| v.is_finite()));
    }
}
