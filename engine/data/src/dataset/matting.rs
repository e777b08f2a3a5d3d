//! The mask defines the person: how a frame's file becomes its training target
//! (image x alpha + background x (1 - alpha), alpha = mask / 255 with soft edges kept),
//! and how far a frame's surroundings lie from the declared background.

use image::{GrayImage, RgbImage};

/// How a dataset's image files relate to its `background`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Matting {
    /// The files already show the person over `background` (what `synth` writes, and the
    /// default of a dataset.json without `matting`). A frame whose surroundings contradict
    /// the background is composited by its mask anyway and flagged
    /// ([`super::FrameImages::composited`]).
    #[default]
    Matted,
    /// The files are camera frames (what `import` writes): every frame is composited by
    /// its mask when it is decoded; the file stays as it was for overlays.
    ByMask,
    /// Matted files with coverage masks ([`Masks::Coverage`]) shown over `background`
    /// instead of `files_over`, the colour they were written over: every frame is
    /// recomposited when it is decoded ([`recomposite`]). What [`super::Dataset::show_over`]
    /// makes of a `synth` dataset; it is written to dataset.json as what it was, matted
    /// over `files_over`.
    Reshown { files_over: [f32; 3] },
}

impl Matting {
    pub const fn name(self) -> &'static str {
        match self {
            Matting::Matted | Matting::Reshown { .. } => "matted",
            Matting::ByMask => "by_mask",
        }
    }

    pub fn from_name(name: &str) -> Option<Matting> {
        [Matting::Matted, Matting::ByMask]
            .into_iter()
            .find(|m| m.name() == name)
    }
}

/// What a dataset's masks are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Masks {
    /// A matte, from a matting tool or a renderer: its value is the alpha compositing
    /// uses, soft edges kept, but a matted file's edge pixel cannot be split into the
    /// person and the background it was written over (the default).
    #[default]
    Matte,
    /// Each pixel's exact covered fraction (`"masks": "coverage"`, what `synth` writes):
    /// a matted file's pixel is mask x person + (1 - mask) x background, so the person can
    /// be shown over another colour ([`recomposite`]), as camera captures are scored.
    Coverage,
}

impl Masks {
    pub const fn name(self) -> &'static str {
        match self {
            Masks::Matte => "matte",
            Masks::Coverage => "coverage",
        }
    }

    pub fn from_name(name: &str) -> Option<Masks> {
        [Masks::Matte, Masks::Coverage]
            .into_iter()
            .find(|m| m.name() == name)
    }
}

/// Why a frame's target is not its file as it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Composited {
    /// The file is the target (a matted dataset whose frame agrees with its background).
    No,
    /// The dataset declares `"matting": "by_mask"`.
    Declared,
    /// The dataset declares its images matted, but this frame's surroundings contradict
    /// the background: composited by its mask, and every command that trains says so.
    Contradicted,
    /// A matted file with coverage masks shown over another background
    /// ([`Matting::Reshown`]).
    Reshown,
}

/// A channel farther than this from the background (in [0, 1]) makes a pixel "off".
pub const OFF_BY: f32 = 0.1;
/// A frame whose surroundings hold more than this share of off pixels contradicts its
/// background. JPEG noise or a slightly different white stay far below it; a studio,
/// a room or a dark backdrop lie far above (a camera frame is 60-100% off).
pub const MAX_OFF_SHARE: f32 = 0.05;
/// Pixels within this many pixels of any mask value above 0 are the mask's soft edge,
/// not the surroundings.
pub const EDGE_BAND_PX: u32 = 3;

/// How far a frame's surroundings (pixels outside the mask and its edge band) lie from
/// the background.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surroundings {
    /// Pixels counted.
    pub pixels: usize,
    /// Share of them with a channel more than [`OFF_BY`] from the background.
    pub off_share: f32,
}

impl Surroundings {
    /// The frame does not show the person over the background.
    pub fn contradicts(&self) -> bool {
        self.pixels > 0 && self.off_share > MAX_OFF_SHARE
    }
}

