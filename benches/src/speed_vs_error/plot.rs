//! The PSNR-against-training-seconds plot, drawn with `plotters`: one line per run on a
//! logarithmic time axis (a speed-up is then the same horizontal distance at any time;
//! the untrained start at 0 s is left off), each target PSNR as a dashed level, labelled
//! axes and a legend. Text is DejaVu Sans from the `dejavu` crate: no system fonts.

use image::RgbImage;
use plotters::prelude::*;

use crate::plot_style::{font_ready, labelled_line, legend};

const W: u32 = 760;
const H: u32 = 460;

/// One line: name, colour, points (seconds, psnr).
pub type Curve<'a> = (&'a str, [u8; 3], Vec<(f64, f64)>);

/// The colour of the target levels.
pub const TARGET_COLOUR: [u8; 3] = [120, 120, 120];

/// `targets`: PSNRs drawn as dashed levels. Errors are plotters' drawing errors, as text.
pub fn plot_psnr_vs_seconds(curves: &[Curve], targets: &[f64]) -> Result<RgbImage, String> {
    if !font_ready() {
        return Err("the plot's font (DejaVu Sans) could not be loaded".into());
    }
    let finite = |pts: &[(f64, f64)]| -> Vec<(f64, f64)> {
        pts.iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && *x > 0.0 && y.is_finite())
            .collect()
    };
    let all: Vec<(f64, f64)> = curves.iter().flat_map(|c| finite(&c.2)).collect();
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
    let (x_min, x_max) = (10f64.powf(d_lo), 10f64.powf(d_hi));
    let levels: Vec<f64> = targets.iter().copied().filter(|t| t.is_finite()).collect();
    let (mut y_min, mut y_max) = all
        .iter()
        .map(|p| p.1)
        .chain(levels.iter().copied())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
            (a.min(y), b.max(y))
        });
    if !(y_min.is_finite() && y_max.is_finite()) {
        (y_min, y_max) = (0.0, 40.0);
    }
    let (y_min, y_max) = ((y_min - 1.0).floor(), (y_max + 1.0).ceil());

    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let root = BitMapBackend::with_buffer(&mut buffer, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(14)
            .caption(
                "PSNR on test_same against training time",
                ("sans-serif", 20),
            )
            .x_label_area_size(44)
            .y_label_area_size(52)
            .build_cartesian_2d((x_min..x_max).log_scale(), y_min..y_max)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("training seconds (log scale)")
            .y_desc("PSNR (dB)")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .light_line_style(RGBColor(244, 244, 244))
            .x_label_formatter(&|x| {
                if *x >= 1.0 {
                    format!("{x:.0}")
                } else {
                    format!("{x}")
                }
            })
            .y_label_formatter(&|y| format!("{y:.0}"))
            .draw()
            .map_err(e)?;
        let grey = RGBColor(TARGET_COLOUR[0], TARGET_COLOUR[1], TARGET_COLOUR[2]);
        for level in &levels {
            chart
                .draw_series(DashedLineSeries::new(
                    [(x_min, *level), (x_max, *level)],
                    8,
                    6,
                    grey.stroke_width(1),
                ))
                .map_err(e)?;
        }
        for (name, [r, g, b], pts) in curves {
            let colour = RGBColor(*r, *g, *b);
            let pts = finite(pts);
            labelled_line(&mut chart, name, colour, &pts)?;
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight, 15)?;
        root.present().map_err(e)?;
    }
    RgbImage::from_raw(W, H, buffer).ok_or_else(|| "plot buffer of the wrong size".into())
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
        )
        .unwrap();
        // Both colours were drawn, and the targets' dashed levels.
        let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count([230, 90, 30]) > 50 && count([40, 90, 200]) > 50);
        assert!(count(TARGET_COLOUR) > 100);
        // Text was drawn (dark pixels left of the plot: the tick labels).
        let dark_left = (0..H)
            .flat_map(|y| (0..60).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&v| v < 100))
            .count();
        assert!(dark_left > 30, "{dark_left}");
        // Empty and NaN input: still an image, no panic.
        let empty = plot_psnr_vs_seconds(
            &[("dense", [0, 0, 255], vec![(f64::NAN, 1.0), (0.0, 3.0)])],
            &[f64::NAN],
        )
        .unwrap();
        assert_eq!(empty.dimensions(), (W, H));
    }
}
