//! The PSNR-against-training-seconds plot: one polyline per run on a logarithmic time
//! axis (a speed-up is then the same horizontal distance at any time; the untrained start
//! at 0 s is left off), each target PSNR as a dashed level, axes with numbered ticks (a
//! 3x5 pixel font, scaled).

use image::{Rgb, RgbImage};

use talkin_data::draw::{dot, line};
use talkin_data::text::draw_text;

const W: u32 = 720;
const H: u32 = 440;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 60.0;

/// One polyline: name, colour, points (seconds, psnr).
pub type Curve<'a> = (&'a str, [u8; 3], Vec<(f64, f64)>);

/// `targets`: PSNRs drawn as dashed levels.
pub fn plot_psnr_vs_seconds(curves: &[Curve], targets: &[f64]) -> RgbImage {
    let mut img = RgbImage::from_pixel(W, H, Rgb([255, 255, 255]));
    let all: Vec<(f64, f64)> = curves
        .iter()
        .flat_map(|c| c.2.iter().copied())
        .filter(|(x, y)| x.is_finite() && *x > 0.0 && y.is_finite())
        .collect();
    // Whole decades around the points.
    let (x_lo, x_hi) = all
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
    let (d_lo, d_hi) = if x_lo.is_finite() {
        let lo = x_lo.log10().floor();
        (lo, x_hi.log10().ceil().max(lo + 1.0))
    } else {
        (0.0, 3.0)
    };
    let levels = targets.iter().copied().filter(|t| t.is_finite());
    let (mut y_min, mut y_max) = all
        .iter()
        .map(|p| p.1)
        .chain(levels.clone())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
            (a.min(y), b.max(y))
        });
    if !(y_min.is_finite() && y_max.is_finite()) {
        (y_min, y_max) = (0.0, 40.0);
    }
    let (y_min, y_max) = ((y_min - 1.0).floor(), (y_max + 1.0).ceil());
    let px = |x: f64| LEFT + (x.log10() - d_lo) / (d_hi - d_lo) * (f64::from(W) - LEFT - RIGHT);
    let py = |y: f64| {
        f64::from(H) - BOTTOM - (y - y_min) / (y_max - y_min) * (f64::from(H) - TOP - BOTTOM)
    };
    let (x_min, x_max) = (10f64.powf(d_lo), 10f64.powf(d_hi));
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    // Axes, ticks and grid: 1, 2 and 5 of every decade.
    line(
        &mut img,
        (LEFT, py(y_min)),
        (px(x_max), py(y_min)),
        black,
        1,
    );
    line(&mut img, (LEFT, py(y_min)), (LEFT, py(y_max)), black, 1);
    for decade in d_lo as i32..=d_hi as i32 {
        for m in [1.0, 2.0, 5.0] {
            let x = m * 10f64.powi(decade);
            if x < x_min * 0.999 || x > x_max * 1.001 {
                continue;
            }
            let colour = if m == 1.0 { grey } else { [230, 230, 230] };
            line(&mut img, (px(x), py(y_min)), (px(x), py(y_max)), colour, 0);
            let label = if x >= 1.0 {
                format!("{x:.0}")
            } else {
                format!("{x}")
            };
            draw_text(
                &mut img,
                &label,
                px(x) as i64 - 6,
                py(y_min) as i64 + 8,
                2,
                black,
            );
        }
    }
    let y_step = nice_step((y_max - y_min) / 6.0);
    let mut y = (y_min / y_step).ceil() * y_step;
    while y <= y_max {
        line(&mut img, (LEFT, py(y)), (px(x_max), py(y)), grey, 0);
        draw_text(&mut img, &format!("{y:.0}"), 20, py(y) as i64 - 5, 2, black);
        y += y_step;
    }
    draw_text(
        &mut img,
        "training seconds (log)",
        W as i64 / 2 - 120,
        i64::from(H) - 28,
        2,
        black,
    );
    draw_text(&mut img, "psnr db", 8, 12, 2, black);
    // The targets, dashed.
    for level in levels {
        let (a, b) = (px(x_min), px(x_max));
        let dash = (b - a) / 80.0;
        let mut x0 = a;
        while x0 < b {
            let x1 = (x0 + dash).min(b);
            line(
                &mut img,
                (x0, py(level)),
                (x1, py(level)),
                [120, 120, 120],
                0,
            );
            x0 += 2.0 * dash;
        }
    }
    // Curves and legend.
    for (k, (name, colour, pts)) in curves.iter().enumerate() {
        let pts: Vec<(f64, f64)> = pts
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && *x > 0.0 && y.is_finite())
            .collect();
        for w in pts.windows(2) {
            line(
                &mut img,
                (px(w[0].0), py(w[0].1)),
                (px(w[1].0), py(w[1].1)),
                *colour,
                1,
            );
        }
        for p in &pts {
            dot(&mut img, (px(p.0), py(p.1)), *colour, 3);
        }
        let ly = 14 + 18 * k as i64;
        line(
            &mut img,
            (f64::from(W) - 230.0, ly as f64 + 5.0),
            (f64::from(W) - 200.0, ly as f64 + 5.0),
            *colour,
            2,
        );
        draw_text(&mut img, name, i64::from(W) - 190, ly, 2, black);
    }
    img
}

/// 1, 2 or 5 times a power of ten, at least `raw`.
fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plots_curves_and_survives_degenerate_input() {
        let img = plot_psnr_vs_seconds(
            &[
                (
                    "accelerated",
                    [230, 90, 30],
                    vec![(0.0, 10.0), (3.0, 16.0), (30.0, 20.0), (60.0, 24.0)],
                ),
                (
                    "dense",
                    [40, 90, 200],
                    vec![(0.0, 10.0), (60.0, 18.0), (900.0, 22.0)],
                ),
            ],
            &[18.0, 22.0],
        );
        // Both colours were drawn.
        let has = |c: [u8; 3]| img.pixels().any(|p| p.0 == c);
        assert!(has([230, 90, 30]) && has([40, 90, 200]));
        // The targets' dashed levels.
        assert!(has([120, 120, 120]));
        // Empty and NaN input: still an image, no panic.
        let empty = plot_psnr_vs_seconds(
            &[("dense", [0, 0, 255], vec![(f64::NAN, 1.0), (0.0, 3.0)])],
            &[f64::NAN],
        );
        assert_eq!(empty.dimensions(), (W, H));
        assert_eq!(nice_step(37.0), 50.0);
        assert_eq!(nice_step(0.3), 0.5);
    }
}
