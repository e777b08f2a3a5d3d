//! Where in the person box the error sits: inside the mask, on its outline, or around
//! the person. A person box on a real capture is mostly background, and a soft
//! silhouette, a mottled texture and floaters score alike in its one PSNR; split by the
//! target's mask, they do not. Each region also gets the render's mean opacity: a
//! field that paints the background's colour around the person scores as well against
//! a plain background as one that leaves it empty, and shows its fog over any other.

use image::{GrayImage, RgbImage};
use serde::Serialize;
use talkin_data::dataset::{mask_edge_band, mask_edge_px};

use crate::metrics::{Rect, psnr_of_mse};

/// Width of the outline band on each side of the mask's cut: the band `train` leaves out
/// of camera frames by default ([`mask_edge_px`]), at least 1 px.
pub fn outline_px(width: u32, height: u32) -> u32 {
    mask_edge_px(width, height).max(1)
}

/// One region of the person box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RegionScore {
    pub psnr: f64,
    /// Pixels of the box in the region.
    pub pixels: usize,
    /// The region's share of the box's squared error (0 where the box has none).
    pub error_share: f64,
    /// The render's mean opacity over the region: 1 inside a solid person, 0 around one
    /// with no fog.
    pub opacity: f64,
}

/// The person box split by the target's mask (its 128 cut).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PersonRegions {
    /// Inside the mask, off the outline: the person's texture.
    pub inside: Option<RegionScore>,
    /// Within `outline_px` of the cut, on either side: the silhouette.
    pub outline: Option<RegionScore>,
    /// Outside the mask, off the outline: floaters and fog around the person.
    pub around: Option<RegionScore>,
    pub outline_px: u32,
}

