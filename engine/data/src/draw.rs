//! Drawing on contact sheets and overlays: blending, lines, dots, capsule outlines, text
//! labels and tiling, on top of `imageproc` and `ab_glyph`. Every function takes any
//! coordinates (off-image, huge, NaN) without panicking.

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

/// Far outside any image: points beyond (and NaN) are not drawn, so the float-to-int
/// arithmetic of the drawing crate stays in range.
const LIMIT: f64 = 1e6;

fn drawable(p: (f64, f64)) -> bool {
    p.0.abs() < LIMIT && p.1.abs() < LIMIT
}

/// A line from `a` to `b` (pixel coordinates, any values: non-finite or far-off ends
/// draw nothing), `width` pixels wide.
pub fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), colour: [u8; 3], width: i64) {
    if !(drawable(a) && drawable(b)) {
        return;
    }
    let r = width / 2;
    for dy in -r..=r {
        for dx in -r..=r {
            let o = (dx as f32, dy as f32);
            imageproc::drawing::draw_line_segment_mut(
                img,
                (a.0 as f32 + o.0, a.1 as f32 + o.1),
                (b.0 as f32 + o.0, b.1 as f32 + o.1),
                Rgb(colour),
            );
        }
    }
}

/// A filled dot of radius `r` pixels around `p` (one pixel for `r = 0`).
pub fn dot(img: &mut RgbImage, p: (f64, f64), colour: [u8; 3], r: i64) {
    if !drawable(p) {
        return;
    }
    let centre = (p.0.floor() as i32, p.1.floor() as i32);
    imageproc::drawing::draw_filled_circle_mut(img, centre, r as i32, Rgb(colour));
}

/// A circle's outline of radius `r` pixels around `p`.
pub fn circle(img: &mut RgbImage, p: (f64, f64), r: f64, colour: [u8; 3]) {
    if !(drawable(p) && (0.0..LIMIT).contains(&r)) {
        return;
    }
    let centre = (p.0.round() as i32, p.1.round() as i32);
    imageproc::drawing::draw_hollow_circle_mut(img, centre, r.round() as i32, Rgb(colour));
}

/// The outline of a capsule seen from the camera: the segment `a`-`b` thickened by the
/// radii `ra` at `a` and `rb` at `b` (pixels): two side lines and a circle at each end.
pub fn capsule_outline(
    img: &mut RgbImage,
    a: (f64, f64),
    b: (f64, f64),
    (ra, rb): (f64, f64),
    colour: [u8; 3],
) {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len = (dx * dx + dy * dy).sqrt();
    if len > 1e-9 {
        let n = (-dy / len, dx / len);
        for s in [-1.0, 1.0] {
            line(
                img,
                (a.0 + s * n.0 * ra, a.1 + s * n.1 * ra),
                (b.0 + s * n.0 * rb, b.1 + s * n.1 * rb),
                colour,
                1,
            );
        }
    }
    circle(img, a, ra, colour);
    circle(img, b, rb, colour);
}

/// DejaVu Sans, parsed once.
fn font() -> Option<&'static ab_glyph::FontRef<'static>> {
    static FONT: std::sync::OnceLock<Option<ab_glyph::FontRef<'static>>> =
        std::sync::OnceLock::new();
    FONT.get_or_init(|| ab_glyph::FontRef::try_from_slice(dejavu::sans::regular()).ok())
        .as_ref()
}

/// Writes `text` with its top-left corner at (`x`, `y`), `height` pixels tall
/// (anti-aliased DejaVu Sans); what falls outside the image is clipped.
pub fn label(img: &mut RgbImage, text: &str, x: i32, y: i32, height: f32, colour: [u8; 3]) {
    if let Some(font) = font() {
        imageproc::drawing::draw_text_mut(img, Rgb(colour), x, y, height, font, text);
    }
}

/// The width and height in pixels `text` takes at `height`.
pub fn label_size(text: &str, height: f32) -> (u32, u32) {
    font().map_or((0, 0), |font| {
        imageproc::drawing::text_size(height, font, text)
    })
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

/// A contact sheet: `tiles` brought to the first one's size, in a near-square grid with
/// 4 px dark gaps (a 1x1 image for no tiles).
pub fn contact_grid(tiles: Vec<RgbImage>) -> RgbImage {
    let Some(first) = tiles.first() else {
        return RgbImage::new(1, 1);
    };
    let (w, h) = first.dimensions();
    let tiles: Vec<RgbImage> = tiles
        .into_iter()
        .map(|t| {
            if t.dimensions() == (w, h) {
                t
            } else {
                image::imageops::resize(&t, w, h, image::imageops::FilterType::Triangle)
            }
        })
        .collect();
    let columns = (tiles.len() as f64).sqrt().ceil() as usize;
    tile(&tiles, columns.max(1), 4, [24, 24, 24])
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
        circle(&mut img, (f64::NAN, 1.0), 3.0, [0, 255, 0]);
        capsule_outline(
            &mut img,
            (1.0, 1.0),
            (1.0, 1.0),
            (1e300, f64::NAN),
            [0, 0, 255],
        );
        label(&mut img, "far", 1_000_000, -5, 12.0, [0, 0, 255]);
        assert_eq!(img.get_pixel(4, 4).0, [255, 0, 0]);
        let sheet = tile(&[img.clone(), img.clone(), img], 2, 1, [9, 9, 9]);
        assert_eq!((sheet.width(), sheet.height()), (2 * 9 + 1, 2 * 9 + 1));
        assert_eq!(heat(0.0), [0, 0, 0]);
        assert_eq!(heat(f32::NAN), [255, 255, 255]);
    }

    #[test]
    fn labels_are_drawn_and_measured() {
        let mut img = RgbImage::new(64, 24);
        label(&mut img, "0.93", 2, 2, 14.0, [255, 255, 255]);
        assert!(img.pixels().any(|p| p.0[0] > 128), "no text drawn");
        let (w, h) = label_size("0.93", 14.0);
        assert!(w > 10 && w < 60 && h > 5 && h <= 16, "{w}x{h}");
    }
}
