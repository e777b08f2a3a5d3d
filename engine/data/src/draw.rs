//! Tiny raster helpers for contact sheets: blending, lines, dots, tiling. Not a renderer.

use image::{Rgb, RgbImage};

/// Colour per segmentation label (background, body, arms, hands, head).
pub const LABEL_COLOURS: [[u8; 3]; 5] = [
    [0, 0, 0],
    [60, 120, 255],
    [60, 200, 60],
    [255, 60, 200],
    [255, 200, 0],
];

/// Blends `colour` over pixel (x, y) with opacity `alpha`; ignores pixels outside.
pub fn blend(img: &mut RgbImage, x: i64, y: i64, colour: [u8; 3], alpha: f32) {
    if x < 0 || y < 0 || x >= img.width() as i64 || y >= img.height() as i64 {
        return;
    }
    let p = img.get_pixel_mut(x as u32, y as u32);
    for c in 0..3 {
        p.0[c] = (p.0[c] as f32 * (1.0 - alpha) + colour[c] as f32 * alpha).round() as u8;
    }
}

/// A line from `a` to `b` (pixel coordinates, any finite values), `width` pixels wide.
pub fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), colour: [u8; 3], width: i64) {
    if !(a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite()) {
        return;
    }
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as i64).clamp(1, 100_000);
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        dot(img, (x, y), colour, width / 2);
    }
}

/// A filled square dot of radius `r` around `p`.
pub fn dot(img: &mut RgbImage, p: (f64, f64), colour: [u8; 3], r: i64) {
    let limit = 1e6; // far outside any image; keeps the integer arithmetic in range
    if !(p.0.abs() < limit && p.1.abs() < limit) {
        return;
    }
    let (cx, cy) = (p.0.floor() as i64, p.1.floor() as i64);
    for dy in -r..=r {
        for dx in -r..=r {
            blend(img, cx + dx, cy + dy, colour, 1.0);
        }
    }
}

/// Arranges equally sized tiles in a grid with `columns` columns and a `gap` px border.
pub fn tile(tiles: &[RgbImage], columns: usize, gap: u32, background: [u8; 3]) -> RgbImage {
    let columns = columns.max(1);
    let (w, h) = tiles
        .first()
        .map(|t| (t.width(), t.height()))
        .unwrap_or((1, 1));
    let rows = tiles.len().div_ceil(columns).max(1);
    let mut sheet = RgbImage::from_pixel(
        columns as u32 * (w + gap) + gap,
        rows as u32 * (h + gap) + gap,
        Rgb(background),
    );
    for (i, t) in tiles.iter().enumerate() {
        let (col, row) = ((i % columns) as u32, (i / columns) as u32);
        image::imageops::overlay(
            &mut sheet,
            t,
            (gap + col * (w + gap)) as i64,
            (gap + row * (h + gap)) as i64,
        );
    }
    sheet
}

/// A colour map for error heat maps: 0 -> black, 1 -> white through red and yellow.
pub fn heat(v: f32) -> [u8; 3] {
    let v = if v.is_finite() {
        v.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let r = (v * 3.0).min(1.0);
    let g = (v * 3.0 - 1.0).clamp(0.0, 1.0);
    let b = (v * 3.0 - 2.0).clamp(0.0, 1.0);
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drawing_outside_or_with_nan_is_harmless() {
        let mut img = RgbImage::new(8, 8);
        line(&mut img, (-100.0, -100.0), (100.0, 100.0), [255, 0, 0], 1);
        line(&mut img, (f64::NAN, 0.0), (3.0, 3.0), [255, 0, 0], 1);
        dot(&mut img, (1e30, -1e30), [0, 255, 0], 2);
        assert_eq!(img.get_pixel(4, 4).0, [255, 0, 0]);
        let sheet = tile(&[img.clone(), img.clone(), img], 2, 1, [9, 9, 9]);
        assert_eq!((sheet.width(), sheet.height()), (2 * 9 + 1, 2 * 9 + 1));
        assert_eq!(heat(0.0), [0, 0, 0]);
        assert_eq!(heat(f32::NAN), [255, 255, 255]);
    }
}
