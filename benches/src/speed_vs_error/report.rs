//! What the benchmark writes: `summary.json`, `speed_vs_error.csv` (every evaluation),
//! `speed_vs_error.png` (PSNR against training seconds, targets marked) and `report.md`
//! (the tables the terminal also prints).

use std::path::Path;

use serde::Serialize;

use super::plot::{Curve, plot_psnr_vs_seconds};
use super::run::{Point, StepCost, Stop};
use super::targets::TargetRow;
use crate::error::BenchError;

/// One sampler's run in `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct SamplerSummary {
    pub sampler: String,
    /// Initial learning rate (the dense run's: the sweep's pick).
    pub lr: f64,
    /// Training seconds the run's schedule was spread over, and at most trained.
    pub budget_s: f64,
    pub trained_s: f64,
    pub steps: usize,
    pub stopped: Stop,
    /// Per target (`targets_db`): training seconds to first reach it, interpolated
    /// between evaluations (`None`: never reached).
    pub seconds_to_target: Vec<Option<f64>>,
    pub steps_to_target: Vec<Option<f64>>,
    pub best_psnr: f64,
    pub final_psnr: f64,
    pub cost: StepCost,
    /// Before the first step (margins, grids, field): not on the time axis.
    pub setup_s: f64,
    /// Spent evaluating: not on the time axis.
    pub eval_s: f64,
}

/// One learning rate of the dense sweep: its PSNR after the sweep's seconds.
#[derive(Clone, Debug, Serialize)]
pub struct SweepRow {
    pub lr: f64,
    pub seconds: f64,
    pub steps: usize,
    pub psnr: f64,
    pub chosen: bool,
}

/// `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub targets_db: Vec<f64>,
    pub eval_split: String,
    pub eval_frames: Vec<usize>,
    pub accelerated: SamplerSummary,
    pub dense: SamplerSummary,
    /// Per target: dense seconds over accelerated seconds to reach it (`None` where the
    /// accelerated run never did).
    pub speedup_at_target: Vec<Option<f64>>,
    /// Per target: the dense run never reached it, so its speed-up is its training
    /// seconds over the accelerated run's time: a lower bound.
    pub is_lower_bound: Vec<bool>,
    /// The highest target the accelerated run reached, with the dense run's time to it
    /// measured or, where dense trained its whole budget without reaching it, bounded.
    pub highest_common_target_db: Option<f64>,
    /// The speed-up there (a lower bound with `highest_common_is_lower_bound`).
    pub speedup_at_highest_common_target: Option<f64>,
    pub highest_common_is_lower_bound: bool,
    /// Per target: the speed-up as (dense / accelerated steps) x (dense / accelerated
    /// seconds a step).
    pub targets: Vec<TargetRow>,
    /// The dense learning-rate sweep (empty when one rate was given).
    pub dense_lr_sweep: Vec<SweepRow>,
    /// Seconds of each sweep run.
    pub dense_sweep_s: f64,
    pub lpips_note: Option<String>,
    pub points: Vec<Point>,
}

/// Writes every file of the report into `out`.
pub fn write_outputs(out: &Path, summary: &Summary) -> Result<(), BenchError> {
    let write = |name: &str, bytes: &[u8]| {
        let file = out.join(name);
        talkin_data::atomic::write_atomic(&file, bytes)
            .map_err(|source| BenchError::Io { file, source })
    };
    let table = csv(&summary.points).map_err(|e| BenchError::Io {
        file: out.join("speed_vs_error.csv"),
        source: std::io::Error::other(e),
    })?;
    write("speed_vs_error.csv", &table)?;
    let json = serde_json::to_string_pretty(summary).map_err(|e| BenchError::Io {
        file: out.join("summary.json"),
        source: std::io::Error::other(e),
    })?;
    write("summary.json", json.as_bytes())?;
    write("report.md", format_summary(summary).as_bytes())?;
    let curves: Vec<Curve> = [("accelerated", [230, 90, 30]), ("dense", [40, 90, 200])]
        .into_iter()
        .map(|(run, colour)| {
            let pts = summary
                .points
                .iter()
                .filter(|p| p.run == run)
                .map(|p| (p.seconds, p.psnr))
                .collect();
            (run, colour, pts)
        })
        .collect();
    let png = plot_psnr_vs_seconds(&curves, &summary.targets_db).map_err(|e| BenchError::Io {
        file: out.join("speed_vs_error.png"),
        source: std::io::Error::other(e),
    })?;
    let mut bytes = Vec::new();
    png.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| BenchError::Io {
        file: out.join("speed_vs_error.png"),
        source: std::io::Error::other(e),
    })?;
    write("speed_vs_error.png", &bytes)
}

