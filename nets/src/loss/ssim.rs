use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Tensor, TensorData};

/// Side of the Gaussian window (Wang et al. 2004).
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the Gaussian window, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// `(0.01 * L)^2` for data range `L = 1`.
pub const SSIM_C1: f64 = 0.01 * 0.01;
/// `(0.03 * L)^2` for data range `L = 1`.
pub const SSIM_C2: f64 = 0.03 * 0.03;

/// The normalised 1D Gaussian window.
pub(crate) fn gaussian_window() -> [f64; SSIM_WINDOW] {
    let half = (SSIM_WINDOW / 2) as f64;
    let mut w = [0.0; SSIM_WINDOW];
    for (i, v) in w.iter_mut().enumerate() {
        let d = i as f64 - half;
        *v = (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let sum: f64 = w.iter().sum();
    w.map(|v| v / sum)
}

/// Mean SSIM per image: Gaussian window 11, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, data
/// range 1, the map computed over the "valid" region (no padding, as in Wang et al.'s
/// reference code) and averaged over channels and pixels. Differentiable in both inputs.
///
/// # Shapes
/// - `x`, `y`: `[N, C, H, W]`, values in `[0, 1]`, `H, W >= 11`
/// - output: `[N]`
pub fn ssim(x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
    let [n, c, h, w] = x.dims();
    assert_eq!(x.dims(), y.dims(), "ssim: shapes differ");
    assert!(
        h >= SSIM_WINDOW && w >= SSIM_WINDOW,
        "ssim: images must be at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {h}x{w}"
    );
    let device = x.device();
    // Blur the five moments in one depthwise, separable pass.
    let stack = Tensor::cat(
        vec![
            x.clone(),
            y.clone(),
            x.clone() * x.clone(),
            y.clone() * y.clone(),
            x * y,
        ],
        1,
    ); // [N, 5C, H, W]
    let groups = 5 * c;
    let g: Vec<f32> = gaussian_window().iter().map(|&v| v as f32).collect();
    let taps: Vec<f32> = (0..groups).flat_map(|_| g.iter().copied()).collect();
    let w_row = Tensor::<4>::from_data(
        TensorData::new(taps.clone(), [groups, 1, 1, SSIM_WINDOW]),
        &device,
    );
    let w_col = Tensor::<4>::from_data(TensorData::new(taps, [groups, 1, SSIM_WINDOW, 1]), &device);
    let opts = ConvOptions::new([1, 1], [0, 0], [1, 1], groups);
    let blurred = conv2d(stack, w_row, None, opts.clone());
    let blurred = conv2d(blurred, w_col, None, opts); // [N, 5C, H', W']
    let [_, _, h2, w2] = blurred.dims();
    let m = blurred.reshape([n, 5, c, h2, w2]);
    let part = |i: usize| m.clone().narrow(1, i, 1).reshape([n, c, h2, w2]);
    let (mu_x, mu_y, exx, eyy, exy) = (part(0), part(1), part(2), part(3), part(4));
    let mu_xx = mu_x.clone() * mu_x.clone();
    let mu_yy = mu_y.clone() * mu_y.clone();
    let mu_xy = mu_x * mu_y;
    let s_xx = exx - mu_xx.clone();
    let s_yy = eyy - mu_yy.clone();
    let s_xy = exy - mu_xy.clone();
    let num = (mu_xy * 2.0 + SSIM_C1) * (s_xy * 2.0 + SSIM_C2);
    let den = (mu_xx + mu_yy + SSIM_C1) * (s_xx + s_yy + SSIM_C2);
    let map = num / den; // [N, C, H', W']
    map.reshape([n, c * h2 * w2]).mean_dim(1).reshape([n])
}

/// `1 - mean SSIM` over the batch, the SSIM training loss.
///
/// # Shapes
/// - `pred`, `target`: `[N, C, H, W]` in `[0, 1]`
/// - output: `[1]`
pub fn ssim_loss(pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
    ssim(pred, target).mean().neg() + 1.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;

    /// Plain f64 SSIM: a direct (non-separable) 2D Gaussian window over the valid region.
    fn ssim_reference(x: &[f64], y: &[f64], n: usize, c: usize, h: usize, w: usize) -> Vec<f64> {
        let r = SSIM_WINDOW / 2;
        let mut k = vec![0.0; SSIM_WINDOW * SSIM_WINDOW];
        for dy in 0..SSIM_WINDOW {
            for dx in 0..SSIM_WINDOW {
                let (fy, fx) = (dy as f64 - r as f64, dx as f64 - r as f64);
                k[dy * SSIM_WINDOW + dx] =
                    (-(fx * fx + fy * fy) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
            }
        }
        let ksum: f64 = k.iter().sum();
        k.iter_mut().for_each(|v| *v /= ksum);
        let (h2, w2) = (h - SSIM_WINDOW + 1, w - SSIM_WINDOW + 1);
        (0..n)
            .map(|b| {
                let mut acc = 0.0;
                for ch in 0..c {
                    let base = (b * c + ch) * h * w;
                    for i in 0..h2 {
                        for j in 0..w2 {
                            let (mut mx, mut my, mut sxx, mut syy, mut sxy) =
                                (0.0, 0.0, 0.0, 0.0, 0.0);
                            for dy in 0..SSIM_WINDOW {
                                for dx in 0..SSIM_WINDOW {
                                    let g = k[dy * SSIM_WINDOW + dx];
                                    let p = base + (i + dy) * w + j + dx;
                                    mx += g * x[p];
                                    my += g * y[p];
                                    sxx += g * x[p] * x[p];
                                    syy += g * y[p] * y[p];
                                    sxy += g * x[p] * y[p];
                                }
                            }
                            let (vx, vy, cxy) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
                            acc += ((2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2))
                                / ((mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2));
                        }
                    }
                }
                acc / (c * h2 * w2) as f64
            })
            .collect()
    }

    /// Deterministic pseudo-random image values in [0, 1].
    fn pattern(len: usize, seed: u32, smooth: bool) -> Vec<f64> {
        (0..len)
            .map(|i| {
                let mut u = (i as u32).wrapping_mul(0x9e37_79b9) ^ seed;
                u ^= u >> 16;
                u = u.wrapping_mul(0x7feb_352d);
                u ^= u >> 15;
                let noise = u as f64 / u32::MAX as f64;
                if smooth {
                    0.5 + 0.3 * ((i % 20) as f64 * 0.3).sin() + 0.1 * noise
                } else {
                    noise
                }
            })
            .collect()
    }

    #[test]
    fn ssim_matches_f64_reference() {
        let device = Device::flex();
        let (n, c, h, w) = (2, 3, 16, 20);
        let x = pattern(n * c * h * w, 1, true);
        let y: Vec<f64> = x
            .iter()
            .zip(pattern(n * c * h * w, 7, false))
            .map(|(a, b)| (0.8 * a + 0.2 * b).clamp(0.0, 1.0))
            .collect();
        let to_t = |v: &[f64]| {
            let f: Vec<f32> = v.iter().map(|&a| a as f32).collect();
            Tensor::<4>::from_data(TensorData::new(f, [n, c, h, w]), &device)
        };
        // Compare against the f32-rounded inputs.
        let xr: Vec<f64> = x.iter().map(|&a| a as f32 as f64).collect();
        let yr: Vec<f64> = y.iter().map(|&a| a as f32 as f64).collect();
        let want = ssim_reference(&xr, &yr, n, c, h, w);
        let got = ssim(to_t(&x), to_t(&y))
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap();
        for (g, w) in got.iter().zip(&want) {
            assert!(
                (*g as f64 - w).abs() < 2e-4,
                "ssim {got:?} vs reference {want:?}"
            );
        }
        assert!(
            want.iter().all(|&v| v < 0.99),
            "test images too similar: {want:?}"
        );
    }

    #[test]
    fn ssim_of_identical_images_is_one() {
        let device = Device::flex();
        let x = pattern(3 * 32 * 32, 3, false);
        let f: Vec<f32> = x.iter().map(|&a| a as f32).collect();
        let t = Tensor::<4>::from_data(TensorData::new(f, [1, 3, 32, 32]), &device);
        let got: f32 = ssim(t.clone(), t.clone()).into_scalar();
        assert!((got - 1.0).abs() < 1e-5, "{got}");
        let loss: f32 = ssim_loss(t.clone(), t).into_scalar();
        assert!(loss.abs() < 1e-5, "{loss}");
    }

    #[test]
    fn ssim_gradient_is_finite() {
        let device = Device::flex().autodiff();
        let x: Vec<f32> = pattern(3 * 16 * 16, 5, true)
            .iter()
            .map(|&a| a as f32)
            .collect();
        let y: Vec<f32> = pattern(3 * 16 * 16, 9, false)
            .iter()
            .map(|&a| a as f32)
            .collect();
        let x = Tensor::<4>::from_data(TensorData::new(x, [1, 3, 16, 16]), &device).require_grad();
        let y = Tensor::<4>::from_data(TensorData::new(y, [1, 3, 16, 16]), &device);
        let grads = ssim_loss(x.clone(), y).backward();
        let g = x
            .grad(&grads)
            .expect("gradient")
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert!(g.iter().all(|v| v.is_finite()));
        assert!(g.iter().any(|&v| v != 0.0));
    }
}
