//! Removing lens distortion (OpenCV's model: k1, k2, p1, p2, k3) from images and masks,
//! as `cv2.undistort(img, K, D)` does with the new camera matrix equal to K: every output
//! (undistorted) pixel looks up where the lens put it, by applying the distortion to its
//! normalised coordinates, and samples there (bilinear for images, nearest for masks; 0
//! outside the stored image). Coordinates are OpenCV's: pixel centres at integers.
//!
//! [`undistort_point`] is the inverse map for single points (fixed-point iteration, as
//! `cv2.undistortPoints` does), used where a distorted pixel must be located in the
//! undistorted image.

use glam::DVec2;
use image::{GrayImage, Rgb, RgbImage};

/// Normalised camera coordinates of pixel `p` under K.
fn normalise(k: &[[f64; 3]; 3], p: DVec2) -> DVec2 {
    let y = (p.y - k[1][2]) / k[1][1];
    let x = (p.x - k[0][2] - k[0][1] * y) / k[0][0];
    DVec2::new(x, y)
}

fn to_pixel(k: &[[f64; 3]; 3], n: DVec2) -> DVec2 {
    DVec2::new(
        k[0][0] * n.x + k[0][1] * n.y + k[0][2],
        k[1][1] * n.y + k[1][2],
    )
}

/// OpenCV's distortion of normalised coordinates.
pub fn distort_normalised(n: DVec2, d: &[f64; 5]) -> DVec2 {
    let [k1, k2, p1, p2, k3] = *d;
    let r2 = n.length_squared();
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    DVec2::new(
        n.x * radial + 2.0 * p1 * n.x * n.y + p2 * (r2 + 2.0 * n.x * n.x),
        n.y * radial + p1 * (r2 + 2.0 * n.y * n.y) + 2.0 * p2 * n.x * n.y,
    )
}

/// Where undistorted pixel `p` lies in the distorted (stored) image.
pub fn distort_pixel(k: &[[f64; 3]; 3], d: &[f64; 5], p: DVec2) -> DVec2 {
    to_pixel(k, distort_normalised(normalise(k, p), d))
}

/// Where distorted pixel `p` lies in the undistorted image (the inverse of
/// [`distort_pixel`], by fixed-point iteration on the normalised coordinates).
pub fn undistort_point(k: &[[f64; 3]; 3], d: &[f64; 5], p: DVec2) -> DVec2 {
    let target = normalise(k, p);
    let mut n = target;
    for _ in 0..50 {
        let err = distort_normalised(n, d) - target;
        if err.length() < 1e-12 {
            break;
        }
        n -= err;
    }
    to_pixel(k, n)
}

/// The undistorted image (same size and K), bilinear.
pub fn undistort_rgb(img: &RgbImage, k: &[[f64; 3]; 3], d: &[f64; 5]) -> RgbImage {
    let (w, h) = img.dimensions();
    RgbImage::from_fn(w, h, |x, y| {
        let s = distort_pixel(k, d, DVec2::new(x as f64, y as f64));
        let (x0, y0) = (s.x.floor(), s.y.floor());
        let (fx, fy) = (s.x - x0, s.y - y0);
        let mut acc = [0.0f64; 3];
        for (dx, dy, wgt) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let (sx, sy) = (x0 as i64 + dx, y0 as i64 + dy);
            if sx >= 0 && sy >= 0 && sx < w as i64 && sy < h as i64 {
                let p = img.get_pixel(sx as u32, sy as u32);
                for c in 0..3 {
                    acc[c] += wgt * p[c] as f64;
                }
            }
        }
        Rgb(acc.map(|v| v.round().clamp(0.0, 255.0) as u8))
    })
}

/// The undistorted mask (same size and K), nearest: labels and hard edges stay as they are.
pub fn undistort_mask(mask: &GrayImage, k: &[[f64; 3]; 3], d: &[f64; 5]) -> GrayImage {
    let (w, h) = mask.dimensions();
    GrayImage::from_fn(w, h, |x, y| {
        let s = distort_pixel(k, d, DVec2::new(x as f64, y as f64));
        let (sx, sy) = (s.x.round(), s.y.round());
        if sx >= 0.0 && sy >= 0.0 && sx < w as f64 && sy < h as f64 {
            *mask.get_pixel(sx as u32, sy as u32)
        } else {
            image::Luma([0])
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const K: [[f64; 3]; 3] = [[80.0, 0.0, 31.5], [0.0, 82.0, 23.5], [0.0, 0.0, 1.0]];
    const D: [f64; 5] = [-0.2, 0.05, 0.001, -0.002, 0.01];

    #[test]
    fn undistort_point_inverts_the_distortion() {
        for &(x, y) in &[(0.0, 0.0), (63.0, 47.0), (10.0, 40.0), (31.5, 23.5)] {
            let p = DVec2::new(x, y);
            let back = distort_pixel(&K, &D, undistort_point(&K, &D, p));
            assert!((back - p).length() < 1e-9, "{p} -> {back}");
        }
        // A real distortion moves the corners.
        assert!((undistort_point(&K, &D, DVec2::ZERO) - DVec2::ZERO).length() > 1.0);
    }

    #[test]
    fn a_dot_moves_to_its_undistorted_place() {
        // A distorted image with one bright pixel near a corner: after undistortion the
        // bright pixel sits where undistort_point puts it.
        let (w, h) = (64, 48);
        let src = DVec2::new(6.0, 5.0);
        let mut img = RgbImage::new(w, h);
        img.put_pixel(src.x as u32, src.y as u32, Rgb([255, 255, 255]));
        let out = undistort_rgb(&img, &K, &D);
        let (bx, by) = out
            .enumerate_pixels()
            .max_by_key(|(_, _, p)| p[0])
            .map(|(x, y, _)| (x, y))
            .unwrap();
        let want = undistort_point(&K, &D, src);
        assert!(
            (DVec2::new(bx as f64, by as f64) - want).length() <= 1.0,
            "bright pixel at ({bx}, {by}), expected near {want}"
        );
        let mut mask = GrayImage::new(w, h);
        mask.put_pixel(src.x as u32, src.y as u32, image::Luma([255]));
        let m = undistort_mask(&mask, &K, &D);
        assert!(m.pixels().all(|p| p[0] == 0 || p[0] == 255));
    }

    #[test]
    fn zero_distortion_is_the_identity() {
        let img = RgbImage::from_fn(16, 12, |x, y| Rgb([x as u8 * 10, y as u8 * 20, 7]));
        assert_eq!(undistort_rgb(&img, &K, &[0.0; 5]), img);
    }
}
