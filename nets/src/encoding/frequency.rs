//! Sinusoidal positional encoding (NeRF), optionally with HumanNeRF's truncated Hann window
//! that fades the high bands in as training proceeds (coarse-to-fine for deformation nets).

use burn::prelude::*;

use crate::util::floats;

/// HumanNeRF's band schedule: `alpha = n_bands * clamp((step - start) / (full - start), 0, 1)`,
/// band `j` weighted by `(1 - cos(pi * clamp(alpha - j, 0, 1))) / 2`. Before `start_step`
/// every band is off (only the raw input passes); from `full_step` on all bands are on.
#[derive(Config, Debug, Copy)]
pub struct HannWindowConfig {
    /// Step at which the first band starts to fade in.
    pub start_step: usize,
    /// Step from which all bands are fully on.
    pub full_step: usize,
}

impl HannWindowConfig {
    /// Weight of each of the `n_bands` bands at `step`.
    pub fn weights(&self, n_bands: usize, step: usize) -> Vec<f32> {
        let span = self.full_step.saturating_sub(self.start_step).max(1) as f64;
        let progress = (step as f64 - self.start_step as f64) / span;
        let alpha = n_bands as f64 * progress.clamp(0.0, 1.0);
        (0..n_bands)
            .map(|j| {
                let x = (alpha - j as f64).clamp(0.0, 1.0);
                (0.5 * (1.0 - (std::f64::consts::PI * x).cos())) as f32
            })
            .collect()
    }
}

/// Configuration of [`FrequencyEncoding`].
#[derive(Config, Debug)]
pub struct FrequencyConfig {
    /// Number of frequency bands `L`: frequencies `2^0 .. 2^(L-1)`.
    pub n_bands: usize,
    /// Coarse-to-fine window (HumanNeRF); `None` keeps every band on.
    #[config(default = "None")]
    pub window: Option<HannWindowConfig>,
}

impl FrequencyConfig {
    /// Builds the (parameter-free) encoding.
    pub fn init(&self) -> FrequencyEncoding {
        let (windowed, start, full) = match self.window {
            Some(w) => (true, w.start_step, w.full_step),
            None => (false, 0, 0),
        };
        FrequencyEncoding {
            n_bands: self.n_bands,
            windowed,
            window_start: start,
            window_full: full,
        }
    }
}

/// `gamma(x) = [x, sin(2^k x), cos(2^k x)]_{k < L}` per coordinate, no pi factor (as NeRF's
/// and HumanNeRF's code); feed coordinates in about [-1, 1].
#[derive(Module, Debug)]
pub struct FrequencyEncoding {
    n_bands: usize,
    windowed: bool,
    window_start: usize,
    window_full: usize,
}

impl FrequencyEncoding {
    /// Output width for a `d_input`-wide input: `d_input * (1 + 2 L)`.
    pub fn output_dim(&self, d_input: usize) -> usize {
        d_input * (1 + 2 * self.n_bands)
    }

    /// Band weights at `step` (all ones without a window).
    pub fn band_weights(&self, step: usize) -> Vec<f32> {
        if self.windowed {
            HannWindowConfig::new(self.window_start, self.window_full).weights(self.n_bands, step)
        } else {
            vec![1.0; self.n_bands]
        }
    }

    /// Encodes `x`.
    ///
    /// # Shapes
    /// - `x`: `[n, d]`
    /// - output: `[n, d * (1 + 2 L)]`, laid out `[x, sin (band-major), cos (band-major)]`.
    pub fn forward(&self, x: Tensor<2>, step: usize) -> Tensor<2> {
        if self.n_bands == 0 {
            return x;
        }
        let weights = self.band_weights(step);
        if let Some(fused) = crate::kernels::frequency::encode(&x, &weights) {
            return fused;
        }
        #[cfg(feature = "wgpu")]
        if x.dims()[0] > 0 && x.dims()[1] > 0 && !crate::device::is_cpu(&x.device()) {
            return crate::kernels::cube::frequency::encode(x, &weights);
        }
        self.composed(x, &weights)
    }

    /// [`FrequencyEncoding::forward`] as tensor ops (any backend; the reference of the
    /// fused op).
    fn composed(&self, x: Tensor<2>, weights: &[f32]) -> Tensor<2> {
        let [n, d] = x.dims();
        let l = self.n_bands;
        let device = x.device();
        let freqs: Vec<f32> = (0..l).map(|k| (1u64 << k) as f32).collect();
        let freqs = floats(freqs, [1, l, 1], &device); // [1, L, 1]
        let window = floats(weights.to_vec(), [1, l, 1], &device); // [1, L, 1]
        let scaled = x.clone().unsqueeze_dim::<3>(1) * freqs; // [n, L, d]
        let sin = (scaled.clone().sin() * window.clone()).reshape([n, l * d]);
        let cos = (scaled.cos() * window).reshape([n, l * d]);
        Tensor::cat(vec![x, sin, cos], 1) // [n, d (1 + 2L)]
    }
}

#[cfg(test)]
mod tests {
    use burn::tensor::TensorData;

    use super::*;

