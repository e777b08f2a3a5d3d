//! The anchors' protocol: a frame scored as HumanNeRF's and Neural Body's tables score it,
//! so a run can be set beside their published numbers. The whole frame (over the
//! evaluation's background: black on a capture, onto which they mask the truth), PSNR,
//! SSIM as scikit-image 0.19's `structural_similarity(a, b, multichannel=True)` computed it
//! for float images in [0, 1] when those tables were made, and LPIPS with the VGG16
//! backbone, x1000.
//!
//! scikit-image 0.19 took a float image's data range from its dtype, [-1, 1], so the SSIM
//! of those tables is at data range 2 ([`ANCHOR_SSIM_RANGE`]): its constants C1 and C2 are
//! four times those of range 1, which lifts SSIM on dark, flat frames (0.958 against 0.938
//! on a ZJU-MoCap frame). Later versions refuse float images without `data_range`.

use image::RgbImage;
use serde::Serialize;

use super::lpips::LpipsScorer;
use crate::metrics::{Rect, psnr};

/// The data range scikit-image 0.19 used for float images (its dtype range, [-1, 1]).
pub const ANCHOR_SSIM_RANGE: f64 = 2.0;

/// scikit-image's default window: 7x7, uniform.
const WINDOW: usize = 7;

/// One frame by the anchors' protocol.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AnchorScore {
    /// Whole frame, dB (the engine's full-frame PSNR).
    pub psnr: f64,
    /// Whole frame, scikit-image 0.19 on floats (data range 2).
    pub ssim: f64,
    /// Whole frame, LPIPS (VGG16) x1000; `None` without the VGG weights.
    pub lpips_vgg: Option<f64>,
}

/// Scores the whole of `render` against `truth` (same size); `vgg` scores LPIPS.
pub fn anchor_score(
    truth: &RgbImage,
    render: &RgbImage,
    vgg: Option<&LpipsScorer>,
) -> Option<AnchorScore> {
    let full = Rect::full(render);
    Some(AnchorScore {
        psnr: psnr(truth, render, full),
        ssim: ssim_skimage(truth, render, ANCHOR_SSIM_RANGE)?,
        lpips_vgg: vgg.and_then(|s| s.distance(truth, render, full).map(|d| d * 1000.0)),
    })
}

/// SSIM of two 8-bit images read as floats in [0, 1], as scikit-image computes it with
/// its defaults (`win_size` 7, uniform filter, `use_sample_covariance`, K1 0.01, K2 0.03)
/// at `data_range`, averaged over channels: the mean of the SSIM map over the image
/// without its 3-pixel border (where the reflected padding never reaches), so only the
/// valid 7x7 windows count. `None` for an image smaller than the window.
///
/// Panics if the images differ in size.
pub fn ssim_skimage(a: &RgbImage, b: &RgbImage, data_range: f64) -> Option<f64> {
    assert_eq!(a.dimensions(), b.dimensions(), "ssim: image sizes differ");
    let (w, h) = (a.width() as usize, a.height() as usize);
    if w < WINDOW || h < WINDOW {
        return None;
    }
    let np = (WINDOW * WINDOW) as f64;
    let cov_norm = np / (np - 1.0);
    let c1 = (0.01 * data_range).powi(2);
    let c2 = (0.03 * data_range).powi(2);
    let (wo, ho) = (w + 1 - WINDOW, h + 1 - WINDOW);
    let mut total = 0.0;
    for c in 0..3 {
        let plane =
            |img: &RgbImage| -> Vec<f64> { img.pixels().map(|p| p.0[c] as f64 / 255.0).collect() };
        let (x, y) = (plane(a), plane(b));
        let box_mean = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
            // Rows, then columns: sums of 7, divided by 49.
            let mut rows = vec![0.0; h * wo];
            for r in 0..h {
                for k in 0..wo {
                    rows[r * wo + k] = (0..WINDOW).map(|d| f(r * w + k + d)).sum();
                }
            }
            let mut out = vec![0.0; ho * wo];
            for r in 0..ho {
                for k in 0..wo {
                    out[r * wo + k] = (0..WINDOW).map(|d| rows[(r + d) * wo + k]).sum::<f64>() / np;
                }
            }
            out
        };
        let ux = box_mean(&|i| x[i]);
        let uy = box_mean(&|i| y[i]);
        let uxx = box_mean(&|i| x[i] * x[i]);
        let uyy = box_mean(&|i| y[i] * y[i]);
        let uxy = box_mean(&|i| x[i] * y[i]);
        let mut sum = 0.0;
        for i in 0..ux.len() {
            let vx = cov_norm * (uxx[i] - ux[i] * ux[i]);
            let vy = cov_norm * (uyy[i] - uy[i] * uy[i]);
            let vxy = cov_norm * (uxy[i] - ux[i] * uy[i]);
            sum += ((2.0 * ux[i] * uy[i] + c1) * (2.0 * vxy + c2))
                / ((ux[i] * ux[i] + uy[i] * uy[i] + c1) * (vx + vy + c2));
        }
        total += sum / ux.len() as f64;
    }
    Some(total / 3.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded image with texture, flat black and a hard edge.
    fn image(w: u32, h: u32, seed: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let mut u = (x * 7919 + y * 104_729 + seed).wrapping_mul(0x9e37_79b9);
            u ^= u >> 15;
            u = u.wrapping_mul(0x7feb_352d);
            u ^= u >> 13;
            if x < w / 3 {
                return image::Rgb([0, 0, 0]);
            }
            let smooth = 120.0 + 70.0 * ((x as f64 * 0.31).sin() + (y as f64 * 0.17).cos()) / 2.0;
            image::Rgb(std::array::from_fn(|c| {
                (smooth + ((u >> (8 * c)) & 63) as f64) as u8
            }))
        })
    }

    /// Values from scikit-image 0.26.0 (`structural_similarity(a / 255, b / 255,
    /// channel_axis=2, data_range=R)`, its defaults otherwise) on these two images, the
    /// same formula 0.19 ran for floats with R = 2.
    #[test]
    fn matches_scikit_image() {
        let a = image(23, 17, 1);
        let b = image(23, 17, 2);
        let at_1 = ssim_skimage(&a, &b, 1.0).unwrap();
        let at_2 = ssim_skimage(&a, &b, 2.0).unwrap();
        assert!((at_1 - SKIMAGE_AT_1).abs() < 1e-9, "{at_1}");
        assert!((at_2 - SKIMAGE_AT_2).abs() < 1e-9, "{at_2}");
        assert!((ssim_skimage(&a, &a, 2.0).unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(ssim_skimage(&image(6, 40, 1), &image(6, 40, 2), 2.0), None);
    }

    const SKIMAGE_AT_1: f64 = 0.642652784984921;
    const SKIMAGE_AT_2: f64 = 0.685330173017983;
}
