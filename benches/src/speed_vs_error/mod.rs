//! `talkin bench speed-vs-error`: the accelerated and the dense sampler trained on the
//! same data for the same wall-clock budgets in one run, each evaluated on held-out
//! frames at every budget mark, and how much sooner the accelerated run reaches the
//! dense run's best PSNR.
//!
//! Each sampler trains once with its schedule spread over the largest budget; the
//! evaluation at a mark pauses the training clock (it is not training time). The marks
//! are the budgets plus a quarter and a half of the first one, and 0 (the untrained
//! field), so the time to a PSNR is interpolated on a fine enough curve.
//!
//! Both runs are rendered for evaluation by the same renderer: the accelerated sampler
//! with the subject's capsule intervals and its *initial* (capsule-marked) grid for the
//! dense run, whose grid is never updated. Only error is compared here, and this renderer
//! can only remove what the dense field put outside every grown capsule (floaters), so it
//! never hurts the baseline; rendering the dense run densely cost ~2 min per frame on 2
//! cores.

mod plot;

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use talkin_grids::SamplerKind;

pub use plot::{Curve, plot_psnr_vs_seconds};

use talkin_data::dataset::{Dataset, Split};
use talkin_render::avatar::Avatar;
use talkin_render::eval::{EvalOptions, evaluate};
use talkin_train::{Budget, TrainOptions, Trainer};

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct SpeedVsErrorOptions {
    /// Wall-clock training budgets (seconds), ascending.
    pub budgets: Vec<f64>,
    /// Evaluation frames from `test_same` (evenly spaced; 0: all).
    pub eval_frames: usize,
    /// The training recipe both samplers share (budget and sampler are overridden).
    pub train: TrainOptions,
    /// LPIPS weights for the evaluation (`None`: LPIPS is not reported).
    pub lpips_dir: Option<PathBuf>,
}

/// One evaluation of one sampler's run.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub sampler: String,
    /// Training seconds at the evaluation.
    pub seconds: f64,
    pub steps: usize,
    pub psnr: f64,
    pub ssim: f64,
    pub lpips: Option<f64>,
    pub psnr_face: Option<f64>,
    pub psnr_hands: Option<f64>,
    /// Mean field samples per training ray so far.
    pub samples_per_ray: f64,
}

/// `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub budgets_s: Vec<f64>,
    pub eval_split: String,
    pub eval_frames: Vec<usize>,
    pub dense_best_psnr: f64,
    /// Training seconds at which the dense run first measured its best PSNR.
    pub dense_seconds_to_best: f64,
    /// Training seconds the accelerated run needed to reach `dense_best_psnr`
    /// (interpolated between marks); `None` if it never did.
    pub accelerated_seconds_to_dense_best: Option<f64>,
    /// `dense_seconds_to_best / accelerated_seconds_to_dense_best`.
    pub speedup_to_dense_final_psnr: Option<f64>,
    pub accelerated_final_psnr: f64,
    pub dense_final_psnr: f64,
    pub accelerated_steps_per_s: f64,
    pub dense_steps_per_s: f64,
    pub accelerated_samples_per_ray: f64,
    pub dense_samples_per_ray: f64,
    /// Setup before the first step (margins, grids, field), not on the time axis.
    pub accelerated_setup_s: f64,
    pub dense_setup_s: f64,
    pub lpips_note: Option<String>,
    /// Why there is no speedup, when there is none.
    pub note: Option<String>,
    pub points: Vec<Point>,
}

pub use crate::error::BenchError as SpeedVsErrorError;

/// The evaluation marks for `budgets`: 0, a quarter and a half of the first budget, and
/// every budget.
pub fn eval_marks(budgets: &[f64]) -> Vec<f64> {
    let mut marks = vec![0.0];
    if let Some(&first) = budgets.first() {
        marks.push(first / 4.0);
        marks.push(first / 2.0);
    }
    marks.extend_from_slice(budgets);
    marks.sort_by(f64::total_cmp);
    marks.dedup();
    marks
}

/// `count` frames of `split` evenly spaced over the split (all when `count` is 0 or
/// larger than the split).
pub fn spread_frames(dataset: &Dataset, split: Split, count: usize) -> Vec<usize> {
    crate::shared::thin(&dataset.split_indices(split), count)
}

