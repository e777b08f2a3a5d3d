//! Two panels against the noise level: test_same PSNR with and without refinement, and
//! the training fits' joint error before and after it.

use image::RgbImage;
use plotters::prelude::*;

use super::Level;
use crate::plot_style::{font_ready, labelled_line, legend};

const W: u32 = 900;
const H: u32 = 400;

/// Errors are plotters' drawing errors, as text.
pub fn plot_levels(levels: &[Level]) -> Result<RgbImage, String> {
    if !font_ready() {
        return Err("the plot's font (DejaVu Sans) could not be loaded".into());
    }
    let x_max = levels.iter().map(|l| l.noise_deg).fold(1.0, f64::max) * 1.05;
    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let root = BitMapBackend::with_buffer(&mut buffer, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let panels = root.split_evenly((1, 2));
        let psnr = |l: &Level| [(l.noise_deg, l.psnr_without), (l.noise_deg, l.psnr_with)];
        let joint = |l: &Level| {
            [
                (l.noise_deg, 1e3 * l.joint_error_before_m),
                (l.noise_deg, 1e3 * l.joint_error_after_m),
            ]
        };
        type Pick = dyn Fn(&Level) -> [(f64, f64); 2];
        let specs: [(&str, &str, &Pick, [&str; 2]); 2] = [
            (
                "test_same PSNR",
                "PSNR (dB)",
                &psnr,
                ["without refinement", "with refinement"],
            ),
            (
                "training fits' joint error",
                "mean joint error (mm)",
                &joint,
                ["noisy fits", "refined fits"],
            ),
        ];
        for (panel, (title, y_desc, pick, names)) in panels.iter().zip(specs) {
            let ys: Vec<f64> = levels.iter().flat_map(|l| pick(l).map(|p| p.1)).collect();
            let (lo, hi) = ys
                .iter()
                .filter(|y| y.is_finite())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
                    (a.min(y), b.max(y))
                });
            let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 1.0) };
            let pad = 0.1 * (hi - lo).max(1.0);
            // Headroom above the points for the legend (top right), so it hides none.
            let headroom = 0.45 * (hi - lo).max(1.0);
            let mut chart = ChartBuilder::on(panel)
                .margin(14)
                .caption(title, ("sans-serif", 18))
                .x_label_area_size(40)
                .y_label_area_size(52)
                .build_cartesian_2d(-0.3..x_max, lo - pad..hi + pad + headroom)
                .map_err(e)?;
            chart
                .configure_mesh()
                .x_desc("injected noise (degrees RMS)")
                .y_desc(y_desc)
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .light_line_style(RGBColor(244, 244, 244))
                .draw()
                .map_err(e)?;
            for (k, (name, colour)) in names
                .into_iter()
                .zip([RGBColor(200, 80, 40), RGBColor(40, 110, 200)])
                .enumerate()
            {
                let pts: Vec<(f64, f64)> = levels
                    .iter()
                    .map(|l| pick(l)[k])
                    .filter(|p| p.1.is_finite())
                    .collect();
                labelled_line(&mut chart, name, colour, &pts)?;
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
    use crate::shared::Scores;

    fn level(noise_deg: f64, without: f64, with: f64, before: f64, after: f64) -> Level {
        let scores = |psnr| Scores {
            psnr,
            ssim: 0.9,
            lpips: None,
            psnr_person: None,
            psnr_face: None,
            psnr_hands: None,
        };
        Level {
            noise_deg,
            psnr_without: without,
            psnr_with: with,
            without: scores(without),
            with: scores(with),
            joint_error_before_m: before,
            joint_error_after_m: after,
            rotation_error_before_deg: 0.0,
            rotation_error_after_deg: 0.0,
            steps_without: 1,
            steps_with: 1,
        }
    }

    #[test]
    fn plots_levels_and_survives_degenerate_input() {
        let levels = [
            level(0.0, 24.0, 23.9, 0.0, 0.004),
            level(6.0, 15.4, 18.2, 0.063, 0.024),
        ];
        let img = plot_levels(&levels).unwrap();
        assert_eq!(img.dimensions(), (W, H));
        // Both colours are drawn.
        let has = |c: [u8; 3]| img.pixels().any(|p| p.0 == c);
        assert!(has([200, 80, 40]) && has([40, 110, 200]));
        assert!(plot_levels(&[]).is_ok());
        assert!(plot_levels(&[level(3.0, f64::NAN, f64::NAN, f64::NAN, 0.01)]).is_ok());
    }
}
