//! The comparison contact sheet: one row per frame, ground truth | render | error heat map.

use image::RgbImage;

use crate::draw;

/// Absolute error (mean over channels, in [0, 1]) that the heat map shows as white.
pub const HEAT_FULL_SCALE: f32 = 0.25;

/// Per-pixel error heat map of two images of the same size.
pub fn error_heat(truth: &RgbImage, render: &RgbImage) -> RgbImage {
    RgbImage::from_fn(truth.width(), truth.height(), |x, y| {
        let (a, b) = (truth.get_pixel(x, y).0, render.get_pixel(x, y).0);
        let err: f32 = (0..3)
            .map(|c| (a[c] as f32 - b[c] as f32).abs() / 255.0)
            .sum::<f32>()
            / 3.0;
        image::Rgb(draw::heat(err / HEAT_FULL_SCALE))
    })
}

/// Rows of (ground truth, render) pairs of one size: ground truth | render | heat map.
pub fn comparison_sheet(pairs: &[(RgbImage, RgbImage)]) -> RgbImage {
    let tiles: Vec<RgbImage> = pairs
        .iter()
        .flat_map(|(truth, render)| [truth.clone(), render.clone(), error_heat(truth, render)])
        .collect();
    draw::tile(&tiles, 3, 2, [24, 24, 24])
}
