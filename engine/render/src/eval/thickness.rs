//! How thick the person renders: inside the target's mask (off its outline), the spread
//! of each opaque ray's compositing weight over depth
//! ([`crate::avatar::RenderedFrame::depth_spread`]). A surface is a few millimetres, a
//! cloud centimetres; PSNR cannot tell a sharp texture on a surface from a colour that
//! a cloud mixes along the ray to match one view.

use image::GrayImage;
use serde::Serialize;
use talkin_data::dataset::mask_edge_band;

use super::regions::outline_px;
use crate::metrics::Rect;

/// Below this opacity a ray met too little matter to have a thickness.
pub const THICKNESS_MIN_OPACITY: f32 = 0.5;

/// The depth spread of the rays inside a person's mask, millimetres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Thickness {
    pub median_mm: f64,
    pub p90_mm: f64,
    /// Rays measured: inside the mask, off the outline, at least
    /// [`THICKNESS_MIN_OPACITY`] opaque.
    pub rays: usize,
}

/// The thickness of `rect`'s rays inside `mask` (its 128 cut, less the outline band
/// [`outline_px`]), from per-pixel `depth_spread` (metres) and `opacity`, row-major at
/// the mask's size. `None` where no such ray exists.
pub fn thickness_inside(
    mask: &GrayImage,
    depth_spread: &[f32],
    opacity: &[f32],
    rect: Rect,
) -> Option<Thickness> {
    let (w, h) = mask.dimensions();
    debug_assert!(depth_spread.len() == (w * h) as usize && opacity.len() == depth_spread.len());
    let band = mask_edge_band(mask, outline_px(w, h));
    let mut mm: Vec<f64> = Vec::new();
    for y in rect.y..(rect.y + rect.height).min(h) {
        for x in rect.x..(rect.x + rect.width).min(w) {
            let i = (y * w + x) as usize;
            let inside = mask.as_raw()[i] >= 128 && !band.get(i).copied().unwrap_or(false);
            if inside && opacity[i] >= THICKNESS_MIN_OPACITY && depth_spread[i].is_finite() {
                mm.push(1000.0 * f64::from(depth_spread[i]));
            }
        }
    }
    if mm.is_empty() {
        return None;
    }
    mm.sort_by(f64::total_cmp);
    let at = |q: f64| mm[((q * (mm.len() - 1) as f64).round() as usize).min(mm.len() - 1)];
    Some(Thickness {
        median_mm: at(0.5),
        p90_mm: at(0.9),
        rays: mm.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;

    #[test]
    fn only_opaque_rays_inside_the_mask_count() {
        // A 40x40 frame, the person the middle 20x20; 1 px of outline either side.
        let mask = GrayImage::from_fn(40, 40, |x, y| {
            Luma([if (10..30).contains(&x) && (10..30).contains(&y) {
                255
            } else {
                0
            }])
        });
        let mut spread = vec![0.5f32; 40 * 40]; // around the person: a thick cloud
        let mut opacity = vec![1.0f32; 40 * 40];
        for y in 11..29 {
            for x in 11..29 {
                // Inside: 2 mm on the left half, 20 mm on the right.
                spread[y * 40 + x] = if x < 20 { 0.002 } else { 0.02 };
            }
        }
        // A translucent column inside is left out.
        for y in 11..29 {
            opacity[y * 40 + 12] = 0.2;
            spread[y * 40 + 12] = 9.0;
        }
        let full = Rect {
            x: 0,
            y: 0,
            width: 40,
            height: 40,
        };
        let t = thickness_inside(&mask, &spread, &opacity, full).unwrap();
        // 18 rows x (9 left less the translucent column, 9 right) inside the outline.
        assert_eq!(t.rays, 18 * 17);
        assert!((t.p90_mm - 20.0).abs() < 1e-3, "{t:?}");
        assert!(t.median_mm > 1.9 && t.median_mm < 20.1, "{t:?}");
        let outside = Rect {
            x: 0,
            y: 0,
            width: 8,
            height: 8,
        };
        assert_eq!(thickness_inside(&mask, &spread, &opacity, outside), None);
    }
}