/// Scores `rect` of `render` against `truth` region by region of `mask`: all three the
/// same size (the dataset decodes masks at the frame's size) and `rect` inside them, as
/// for every crop, and `opacity` the render's, row-major (`[w * h]`). A region with no
/// pixel in the box is `None`.
pub fn person_regions(
    truth: &RgbImage,
    render: &RgbImage,
    opacity: &[f32],
    mask: &GrayImage,
    rect: Rect,
) -> PersonRegions {
    let (w, h) = mask.dimensions();
    debug_assert!(truth.dimensions() == (w, h) && render.dimensions() == (w, h));
    debug_assert!(opacity.len() == (w * h) as usize);
    debug_assert!(rect.x + rect.width <= w && rect.y + rect.height <= h);
    let band_px = outline_px(w, h);
    let band = mask_edge_band(mask, band_px);
    // Squared error sums (per channel, in [0, 1] units) and pixel counts.
    let mut sums = [0.0f64; 3];
    let mut opacities = [0.0f64; 3];
    let mut counts = [0usize; 3];
    for y in rect.y..rect.y + rect.height {
        for x in rect.x..rect.x + rect.width {
            let i = (y * w + x) as usize;
            let region = if band[i] {
                1
            } else if mask.as_raw()[i] >= 128 {
                0
            } else {
                2
            };
            let (a, b) = (truth.get_pixel(x, y).0, render.get_pixel(x, y).0);
            let se: f64 = (0..3)
                .map(|c| ((a[c] as f64 - b[c] as f64) / 255.0).powi(2))
                .sum();
            sums[region] += se;
            opacities[region] += opacity[i].clamp(0.0, 1.0) as f64;
            counts[region] += 1;
        }
    }
    let total: f64 = sums.iter().sum();
    let score = |k: usize| -> Option<RegionScore> {
        (counts[k] > 0).then(|| RegionScore {
            psnr: psnr_of_mse(sums[k] / (3 * counts[k]) as f64),
            pixels: counts[k],
            error_share: if total > 0.0 { sums[k] / total } else { 0.0 },
            opacity: opacities[k] / counts[k] as f64,
        })
    };
    PersonRegions {
        inside: score(0),
        outline: score(1),
        around: score(2),
        outline_px: band_px,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::PSNR_CAP_DB;
    use image::{Luma, Rgb};

    /// A 40x40 frame with a 20x20 person in the middle.
    fn square_mask() -> GrayImage {
        GrayImage::from_fn(40, 40, |x, y| {
            Luma([if (10..30).contains(&x) && (10..30).contains(&y) {
                255
            } else {
                0
            }])
        })
    }

    /// A render's opacity that is the mask's: solid person, nothing around.
    fn person_opacity(mask: &GrayImage) -> Vec<f32> {
        mask.as_raw()
            .iter()
            .map(|&m| f32::from(m) / 255.0)
            .collect()
    }

    #[test]
    fn fog_the_colour_of_the_background_shows_in_the_opacity_alone() {
        // A white fog of opacity 0.6 around the person, rendered over white: not one
        // pixel differs from the truth, yet the render is not the person alone.
        let mask = square_mask();
        let truth = RgbImage::from_pixel(40, 40, Rgb([255, 255, 255]));
        let fog: Vec<f32> = person_opacity(&mask)
            .iter()
            .map(|&a| if a > 0.5 { 1.0 } else { 0.6 })
            .collect();
        let r = person_regions(&truth, &truth, &fog, &mask, Rect::full(&truth));
        let (inside, around) = (r.inside.unwrap(), r.around.unwrap());
        assert_eq!(around.psnr, PSNR_CAP_DB);
        assert!((around.opacity - 0.6).abs() < 1e-6, "{around:?}");
        assert_eq!(inside.opacity, 1.0);
        // The outline straddles the cut: half its pixels solid, half fog.
        let outline = r.outline.unwrap();
        assert!(
            outline.opacity > 0.6 && outline.opacity < 1.0,
            "{outline:?}"
        );
    }

    #[test]
    fn an_error_on_the_outline_is_counted_there_alone() {
        let mask = square_mask();
        let truth = RgbImage::from_pixel(40, 40, Rgb([200, 100, 50]));
        let mut render = truth.clone();
        // The person's left edge, one pixel inside the cut: the outline.
        for y in 12..28 {
            render.put_pixel(10, y, Rgb([0, 0, 0]));
        }
        let solid = person_opacity(&mask);
        let r = person_regions(&truth, &render, &solid, &mask, Rect::full(&truth));
        assert_eq!(r.outline_px, 1);
        let (inside, outline, around) = (r.inside.unwrap(), r.outline.unwrap(), r.around.unwrap());
        assert_eq!(inside.psnr, PSNR_CAP_DB);
        assert_eq!(around.psnr, PSNR_CAP_DB);
        assert!(outline.psnr < 20.0, "{outline:?}");
        assert_eq!(outline.error_share, 1.0);
        assert_eq!(inside.error_share + around.error_share, 0.0);
        assert_eq!((inside.opacity, around.opacity), (1.0, 0.0));
        // 1 px either side of a 20x20 square's cut: 22^2 - 18^2 pixels.
        assert_eq!(outline.pixels, 22 * 22 - 18 * 18);
        assert_eq!(inside.pixels + outline.pixels + around.pixels, 40 * 40);
    }

    #[test]
    fn a_box_inside_the_person_has_no_outline_or_surroundings() {
        let mask = square_mask();
        let truth = RgbImage::from_pixel(40, 40, Rgb([10, 20, 30]));
        let render = RgbImage::from_pixel(40, 40, Rgb([20, 20, 30]));
        let inner = Rect {
            x: 15,
            y: 15,
            width: 10,
            height: 10,
        };
        let r = person_regions(&truth, &render, &person_opacity(&mask), &mask, inner);
        assert!(r.outline.is_none() && r.around.is_none());
        let inside = r.inside.unwrap();
        assert_eq!(inside.error_share, 1.0);
        // One channel off by 10/255: MSE = (10/255)^2 / 3.
        let want = -10.0 * ((10.0f64 / 255.0).powi(2) / 3.0).log10();
        assert!((inside.psnr - want).abs() < 1e-9);
    }

    #[test]
    fn the_band_grows_with_the_frame() {
        assert_eq!(outline_px(96, 72), 1);
        assert_eq!(outline_px(512, 512), 2);
        assert_eq!(outline_px(768, 1024), 4);
    }
}