/// Every evaluation, one row each, as CSV.
pub fn csv(points: &[Point]) -> Result<Vec<u8>, csv::Error> {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record([
        "run",
        "sampler",
        "lr",
        "seconds",
        "steps",
        "psnr",
        "ssim",
        "lpips",
        "psnr_face",
        "psnr_hands",
        "samples_per_ray",
        "eval_s",
    ])?;
    for p in points {
        w.write_record([
            p.run.to_string(),
            p.sampler.to_string(),
            format!("{:e}", p.lr),
            format!("{:.2}", p.seconds),
            p.steps.to_string(),
            format!("{:.4}", p.psnr),
            format!("{:.5}", p.ssim),
            opt(p.lpips),
            opt(p.psnr_face),
            opt(p.psnr_hands),
            format!("{:.2}", p.samples_per_ray),
            format!("{:.2}", p.eval_s),
        ])?;
    }
    w.into_inner().map_err(|e| e.into_error().into())
}

/// The report's tables in Markdown: time to each target, what a step costs, the dense
/// sweep, and every evaluation of the two runs.
pub fn format_summary(s: &Summary) -> String {
    let opt =
        |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    let (a, d) = (&s.accelerated, &s.dense);
    let mut t = format!(
        "Time to quality on {} ({} frames), each run rendered by its own sampler.\n\n\
         | target dB | accelerated s | accelerated steps | dense s | dense steps | speed-up | \
         = steps ratio | x step cost ratio |\n|---|---|---|---|---|---|---|---|\n",
        s.eval_split,
        s.eval_frames.len()
    );
    for (k, r) in s.targets.iter().enumerate() {
        let bound = if r.is_lower_bound { ">= " } else { "" };
        t.push_str(&format!(
            "| {:.1} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.target_db,
            opt(a.seconds_to_target[k], 1),
            opt(a.steps_to_target[k], 0),
            if r.is_lower_bound {
                format!("> {:.0}", d.trained_s)
            } else {
                opt(d.seconds_to_target[k], 1)
            },
            if r.is_lower_bound {
                format!("> {}", d.steps)
            } else {
                opt(d.steps_to_target[k], 0)
            },
            r.speedup
                .map_or("-".into(), |v| format!("**{bound}{v:.2}x**")),
            r.steps_ratio
                .map_or("-".into(), |v| format!("{bound}{v:.2}")),
            opt(r.step_cost_ratio, 2),
        ));
    }
    t.push_str(&format!(
        "\nHighest common target: {}; speed-up there: {}{}.\n\n",
        s.highest_common_target_db
            .map_or("none".into(), |v| format!("{v:.1} dB")),
        if s.highest_common_is_lower_bound {
            ">= "
        } else {
            ""
        },
        opt(s.speedup_at_highest_common_target, 2) + "x",
    ));
    t.push_str(
        "| run | lr | budget s | trained s | steps | stopped | best dB | median step ms | \
         mean step ms | samples/ray | bones/sample | sampling share |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in [a, d] {
        t.push_str(&format!(
            "| {} | {:e} | {:.0} | {:.0} | {} | {:?} | {:.2} | {:.1} | {:.1} | {:.1} | {:.2} | \
             {:.1}% |\n",
            r.sampler,
            r.lr,
            r.budget_s,
            r.trained_s,
            r.steps,
            r.stopped,
            r.best_psnr,
            1e3 * r.cost.median_step_s,
            1e3 * r.cost.mean_step_s,
            r.cost.samples_per_ray,
            r.cost.bones_per_sample,
            100.0 * r.cost.sampling_share,
        ));
    }
    if a.cost.median_step_s > 0.0 {
        t.push_str(&format!(
            "\nMedian step: dense / accelerated = {:.2}x.\n",
            d.cost.median_step_s / a.cost.median_step_s
        ));
    }
    if !s.dense_lr_sweep.is_empty() {
        t.push_str(&format!(
            "\nDense learning-rate sweep ({:.1} s each, schedule of the full dense budget, \
             scored by the dense renderer):\n\n| lr | steps | PSNR | chosen |\n|---|---|---|---|\n",
            s.dense_sweep_s
        ));
        for r in &s.dense_lr_sweep {
            t.push_str(&format!(
                "| {:e} | {} | {:.2} | {} |\n",
                r.lr,
                r.steps,
                r.psnr,
                if r.chosen { "yes" } else { "" }
            ));
        }
    }
    t.push_str(
        "\n| run | seconds | steps | PSNR | SSIM | LPIPS* | samples/ray |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for p in s
        .points
        .iter()
        .filter(|p| p.run == "accelerated" || p.run == "dense")
    {
        t.push_str(&format!(
            "| {} | {:.1} | {} | {:.2} | {:.4} | {} | {:.1} |\n",
            p.run,
            p.seconds,
            p.steps,
            p.psnr,
            p.ssim,
            opt(p.lpips, 1),
            p.samples_per_ray
        ));
    }
    if let Some(note) = &s.lpips_note {
        t.push_str(&format!("\nLPIPS: {note}\n"));
    }
    t
}