/// Measures `rgb`'s surroundings against `background` (RGB in [0, 1]).
pub fn surroundings(rgb: &RgbImage, mask: &GrayImage, background: [f32; 3]) -> Surroundings {
    let person: Vec<bool> = mask.iter().map(|&m| m > 0).collect();
    let near = dilate(&person, mask.width(), mask.height(), EDGE_BAND_PX);
    let bg = background.map(|c| c * 255.0);
    let (mut pixels, mut off) = (0usize, 0usize);
    for (p, near) in rgb.pixels().zip(near) {
        if near {
            continue;
        }
        let d = (0..3)
            .map(|c| (f32::from(p.0[c]) - bg[c]).abs() / 255.0)
            .fold(0.0f32, f32::max);
        pixels += 1;
        off += usize::from(d > OFF_BY);
    }
    Surroundings {
        pixels,
        off_share: if pixels == 0 {
            0.0
        } else {
            off as f32 / pixels as f32
        },
    }
}

/// image x alpha + background x (1 - alpha), alpha = mask / 255.
pub fn composite(rgb: &RgbImage, mask: &GrayImage, background: [f32; 3]) -> RgbImage {
    let bg = background.map(|c| c * 255.0);
    RgbImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let a = f32::from(mask.get_pixel(x, y).0[0]) / 255.0;
        let p = rgb.get_pixel(x, y).0;
        image::Rgb(std::array::from_fn(|c| {
            (f32::from(p[c]) * a + bg[c] * (1.0 - a))
                .round()
                .clamp(0.0, 255.0) as u8
        }))
    })
}

/// A matted frame over `to` instead of `from`, by its coverage mask `a` = mask / 255: a
/// pixel written as a x person + (1 - a) x from becomes a x person + (1 - a) x to, that
/// is rgb + (1 - a) x (to - from). Exact for coverage masks (up to the files' 8 bits);
/// a matte's edge would keep some of `from`.
pub fn recomposite(rgb: &RgbImage, mask: &GrayImage, from: [f32; 3], to: [f32; 3]) -> RgbImage {
    let shift: [f32; 3] = std::array::from_fn(|c| (to[c] - from[c]) * 255.0);
    RgbImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let a = f32::from(mask.get_pixel(x, y).0[0]) / 255.0;
        let p = rgb.get_pixel(x, y).0;
        image::Rgb(std::array::from_fn(|c| {
            (f32::from(p[c]) + (1.0 - a) * shift[c])
                .round()
                .clamp(0.0, 255.0) as u8
        }))
    })
}

/// The mask-edge width of a camera frame `width` x `height`: 1 px per whole 256 px of its
/// longer side (0 below 256 px, where a pixel is a limb's edge). What `train` leaves out
/// of a `by_mask` frame's random rays by default, and `eval`'s outline (at least 1 px).
pub fn mask_edge_px(width: u32, height: u32) -> u32 {
    width.max(height) / 256
}

/// The mask's uncertain edge (row-major): pixels within `r` px (Chebyshev) of a pixel
/// on the other side of the mask's 128 cut, on either side. A matting tool's mask is
/// off by a pixel or two along its edge, so a target there may be the room or the
/// background where the person is, or the reverse; Neural Body's loaders leave out the
/// band between the mask dilated and eroded by a 5x5 kernel (`r` = 2). Empty for `r` = 0.
pub fn mask_edge_band(mask: &GrayImage, r: u32) -> Vec<bool> {
    if r == 0 {
        return Vec::new();
    }
    let (w, h) = mask.dimensions();
    let person: Vec<bool> = mask.iter().map(|&m| m >= 128).collect();
    let outside: Vec<bool> = person.iter().map(|&p| !p).collect();
    let near_person = dilate(&person, w, h, r);
    let near_outside = dilate(&outside, w, h, r);
    near_person
        .into_iter()
        .zip(near_outside)
        .map(|(a, b)| a && b)
        .collect()
}

/// Whether pixel (x, y) touches the mask's 128 cut: one of its 8 neighbours lies on the
/// other side. The 1 px [`mask_edge_band`], read at one pixel without building the band.
pub fn on_mask_cut(mask: &GrayImage, x: u32, y: u32) -> bool {
    let (w, h) = mask.dimensions();
    let person = |x: u32, y: u32| mask.get_pixel(x, y).0[0] >= 128;
    let here = person(x, y);
    (y.saturating_sub(1)..=(y + 1).min(h - 1))
        .any(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).any(|xx| person(xx, yy) != here))
}

