//! PSNR and SSIM of two 8-bit RGB images over a rectangle, in f64 on the CPU.
//!
//! SSIM mirrors `nets::loss::ssim` (Gaussian window 11, sigma 1.5, C1 = 0.01^2,
//! C2 = 0.03^2, data range 1, the valid region without padding, averaged over channels
//! and pixels); a test checks the two agree.

use image::RgbImage;
use serde::Serialize;
use talkin_nets::loss::{SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW};

/// PSNR reported for identical images (and the cap of every PSNR): JSON has no infinity.
pub const PSNR_CAP_DB: f64 = 100.0;

/// A pixel rectangle `[x, x + width) x [y, y + height)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Rect {
    /// The whole image.
    pub fn full(img: &RgbImage) -> Rect {
        Rect {
            x: 0,
            y: 0,
            width: img.width(),
            height: img.height(),
        }
    }

    /// True if the rectangle is non-empty and lies inside a `width` x `height` image.
    pub fn is_inside(&self, width: u32, height: u32) -> bool {
        self.width > 0
            && self.height > 0
            && u64::from(self.x) + u64::from(self.width) <= u64::from(width)
            && u64::from(self.y) + u64::from(self.height) <= u64::from(height)
    }

    /// True if the continuous point (pixel coordinates) lies in the rectangle.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x as f64
            && y >= self.y as f64
            && x <= (self.x + self.width) as f64
            && y <= (self.y + self.height) as f64
    }
}

/// Channel planes of `r` in [0, 1]: `[3][h * w]`.
fn planes(img: &RgbImage, r: Rect) -> [Vec<f64>; 3] {
    let mut out: [Vec<f64>; 3] =
        std::array::from_fn(|_| Vec::with_capacity((r.width * r.height) as usize));
    for y in r.y..r.y + r.height {
        for x in r.x..r.x + r.width {
            let p = img.get_pixel(x, y).0;
            for c in 0..3 {
                out[c].push(p[c] as f64 / 255.0);
            }
        }
    }
    out
}

fn check(a: &RgbImage, b: &RgbImage, r: Rect) {
    assert_eq!(
        a.dimensions(),
        b.dimensions(),
        "metrics: image sizes differ"
    );
    assert!(
        r.is_inside(a.width(), a.height()),
        "metrics: {r:?} outside the image"
    );
}

/// Mean squared error over `r`, values in [0, 1].
pub fn mse(a: &RgbImage, b: &RgbImage, r: Rect) -> f64 {
    check(a, b, r);
    let (pa, pb) = (planes(a, r), planes(b, r));
    let mut sum = 0.0;
    for c in 0..3 {
        sum += pa[c]
            .iter()
            .zip(&pb[c])
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>();
    }
    sum / (3 * r.width * r.height) as f64
}

/// PSNR in dB over `r` (data range 1), capped at [`PSNR_CAP_DB`].
///
/// Panics if the images differ in size or `r` is not inside them (callers check).
pub fn psnr(a: &RgbImage, b: &RgbImage, r: Rect) -> f64 {
    psnr_of_mse(mse(a, b, r))
}

/// PSNR in dB of a mean squared error (data range 1), capped at [`PSNR_CAP_DB`].
pub fn psnr_of_mse(m: f64) -> f64 {
    if m <= 0.0 {
        return PSNR_CAP_DB;
    }
    (-10.0 * m.log10()).min(PSNR_CAP_DB)
}

