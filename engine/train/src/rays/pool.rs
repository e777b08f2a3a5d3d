//! Where a frame's random rays come from: the person's box, its hand and arm pixels, the
//! whole image, and the mask's uncertain edge, which no random ray lands on.

use image::GrayImage;
use talkin_data::dataset::mask_edge_band;

use super::BatchSpec;
use talkin_grids::SplitMix64;

/// Segmentation labels of arms and hands.
const LABEL_ARMS: u8 = 2;
const LABEL_HANDS: u8 = 3;

/// Draws of a random pixel before one on the mask's edge is kept (the edge is a thin
/// band, so sixteen draws in a row on it almost never happen).
const EDGE_REDRAWS: usize = 16;

/// A frame's pixels as the random rays see them.
pub(crate) struct PixelPool {
    width: u32,
    height: u32,
    /// Person bounding box in pixels, inclusive (`None`: empty mask).
    pub bbox: Option<[u32; 4]>,
    /// The mask's uncertain edge, row-major (empty: none is left out).
    edge: Vec<bool>,
    /// Pixels labelled hands / arms, off the edge (unless every one of them is on it: a
    /// hand thinner than the edge still gets rays).
    hand_pixels: Vec<(u32, u32)>,
    arm_pixels: Vec<(u32, u32)>,
}

impl PixelPool {
    /// The pool of a frame with `mask` (person: >= 128) and `segmentation`, leaving out
    /// the pixels within `mask_edge` px of the mask's cut.
    pub fn new(mask: &GrayImage, segmentation: &GrayImage, mask_edge: u32) -> PixelPool {
        let (width, height) = mask.dimensions();
        let mut bbox: Option<[u32; 4]> = None;
        let (mut hand_pixels, mut arm_pixels) = (Vec::new(), Vec::new());
        for (x, y, m) in mask.enumerate_pixels() {
            if m.0[0] < 128 {
                continue;
            }
            bbox = Some(match bbox {
                None => [x, y, x, y],
                Some([x0, y0, x1, y1]) => [x0.min(x), y0.min(y), x1.max(x), y1.max(y)],
            });
            match segmentation.get_pixel(x, y).0[0] {
                LABEL_HANDS => hand_pixels.push((x, y)),
                LABEL_ARMS => arm_pixels.push((x, y)),
                _ => {}
            }
        }
        let mut pool = PixelPool {
            width,
            height,
            bbox,
            edge: mask_edge_band(mask, mask_edge),
            hand_pixels: Vec::new(),
            arm_pixels: Vec::new(),
        };
        pool.hand_pixels = pool.off_edge(hand_pixels);
        pool.arm_pixels = pool.off_edge(arm_pixels);
        pool
    }

    /// Whether pixel (x, y) lies on the mask's uncertain edge.
    pub fn on_edge(&self, x: u32, y: u32) -> bool {
        !self.edge.is_empty() && self.edge[y as usize * self.width as usize + x as usize]
    }

    fn off_edge(&self, list: Vec<(u32, u32)>) -> Vec<(u32, u32)> {
        let kept: Vec<(u32, u32)> = list
            .iter()
            .copied()
            .filter(|&(x, y)| !self.on_edge(x, y))
            .collect();
        if kept.is_empty() { list } else { kept }
    }

    /// One random pixel off the mask's edge: drawn as [`Self::draw_any`], again while it
    /// lands on the edge (at most [`EDGE_REDRAWS`] times).
    pub fn draw(&self, spec: &BatchSpec, rng: &mut SplitMix64) -> (u32, u32) {
        let mut pixel = self.draw_any(spec, rng);
        for _ in 1..EDGE_REDRAWS {
            if !self.on_edge(pixel.0, pixel.1) {
                break;
            }
            pixel = self.draw_any(spec, rng);
        }
        pixel
    }