/// Runs the benchmark, writing `out/speed_vs_error.csv`, `out/speed_vs_error.png`,
/// `out/summary.json` and each sampler's run under `out/runs/`. `progress` hears what
/// is happening.
pub fn speed_vs_error(
    dataset: &Dataset,
    out: &Path,
    opts: &SpeedVsErrorOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Summary, SpeedVsErrorError> {
    let bad = |field, problem: &str| SpeedVsErrorError::BadOption {
        field,
        problem: problem.to_string(),
    };
    if opts.budgets.is_empty()
        || opts.budgets.iter().any(|b| !(b.is_finite() && *b > 0.0))
        || opts.budgets.windows(2).any(|w| w[0] >= w[1])
    {
        return Err(bad(
            "budgets",
            "expected ascending positive seconds, e.g. 30,60,120,240",
        ));
    }
    let eval_frames = spread_frames(dataset, Split::TestSame, opts.eval_frames);
    if eval_frames.is_empty() {
        return Err(bad(
            "data",
            "the dataset has no test_same frame to evaluate on",
        ));
    }
    std::fs::create_dir_all(out).map_err(|source| SpeedVsErrorError::Io {
        file: out.to_path_buf(),
        source,
    })?;
    let marks = eval_marks(&opts.budgets);
    let mut points = Vec::new();
    let mut rates = Vec::new();
    let mut lpips_note = None;
    for sampler in [SamplerKind::Accelerated, SamplerKind::Dense] {
        let run = train_and_score(dataset, out, opts, sampler, &marks, &eval_frames, progress)?;
        points.extend(run.points);
        rates.push(run.rate);
        lpips_note = run.lpips_note.or(lpips_note);
    }
    let curve =
        |name: &str| -> Vec<&Point> { points.iter().filter(|p| p.sampler == name).collect() };
    let (acc, dense) = (curve("accelerated"), curve("dense"));
    let (best, acc_time, note) = compare(&acc, &dense);
    let summary = Summary {
        budgets_s: opts.budgets.clone(),
        eval_split: Split::TestSame.name().into(),
        eval_frames: eval_frames.clone(),
        dense_best_psnr: best.psnr,
        dense_seconds_to_best: best.seconds,
        accelerated_seconds_to_dense_best: acc_time,
        speedup_to_dense_final_psnr: acc_time.map(|t| best.seconds / t.max(1e-9)),
        note,
        accelerated_final_psnr: acc.last().map_or(f64::NAN, |p| p.psnr),
        dense_final_psnr: dense.last().map_or(f64::NAN, |p| p.psnr),
        accelerated_steps_per_s: rates[0].0,
        dense_steps_per_s: rates[1].0,
        accelerated_samples_per_ray: rates[0].1,
        dense_samples_per_ray: rates[1].1,
        accelerated_setup_s: rates[0].2,
        dense_setup_s: rates[1].2,
        lpips_note,
        points,
    };
    write_outputs(out, &summary)?;
    Ok(summary)
}

/// One sampler's run: its scored points, (steps/s, samples per ray, setup seconds) and
/// the evaluation's LPIPS note, if any.
struct SamplerRun {
    points: Vec<Point>,
    rate: (f64, f64, f64),
    lpips_note: Option<String>,
}

/// Trains `sampler` for the largest budget, scoring test_same at every mark.
fn train_and_score(
    dataset: &Dataset,
    out: &Path,
    opts: &SpeedVsErrorOptions,
    sampler: SamplerKind,
    marks: &[f64],
    eval_frames: &[usize],
    progress: &mut dyn FnMut(&str),
) -> Result<SamplerRun, SpeedVsErrorError> {
    let max_budget = *opts.budgets.last().expect("checked non-empty");
    let mut points = Vec::new();
    let mut lpips_note = None;
    let train_opts = TrainOptions {
        sampler,
        budget: Budget::Seconds(max_budget),
        // Checkpoints only at the end: writing them is not training.
        checkpoint_every_s: f64::INFINITY,
        ..opts.train.clone()
    };
    let run = out.join("runs").join(sampler.name());
    let setup = Instant::now();
    let mut trainer = Trainer::new(dataset, &run, &train_opts)?;
    let setup_s = setup.elapsed().as_secs_f64();
    let (mut rays, mut samples) = (0usize, 0usize);
    for &mark in marks {
        while trainer.elapsed_seconds() < mark && !trainer.done() {
            let log = trainer.step()?;
            rays += log.rays;
            samples += log.samples;
        }
        progress(&format!(
            "{}: {:.0} s trained ({} steps), evaluating {} frames",
            sampler.name(),
            trainer.elapsed_seconds(),
            trainer.steps_taken(),
            eval_frames.len()
        ));
        let mut avatar = Avatar::from_trainer(&trainer);
        avatar.sampler = SamplerKind::Accelerated;
        let report = evaluate(
            &avatar,
            dataset,
            eval_frames,
            &EvalOptions {
                renders_dir: None,
                lpips_dir: opts.lpips_dir.clone(),
                smooth: false,
            },
        )?;
        progress(&format!(
            "{}: PSNR {:.2} dB at {:.0} s",
            sampler.name(),
            report.psnr,
            trainer.elapsed_seconds()
        ));
        if report.lpips_note.is_some() {
            lpips_note = report.lpips_note.clone();
        }
        points.push(Point {
            sampler: sampler.name().into(),
            seconds: trainer.elapsed_seconds(),
            steps: trainer.steps_taken(),
            psnr: report.psnr,
            ssim: report.ssim,
            lpips: report.lpips,
            psnr_face: report.psnr_face,
            psnr_hands: report.psnr_hands,
            samples_per_ray: samples as f64 / rays.max(1) as f64,
        });
    }
    trainer.save()?;
    Ok(SamplerRun {
        points,
        rate: (
            trainer.steps_taken() as f64 / trainer.elapsed_seconds().max(1e-9),
            samples as f64 / rays.max(1) as f64,
            setup_s,
        ),
        lpips_note,
    })
}

/// The dense run's best point after the start, the accelerated run's time to reach its
/// PSNR, and why there is no speedup when there is none. Both runs start from the same
/// untrained field, so the start (0 s) is nobody's achievement: a dense run that never
/// beats it has no time to its best, and the accelerated run must climb to the target.
pub fn compare<'p>(
    acc: &[&'p Point],
    dense: &[&'p Point],
) -> (&'p Point, Option<f64>, Option<String>) {
    let start = dense.first().map_or(f64::NEG_INFINITY, |p| p.psnr);
    let best = dense
        .iter()
        .copied()
        .filter(|p| p.seconds > 0.0)
        .fold(None::<&Point>, |b, p| match b {
            Some(b) if b.psnr >= p.psnr => Some(b),
            _ => Some(p),
        })
        .or_else(|| dense.first().copied())
        .expect("the dense curve has points");
    if best.psnr <= start {
        let note = format!(
            "the dense run never improved on the untrained field's {start:.2} dB within the \
             budget, so it has no time to its best PSNR"
        );
        return (best, None, Some(note));
    }
    match time_to_reach(acc, best.psnr) {
        Some(t) => (best, Some(t), None),
        None => (
            best,
            None,
            Some(format!(
                "the accelerated run never reached the dense best {:.2} dB",
                best.psnr
            )),
        ),
    }
}

/// The first time (seconds) the curve climbs to `psnr`, linearly interpolated between
/// consecutive points; `None` if it never does (the starting point does not count).
pub fn time_to_reach(curve: &[&Point], psnr: f64) -> Option<f64> {
    curve.windows(2).find_map(|w| {
        let (a, b) = (w[0], w[1]);
        (b.psnr >= psnr).then(|| {
            let f = ((psnr - a.psnr) / (b.psnr - a.psnr)).clamp(0.0, 1.0);
            a.seconds + f * (b.seconds - a.seconds)
        })
    })
}

fn write_outputs(out: &Path, summary: &Summary) -> Result<(), SpeedVsErrorError> {
    let write = |name: &str, bytes: &[u8]| {
        let file = out.join(name);
        talkin_data::atomic::write_atomic(&file, bytes)
            .map_err(|source| SpeedVsErrorError::Io { file, source })
    };
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
    let mut csv = String::from(
        "sampler,seconds,steps,psnr,ssim,lpips,psnr_face,psnr_hands,samples_per_ray\n",
    );
    for p in &summary.points {
        csv.push_str(&format!(
            "{},{:.2},{},{:.4},{:.5},{},{},{},{:.2}\n",
            p.sampler,
            p.seconds,
            p.steps,
            p.psnr,
            p.ssim,
            opt(p.lpips),
            opt(p.psnr_face),
            opt(p.psnr_hands),
            p.samples_per_ray
        ));
    }
    write("speed_vs_error.csv", csv.as_bytes())?;
    write(
        "summary.json",
        serde_json::to_string_pretty(summary)
            .expect("plain data serialises")
            .as_bytes(),
    )?;
    let curves: Vec<Curve> = [("accelerated", [230, 90, 30]), ("dense", [40, 90, 200])]
        .into_iter()
        .map(|(name, colour)| {
            let pts = summary
                .points
                .iter()
                .filter(|p| p.sampler == name)
                .map(|p| (p.seconds, p.psnr))
                .collect();
            (name, colour, pts)
        })
        .collect();
    let png = plot_psnr_vs_seconds(&curves, summary.dense_best_psnr);
    let mut bytes = Vec::new();
    png.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .expect("encoding a PNG in memory");
    write("speed_vs_error.png", &bytes)
}

/// A table of the summary for the terminal and the README.
pub fn format_summary(s: &Summary) -> String {
    let mut t = String::from(
        "| sampler | seconds | steps | PSNR | SSIM | LPIPS* | samples/ray |\n|---|---|---|---|---|---|---|\n",
    );
    for p in &s.points {
        t.push_str(&format!(
            "| {} | {:.0} | {} | {:.2} | {:.4} | {} | {:.1} |\n",
            p.sampler,
            p.seconds,
            p.steps,
            p.psnr,
            p.ssim,
            p.lpips.map_or("-".into(), |v| format!("{v:.1}")),
            p.samples_per_ray
        ));
    }
    t.push_str(&format!(
        "\ndense best PSNR {:.2} dB at {:.0} s; accelerated reaches it at {}; \
         speedup_to_dense_final_psnr = {}\n\
         steps/s: accelerated {:.2}, dense {:.2}; samples/ray: accelerated {:.1}, dense {:.1}\n",
        s.dense_best_psnr,
        s.dense_seconds_to_best,
        s.accelerated_seconds_to_dense_best
            .map_or("never".into(), |t| format!("{t:.1} s")),
        s.speedup_to_dense_final_psnr.map_or(
            format!("none: {}", s.note.clone().unwrap_or_default()),
            |v| { format!("{v:.2}x") }
        ),
        s.accelerated_steps_per_s,
        s.dense_steps_per_s,
        s.accelerated_samples_per_ray,
        s.dense_samples_per_ray,
    ));
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(seconds: f64, psnr: f64) -> Point {
        Point {
            sampler: String::new(),
            seconds,
            steps: 0,
            psnr,
            ssim: 0.0,
            lpips: None,
            psnr_face: None,
            psnr_hands: None,
            samples_per_ray: 0.0,
        }
    }

    #[test]
    fn speedup_is_interpolated_and_undefined_when_dense_never_improves() {
        let acc = [p(0.0, 10.0), p(10.0, 14.0), p(20.0, 18.0)];
        let dense = [p(0.0, 10.0), p(30.0, 12.0), p(60.0, 16.0)];
        let (a, d): (Vec<&Point>, Vec<&Point>) = (acc.iter().collect(), dense.iter().collect());
        let (best, t, note) = compare(&a, &d);
        assert_eq!(best.seconds, 60.0);
        // 16 dB lies halfway between 14 (10 s) and 18 (20 s).
        assert!((t.unwrap() - 15.0).abs() < 1e-9 && note.is_none());
        // A dense run that only gets worse has no time to its best.
        let flat = [p(0.0, 10.0), p(30.0, 9.0)];
        let f: Vec<&Point> = flat.iter().collect();
        let (_, t, note) = compare(&a, &f);
        assert!(t.is_none() && note.unwrap().contains("never improved"));
        // An accelerated run that never gets there.
        let slow = [p(0.0, 10.0), p(60.0, 11.0)];
        let s: Vec<&Point> = slow.iter().collect();
        let (_, t, note) = compare(&s, &d);
        assert!(t.is_none() && note.unwrap().contains("never reached"));
        assert_eq!(eval_marks(&[30.0, 60.0]), vec![0.0, 7.5, 15.0, 30.0, 60.0]);
    }
}