    #[test]
    fn hann_window_schedule() {
        let w = HannWindowConfig::new(100, 200);
        assert!(w.weights(6, 0).iter().all(|&v| v == 0.0));
        assert!(w.weights(6, 200).iter().all(|&v| (v - 1.0).abs() < 1e-6));
        let mid = w.weights(6, 150); // alpha = 3: bands 0..3 on, 3.. off
        assert!((mid[0] - 1.0).abs() < 1e-6 && (mid[2] - 1.0).abs() < 1e-6);
        assert!(mid[3].abs() < 1e-6 && mid[5].abs() < 1e-6);
    }

    #[test]
    fn encodes_sin_cos_of_powers_of_two() {
        let device = Device::flex();
        let enc = FrequencyConfig::new(3).init();
        let x = Tensor::<2>::from_floats([[0.3, -0.2]], &device);
        let y = crate::util::host(&enc.forward(x, 0));
        assert_eq!(y.len(), enc.output_dim(2));
        // sin block starts after the raw input: band 2 (freq 4) of coordinate 1.
        assert!((y[2 + 2 * 2 + 1] - (4.0f32 * -0.2).sin()).abs() < 1e-6);
        assert!((y[2 + 6 + 2] - (2.0f32 * 0.3).cos()).abs() < 1e-6);
    }

    /// An empty batch encodes to an empty batch of the full width, and its backward runs.
    #[test]
    fn empty_batch() {
        let enc = FrequencyConfig::new(6).init();
        let device = Device::flex().autodiff();
        let x = Tensor::<2>::from_data(TensorData::new(Vec::<f32>::new(), [0, 3]), &device)
            .require_grad();
        let y = enc.forward(x.clone(), 0);
        assert_eq!(y.dims(), [0, enc.output_dim(3)]);
        let grads = y.sum().backward();
        if let Some(dx) = x.grad(&grads) {
            assert_eq!(dx.dims(), [0, 3]);
        }
    }

    /// The encoding, its band weights, the inputs and their shape of the fused-op tests.
    fn case() -> (FrequencyEncoding, Vec<f32>, Vec<f32>, [usize; 2]) {
        let enc = FrequencyConfig::new(6)
            .with_window(Some(HannWindowConfig::new(0, 600)))
            .init();
        let step = 350; // alpha = 3.5: bands 0..3 on, band 3 half, 4 and 5 off
        let weights = enc.band_weights(step);
        assert!(weights[3] > 0.4 && weights[3] < 0.6 && weights[4] == 0.0);
        let (n, d) = (37, 3);
        let values: Vec<f32> = (0..n * d)
            .map(|i| match i % 7 {
                0 => 0.0,
                1 => 3.0,
                2 => -3.0,
                _ => ((i as f32 * 0.618).fract() - 0.5) * 2.4,
            })
            .collect();
        (enc, weights, values, [n, d])
    }

    /// `fused` on `device` (with autodiff) against the composed ops there, in output and
    /// input gradient, on [`case`]: six bands (angles up to 32 |x|), a half-open window
    /// (one band at 0.5, two off), inputs of both signs up to 3 and 0. Returns the fused
    /// output.
    fn fused_against_composed(
        device: &Device,
        fused: impl Fn(&Tensor<2>, &[f32]) -> Tensor<2>,
    ) -> Vec<f32> {
        let (enc, weights, values, [n, d]) = case();
        let upstream: Vec<f32> = (0..n * enc.output_dim(d))
            .map(|i| ((i as f32 * 0.377).fract() - 0.5) * 2.0)
            .collect();
        let run = |use_fused: bool| {
            let x = Tensor::<2>::from_data(TensorData::new(values.clone(), [n, d]), device)
                .require_grad();
            let y = if use_fused {
                fused(&x, &weights)
            } else {
                enc.composed(x.clone(), &weights)
            };
            let g = Tensor::<2>::from_data(
                TensorData::new(upstream.clone(), [n, enc.output_dim(d)]),
                device,
            );
            let grads = (y.clone() * g).sum().backward();
            let dx = x.grad(&grads).expect("x has a gradient");
            (crate::util::host(&y), dx.try_to_vec_as::<f32>().unwrap())
        };
        let ((y_f, dx_f), (y_c, dx_c)) = (run(true), run(false));
        for (a, b) in y_f.iter().zip(&y_c) {
            assert!((a - b).abs() < 2e-5, "output {a} vs {b}");
        }
        for (a, b) in dx_f.iter().zip(&dx_c) {
            assert!(
                (a - b).abs() < 2e-4 * b.abs().max(1.0),
                "gradient {a} vs {b}"
            );
        }
        y_f
    }

    /// The fused op (Flex, autodiff or not) matches the composed ops.
    #[test]
    fn fused_matches_composed_ops() {
        let fused = |x: &Tensor<2>, w: &[f32]| {
            crate::kernels::frequency::encode(x, w).expect("Flex takes it")
        };
        let y = fused_against_composed(&Device::flex().autodiff(), fused);
        // Without autodiff, the same values.
        let (_, weights, values, shape) = case();
        let plain = Tensor::<2>::from_data(TensorData::new(values, shape), &Device::flex());
        assert_eq!(crate::util::host(&fused(&plain, &weights)), y);
    }

    /// The device op (`kernels::cube::frequency`) matches the composed ops on the device.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_frequency_matches_the_composed_ops() {
        let gpu = crate::device::test_wgpu().autodiff();
        fused_against_composed(&gpu, |x, w| {
            crate::kernels::cube::frequency::encode(x.clone(), w)
        });
    }
}