    /// One random pixel: in the person's box with odds `spec.bbox_fraction` (from the
    /// hand or arm pixels at the schedule's fractions), else anywhere in the image.
    fn draw_any(&self, spec: &BatchSpec, rng: &mut SplitMix64) -> (u32, u32) {
        let pick =
            |list: &[(u32, u32)], rng: &mut SplitMix64| list[rng.below(list.len() as u64) as usize];
        match self.bbox {
            Some([x0, y0, x1, y1]) if rng.next_f32() < spec.bbox_fraction => {
                let u = rng.next_f32();
                if u < spec.parts.hands && !self.hand_pixels.is_empty() {
                    pick(&self.hand_pixels, rng)
                } else if u < spec.parts.hands + spec.parts.arms && !self.arm_pixels.is_empty() {
                    pick(&self.arm_pixels, rng)
                } else {
                    (
                        x0 + rng.below(u64::from(x1 - x0 + 1)) as u32,
                        y0 + rng.below(u64::from(y1 - y0 + 1)) as u32,
                    )
                }
            }
            _ => (
                rng.below(u64::from(self.width)) as u32,
                rng.below(u64::from(self.height)) as u32,
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schedule::PartFractions;

    /// A 64x64 frame: a 20x30 person at (20, 10), its left 4 columns labelled hands.
    fn frame() -> (GrayImage, GrayImage) {
        let mut mask = GrayImage::new(64, 64);
        let mut seg = GrayImage::new(64, 64);
        for y in 10..40 {
            for x in 20..40 {
                mask.put_pixel(x, y, image::Luma([255]));
                seg.put_pixel(x, y, image::Luma([if x < 24 { LABEL_HANDS } else { 1 }]));
            }
        }
        (mask, seg)
    }

    fn spec(hands: f32) -> BatchSpec {
        BatchSpec {
            patches: 0,
            random_rays: 0,
            bbox_fraction: 0.8,
            parts: PartFractions { hands, arms: 0.0 },
        }
    }

    #[test]
    fn random_pixels_stay_off_the_mask_edge() {
        let (mask, seg) = frame();
        let pool = PixelPool::new(&mask, &seg, 2);
        assert_eq!(pool.bbox, Some([20, 10, 39, 39]));
        let mut rng = SplitMix64::new(3);
        let drawn: Vec<(u32, u32)> = (0..4000).map(|_| pool.draw(&spec(0.3), &mut rng)).collect();
        assert!(drawn.iter().all(|&(x, y)| !pool.on_edge(x, y)));
        // The hands keep their pixels off the edge (columns 22-23 of rows 12-37).
        let hands = drawn
            .iter()
            .filter(|&&(x, y)| (20..24).contains(&x) && (10..40).contains(&y))
            .count();
        assert!(hands > 800, "{hands} hand pixels of 4000 draws");
        // Without an edge, every pixel can be drawn, the edge's too.
        let all = PixelPool::new(&mask, &seg, 0);
        let mut rng = SplitMix64::new(3);
        let drawn: Vec<(u32, u32)> = (0..4000).map(|_| all.draw(&spec(0.3), &mut rng)).collect();
        assert!(drawn.iter().any(|&(x, y)| pool.on_edge(x, y)));
    }

    #[test]
    fn a_hand_thinner_than_the_edge_keeps_its_pixels() {
        let (mask, seg) = frame();
        let pool = PixelPool::new(&mask, &seg, 4);
        assert_eq!(pool.hand_pixels.len(), 4 * 30);
        let pool = PixelPool::new(&mask, &seg, 1);
        // Columns 21-23 off the edge's inner pixel, rows 11-38.
        assert_eq!(pool.hand_pixels.len(), 3 * 28);
    }

    #[test]
    fn an_empty_mask_draws_anywhere() {
        let pool = PixelPool::new(&GrayImage::new(8, 8), &GrayImage::new(8, 8), 2);
        assert_eq!(pool.bbox, None);
        let mut rng = SplitMix64::new(1);
        for _ in 0..100 {
            let (x, y) = pool.draw(&spec(0.3), &mut rng);
            assert!(x < 8 && y < 8);
        }
    }
}
