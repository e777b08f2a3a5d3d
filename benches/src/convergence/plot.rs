//! Three panels against the training budget (steps, log scale): the person box's PSNR,
//! the anchors' LPIPS-VGG (LPIPS* where the run was not scored by the anchors' protocol)
//! and the thickness inside the mask, each for held-out and training frames; one dot per
//! seed, the line through the seeds' mean.

use image::RgbImage;
use plotters::prelude::*;

use super::{Mark, Point};
use crate::plot_style::{font_ready, labelled_line, legend};

const W: u32 = 1350;
const H: u32 = 420;

type Pick = fn(&Mark) -> Option<f64>;

/// Errors are plotters' drawing errors, as text.
pub fn plot_points(points: &[Point]) -> Result<RgbImage, String> {
    if !font_ready() {
        return Err("the plot's font (DejaVu Sans) could not be loaded".into());
    }
    let vgg = points
        .iter()
        .all(|p| p.held_out.anchors_lpips_vgg.is_some());
    let lpips: (&str, Pick) = if vgg {
        ("LPIPS-VGG x1000 (anchors)", |m| m.anchors_lpips_vgg)
    } else {
        ("person box LPIPS* (AlexNet)", |m| m.lpips_person)
    };
    let specs: [(&str, Pick); 3] = [
        ("person box PSNR (dB)", |m| m.psnr_person),
        lpips,
        ("thickness inside the mask, median (mm)", |m| {
            m.thickness_median_mm
        }),
    ];
    let mut steps: Vec<usize> = points.iter().map(|p| p.steps).collect();
    steps.sort_unstable();
    steps.dedup();
    let x_lo = steps.first().map_or(1.0, |&s| s as f64 / 1.4);
    let x_hi = steps
        .last()
        .map_or(10.0, |&s| s as f64 * 1.4)
        .max(x_lo * 2.0);
    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let root = BitMapBackend::with_buffer(&mut buffer, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        for (panel, (title, pick)) in root.split_evenly((1, 3)).iter().zip(specs) {
            let marks = |held_out: bool| -> Vec<(f64, f64)> {
                points
                    .iter()
                    .filter_map(|p| {
                        let m = if held_out { &p.held_out } else { &p.training };
                        pick(m)
                            .filter(|v| v.is_finite())
                            .map(|v| (p.steps as f64, v))
                    })
                    .collect()
            };
            let all: Vec<f64> = [marks(true), marks(false)]
                .iter()
                .flatten()
                .map(|p| p.1)
                .collect();
            let (lo, hi) = all
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
                    (a.min(y), b.max(y))
                });
            let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 1.0) };
            let pad = 0.1 * (hi - lo).max(0.5);
            let headroom = 0.4 * (hi - lo).max(0.5);
            let mut chart = ChartBuilder::on(panel)
                .margin(14)
                .caption(title, ("sans-serif", 16))
                .x_label_area_size(40)
                .y_label_area_size(52)
                .build_cartesian_2d((x_lo..x_hi).log_scale(), lo - pad..hi + pad + headroom)
                .map_err(e)?;
            chart
                .configure_mesh()
                .x_desc("training steps")
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .light_line_style(RGBColor(244, 244, 244))
                .draw()
                .map_err(e)?;
            for (name, held_out, colour) in [
                ("held-out frames", true, RGBColor(200, 80, 40)),
                ("training frames", false, RGBColor(40, 110, 200)),
            ] {
                let pts = marks(held_out);
                let means: Vec<(f64, f64)> = steps
                    .iter()
                    .filter_map(|&s| {
                        let ys: Vec<f64> = pts
                            .iter()
                            .filter(|p| p.0 == s as f64)
                            .map(|p| p.1)
                            .collect();
                        (!ys.is_empty())
                            .then(|| (s as f64, ys.iter().sum::<f64>() / ys.len() as f64))
                    })
                    .collect();
                labelled_line(&mut chart, name, colour, &means)?;
                chart
                    .draw_series(
                        pts.iter()
                            .map(|p| Circle::new(*p, 3, colour.stroke_width(1))),
                    )
                    .map_err(e)?;
            }
            legend(&mut chart, SeriesLabelPosition::UpperRight, 13)?;
        }
        root.present().map_err(e)?;
    }
    RgbImage::from_raw(W, H, buffer).ok_or_else(|| "plot buffer of the wrong size".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mark(psnr: f64, vgg: Option<f64>, thick: f64) -> Mark {
        Mark {
            frames: 1,
            psnr_person: Some(psnr),
            ssim_person: None,
            lpips_person: Some(100.0),
            psnr_inside: None,
            anchors_psnr: None,
            anchors_ssim: None,
            anchors_lpips_vgg: vgg,
            thickness_median_mm: Some(thick),
            thickness_p90_mm: None,
        }
    }

    #[test]
    fn plots_budgets_and_seeds_and_survives_degenerate_input() {
        let point = |steps, seed, psnr| Point {
            steps,
            seed,
            train_seconds: 1.0,
            held_out: mark(psnr, Some(70.0), 20.0),
            training: mark(psnr + 0.5, None, 18.0),
        };
        let img = plot_points(&[
            point(3000, 0, 24.5),
            point(3000, 1, 24.7),
            point(12000, 0, 25.0),
        ])
        .unwrap();
        assert_eq!(img.dimensions(), (W, H));
        let has = |c: [u8; 3]| img.pixels().any(|p| p.0 == c);
        assert!(has([200, 80, 40]) && has([40, 110, 200]));
        assert!(plot_points(&[]).is_ok());
        assert!(plot_points(&[point(1, 0, f64::NAN)]).is_ok());
    }
}