/// `set` (row-major, `w` x `h`) grown by `r` px (Chebyshev): whether each pixel lies
/// within `r` px of a set pixel.
pub fn dilate(set: &[bool], w: u32, h: u32, r: u32) -> Vec<bool> {
    let (w, h, r) = (w as usize, h as usize, r as usize);
    let mut rows = vec![false; w * h];
    for y in 0..h {
        let row = &set[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = row[a..=b].iter().any(|&v| v);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b).any(|yy| rows[yy * w + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edge_band_lies_within_r_of_the_cut_on_both_sides() {
        let (_, mask) = frame([0, 0, 0]);
        assert!(mask_edge_band(&mask, 0).is_empty());
        let band = mask_edge_band(&mask, 2);
        let at = |x: usize, y: usize| band[y * 40 + x];
        // The person is x, y in 15..25: its edge columns 15 and 24.
        for x in 13..=16 {
            assert!(at(x, 20), "x = {x} lies within 2 px of the cut");
        }
        assert!(!at(12, 20) && !at(17, 20) && !at(20, 20) && !at(0, 0));
        assert!(at(23, 20) && at(26, 20) && !at(27, 20));
        // An empty or a full mask has no edge.
        assert!(!mask_edge_band(&GrayImage::new(8, 8), 2).contains(&true));
        let full = GrayImage::from_pixel(8, 8, image::Luma([255]));
        assert!(!mask_edge_band(&full, 2).contains(&true));
    }

    #[test]
    fn the_cut_at_one_pixel_is_the_one_pixel_band() {
        // A ragged mask: a box, a hole, a diagonal, and person on the frame's border.
        let mask = GrayImage::from_fn(23, 17, |x, y| {
            let inside = (3..15).contains(&x) && (2..12).contains(&y) && !(x == 8 && y == 6);
            let diagonal = x + 2 == y || x == 0;
            image::Luma([if inside || diagonal { 200 } else { 40 }])
        });
        let band = mask_edge_band(&mask, 1);
        for y in 0..17 {
            for x in 0..23 {
                assert_eq!(
                    on_mask_cut(&mask, x, y),
                    band[(y * 23 + x) as usize],
                    "({x}, {y})"
                );
            }
        }
        assert!(band.contains(&true) && band.contains(&false));
    }

    /// A 40x40 frame: a 10x10 person at (15, 15) over `bg` (8-bit), its exact mask.
    fn frame(bg: [u8; 3]) -> (RgbImage, GrayImage) {
        let mut rgb = RgbImage::from_pixel(40, 40, image::Rgb(bg));
        let mut mask = GrayImage::new(40, 40);
        for y in 15..25 {
            for x in 15..25 {
                rgb.put_pixel(x, y, image::Rgb([200, 30, 30]));
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        (rgb, mask)
    }

    #[test]
    fn a_matted_frame_agrees_and_a_studio_contradicts() {
        let (rgb, mask) = frame([255, 255, 255]);
        let s = surroundings(&rgb, &mask, [1.0; 3]);
        assert_eq!(s.off_share, 0.0);
        assert!(!s.contradicts());
        // Band excluded: 40^2 - 16^2 pixels.
        assert_eq!(s.pixels, 40 * 40 - 16 * 16);
        let (dark, mask) = frame([20, 22, 25]);
        let s = surroundings(&dark, &mask, [1.0; 3]);
        assert!(s.contradicts() && s.off_share == 1.0, "{s:?}");
    }

    #[test]
    fn compositing_keeps_the_person_and_soft_edges() {
        let (dark, mut mask) = frame([20, 22, 25]);
        mask.put_pixel(14, 20, image::Luma([128]));
        let out = composite(&dark, &mask, [1.0; 3]);
        assert_eq!(out.get_pixel(20, 20).0, [200, 30, 30]);
        assert_eq!(out.get_pixel(0, 0).0, [255, 255, 255]);
        // Half alpha: halfway between the dark pixel and white.
        let a = 128.0f32 / 255.0;
        let want = (20.0 * a + 255.0 * (1.0 - a)).round() as u8;
        assert_eq!(out.get_pixel(14, 20).0[0], want);
        assert!(!surroundings(&out, &mask, [1.0; 3]).contradicts());
    }

    #[test]
    fn an_empty_or_full_mask_is_no_contradiction() {
        let (rgb, _) = frame([0, 0, 0]);
        let full = GrayImage::from_pixel(40, 40, image::Luma([255]));
        let s = surroundings(&rgb, &full, [1.0; 3]);
        assert_eq!((s.pixels, s.contradicts()), (0, false));
        let empty = GrayImage::new(40, 40);
        assert!(surroundings(&rgb, &empty, [1.0; 3]).contradicts());
    }
}
