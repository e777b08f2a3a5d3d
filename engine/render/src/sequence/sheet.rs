//! The comparison contact sheet: one row per frame, ground truth | render | error heat map.

use image::RgbImage;

use crate::metrics::Rect;
use talkin_data::draw;

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

/// Outlines `r` on `img` (one pixel wide).
pub fn outline(img: &mut RgbImage, r: Rect, colour: [u8; 3]) {
    let (x0, y0) = (r.x as f64, r.y as f64);
    let (x1, y1) = (x0 + r.width as f64 - 1.0, y0 + r.height as f64 - 1.0);
    for (a, b) in [
        ((x0, y0), (x1, y0)),
        ((x1, y0), (x1, y1)),
        ((x1, y1), (x0, y1)),
        ((x0, y1), (x0, y0)),
    ] {
        draw::line(img, a, b, colour, 1);
    }
}

/// One row of a comparison sheet.
#[derive(Clone, Debug)]
pub struct SheetRow {
    pub truth: RgbImage,
    pub render: RgbImage,
    /// Regions outlined on the ground truth and the heat map (not on the render).
    pub outlines: Vec<(Rect, [u8; 3])>,
}

/// Rows of one size as triplets ground truth | render | heat map, one triplet a row (two
/// side by side beyond four rows).
pub fn comparison_sheet(rows: &[SheetRow]) -> RgbImage {
    let tiles: Vec<RgbImage> = rows
        .iter()
        .flat_map(|row| {
            let mut truth = row.truth.clone();
            let mut heat = error_heat(&row.truth, &row.render);
            for &(r, colour) in &row.outlines {
                outline(&mut truth, r, colour);
                outline(&mut heat, r, colour);
            }
            [truth, row.render.clone(), heat]
        })
        .collect();
    let columns = if rows.len() > 4 { 6 } else { 3 };
    draw::tile(&tiles, columns, 2, [24, 24, 24])
}