/// The normalised 1D Gaussian window of `nets::loss::ssim`.
fn gaussian_window() -> [f64; SSIM_WINDOW] {
    let half = (SSIM_WINDOW / 2) as f64;
    let w: [f64; SSIM_WINDOW] = std::array::from_fn(|i| {
        let d = i as f64 - half;
        (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
    });
    let sum: f64 = w.iter().sum();
    w.map(|v| v / sum)
}

/// Separable "valid" blur of a `h x w` plane: `[(h - 10) * (w - 10)]`.
fn blur(plane: &[f64], h: usize, w: usize, g: &[f64; SSIM_WINDOW]) -> Vec<f64> {
    let (h2, w2) = (h + 1 - SSIM_WINDOW, w + 1 - SSIM_WINDOW);
    let mut rows = vec![0.0; h * w2]; // [h, w2]
    for y in 0..h {
        for x in 0..w2 {
            rows[y * w2 + x] = (0..SSIM_WINDOW).map(|k| g[k] * plane[y * w + x + k]).sum();
        }
    }
    let mut out = vec![0.0; h2 * w2];
    for y in 0..h2 {
        for x in 0..w2 {
            out[y * w2 + x] = (0..SSIM_WINDOW)
                .map(|k| g[k] * rows[(y + k) * w2 + x])
                .sum();
        }
    }
    out
}

/// Mean SSIM over `r`; `None` when `r` is smaller than the 11x11 window.
///
/// Panics if the images differ in size or `r` is not inside them (callers check).
pub fn ssim(a: &RgbImage, b: &RgbImage, r: Rect) -> Option<f64> {
    check(a, b, r);
    let (h, w) = (r.height as usize, r.width as usize);
    if h < SSIM_WINDOW || w < SSIM_WINDOW {
        return None;
    }
    let g = gaussian_window();
    let (pa, pb) = (planes(a, r), planes(b, r));
    let mut total = 0.0;
    let mut count = 0usize;
    for c in 0..3 {
        let (x, y) = (&pa[c], &pb[c]);
        let prod = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> {
            x.iter().zip(y).map(|(&p, &q)| f(p, q)).collect()
        };
        let mu_x = blur(x, h, w, &g);
        let mu_y = blur(y, h, w, &g);
        let exx = blur(&prod(&|p, _| p * p), h, w, &g);
        let eyy = blur(&prod(&|_, q| q * q), h, w, &g);
        let exy = blur(&prod(&|p, q| p * q), h, w, &g);
        for i in 0..mu_x.len() {
            let (mx, my) = (mu_x[i], mu_y[i]);
            let (vx, vy, cxy) = (exx[i] - mx * mx, eyy[i] - my * my, exy[i] - mx * my);
            total += ((2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2))
                / ((mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2));
        }
        count += mu_x.len();
    }
    Some(total / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, Tensor, TensorData};

    /// A seeded textured image.
    fn texture(w: u32, h: u32, seed: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let mut u = (x * 7919 + y * 104_729 + seed).wrapping_mul(0x9e37_79b9);
            u ^= u >> 15;
            u = u.wrapping_mul(0x7feb_352d);
            u ^= u >> 13;
            let smooth = 128.0 + 80.0 * ((x as f64 * 0.3).sin() + (y as f64 * 0.2).cos()) / 2.0;
            image::Rgb(std::array::from_fn(|c| {
                (smooth + ((u >> (8 * c)) & 31) as f64) as u8
            }))
        })
    }

    #[test]
    fn identical_images_score_the_cap_and_one() {
        let a = texture(40, 30, 1);
        let r = Rect::full(&a);
        assert_eq!(psnr(&a, &a, r), PSNR_CAP_DB);
        assert!((ssim(&a, &a, r).unwrap() - 1.0).abs() < 1e-12);
        let small = Rect {
            x: 3,
            y: 2,
            width: 10,
            height: 20,
        };
        assert_eq!(ssim(&a, &a, small), None, "smaller than the window");
    }

    #[test]
    fn known_noise_gives_known_psnr() {
        // Every value off by exactly 8: MSE = (8/255)^2, PSNR = 20 log10(255/8).
        let a = RgbImage::from_pixel(32, 32, image::Rgb([100, 150, 200]));
        let mut b = a.clone();
        for (i, p) in b.pixels_mut().enumerate() {
            let s: i16 = if i % 2 == 0 { 8 } else { -8 };
            p.0 = p.0.map(|v| (v as i16 + s) as u8);
        }
        let want = 20.0 * (255.0f64 / 8.0).log10();
        let got = psnr(&a, &b, Rect::full(&a));
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        // Only the region counts.
        let mut c = a.clone();
        c.put_pixel(0, 0, image::Rgb([0, 0, 0]));
        let inner = Rect {
            x: 1,
            y: 1,
            width: 31,
            height: 31,
        };
        assert_eq!(psnr(&a, &c, inner), PSNR_CAP_DB);
        assert!(psnr(&a, &c, Rect::full(&a)) < 40.0);
        assert!(ssim(&a, &b, Rect::full(&a)).unwrap() < 0.999);
    }

    #[test]
    fn ssim_matches_the_nets_definition() {
        let (w, h) = (37, 29);
        let a = texture(w, h, 3);
        let b = texture(w, h, 11);
        let r = Rect {
            x: 2,
            y: 3,
            width: 33,
            height: 24,
        };
        let ours = ssim(&a, &b, r).unwrap();
        let device = Device::flex();
        let tensor = |img: &RgbImage| {
            let p = planes(img, r);
            let v: Vec<f32> = p.iter().flatten().map(|&x| x as f32).collect();
            Tensor::<4>::from_data(
                TensorData::new(v, [1, 3, r.height as usize, r.width as usize]),
                &device,
            )
        };
        let theirs: f32 = talkin_nets::loss::ssim(tensor(&a), tensor(&b)).into_scalar();
        assert!(ours < 0.95, "test images too similar: {ours}");
        assert!((ours - theirs as f64).abs() < 1e-4, "{ours} vs {theirs}");
    }
}
