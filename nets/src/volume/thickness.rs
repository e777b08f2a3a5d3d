//! How thick the rendered matter is along each ray: the spread of the compositing
//! weights over depth. A surface puts a ray's weight within a few millimetres; a cloud
//! spreads it over centimetres, and renders translucent and mottled wherever frames
//! disagree.
//!
//! Depths are measured from each ray's first sample, so that `f32` keeps the spread's
//! millimetres: from the camera, `t^2` near 10 m^2 would leave about 1e-6 m^2 of precision
//! in `E[t^2] - E[t]^2`, a spread of a millimetre.

use burn::prelude::*;

use super::RaySamples;
use crate::util::floats;

/// Per sample `[1, d, d^2]`, with `d` its midpoint's depth past its ray's first sample
/// start (metres). `[n, 3]`
pub fn depth_columns(samples: &RaySamples, device: &Device) -> Tensor<2> {
    let mut columns = Vec::with_capacity(3 * samples.n_samples());
    for ray in samples.offsets.windows(2) {
        let first = samples.t_start.get(ray[0]).copied().unwrap_or(0.0);
        for i in ray[0]..ray[1] {
            let d = 0.5 * (samples.t_start[i] + samples.t_end[i]) - first;
            columns.extend_from_slice(&[1.0, d, d * d]);
        }
    }
    let n = columns.len() / 3;
    floats(columns, [n, 3], device)
}

/// The weighted standard deviation of depth of one ray from its moments
/// `[sum w, sum w d, sum w d^2]` (metres; 0 for a ray with no weight).
pub fn depth_spread(moments: [f32; 3]) -> f32 {
    let [w, m1, m2] = moments.map(f64::from);
    if !(w > 0.0 && w.is_finite()) {
        return 0.0;
    }
    let mean = m1 / w;
    (m2 / w - mean * mean).max(0.0).sqrt() as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::RenderWeights;

    /// Two rays far from the camera: one with a single opaque sample (no spread), one
    /// with its weight split evenly between two samples 10 mm apart (spread 5 mm).
    #[test]
    fn a_surface_has_no_spread_and_two_layers_half_their_gap() {
        let device = Device::flex();
        let offsets = [0, 3, 5];
        let t_start = [30.0, 30.001, 30.002, 40.0, 40.01];
        let t_end = [30.001, 30.002, 30.003, 40.001, 40.011];
        let samples = RaySamples {
            offsets: &offsets,
            t_start: &t_start,
            t_end: &t_end,
        };
        // Ray 0: all the matter in its middle sample. Ray 1: alpha 1/2, then opaque.
        let sigma = floats(vec![0.0, 1e5, 0.0, 2f32.ln() * 1e3, 1e5], [5], &device);
        let weights = RenderWeights::new(sigma, &samples).unwrap();
        let moments = weights.integrate(depth_columns(&samples, &device));
        let m = moments.try_to_vec_as::<f32>().unwrap();
        assert!(depth_spread([m[0], m[1], m[2]]) < 1e-6, "{m:?}");
        let spread = depth_spread([m[3], m[4], m[5]]);
        assert!((spread - 0.005).abs() < 1e-5, "{spread}");
    }

    #[test]
    fn empty_and_non_finite_moments_spread_nothing() {
        assert_eq!(depth_spread([0.0, 0.0, 0.0]), 0.0);
        assert_eq!(depth_spread([f32::NAN, 1.0, 1.0]), 0.0);
        assert_eq!(depth_spread([f32::INFINITY, 1.0, 1.0]), 0.0);
        // Rounding that leaves E[d^2] a hair below E[d]^2 gives 0, not NaN.
        assert_eq!(depth_spread([1.0, 0.1, 0.00999999]), 0.0);
    }
}
