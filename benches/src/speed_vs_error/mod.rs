//! `talkin bench speed-vs-error`: time to quality. For target PSNRs on test_same, the
//! training seconds and steps the accelerated and the dense sampler each need to first
//! reach each target, and the speed-up at each, split into the steps each needs and what
//! a step costs ([`targets`]).
//!
//! - **The same recipe.** Both train the same field with the same loss, batch and seed;
//!   each run's schedule (learning-rate decay, the paper's phases) is spread over its own
//!   budget.
//! - **Dense at its best.** The dense sampler is HumanNeRF's: 128 stratified samples in
//!   the posed joints' box +- 0.3 m. Its learning rate is its own: a short sweep (the
//!   first seconds of a dense run at each rate, on the full dense budget's schedule) picks
//!   the rate with the highest PSNR, and the dense run proper starts afresh at it.
//! - **Each run rendered by its own sampler.** Evaluation pauses the training clock. A
//!   dense render costs tens of seconds a 144x192 frame on 2 cores, so a few fixed frames
//!   are scored, often but never for longer than the training since the last evaluation
//!   ([`run::eval_marks`]).
//! - **Stopping.** The accelerated run trains until it reaches the highest target or its
//!   budget ends; the dense run until it reaches the highest target the accelerated run
//!   reached, or its budget ends. A target the dense run never reaches gives a lower bound
//!   (its training seconds over the accelerated run's time), marked as one.

pub(crate) mod plot;
mod report;
mod run;
pub mod targets;

use std::path::{Path, PathBuf};

use talkin_data::dataset::{Dataset, Split};
use talkin_grids::SamplerKind;
use talkin_render::eval::EvalOptions;
use talkin_train::TrainOptions;

pub use plot::{Curve, plot_psnr_vs_seconds};
pub use report::{SamplerSummary, Summary, SweepRow, csv, format_summary, write_outputs};
pub use run::{EVAL_GAP_SHARE, MIN_EVAL_GAP_S, Point, StepCost, Stop, eval_marks};
use run::{RunContext, RunResult, RunSpec, train_and_score};
use targets::{RunTotals, compare_at_targets, first_crossing, highest_common, highest_reached};

pub use crate::error::BenchError as SpeedVsErrorError;

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct SpeedVsErrorOptions {
    /// Target PSNRs on test_same (dB), ascending.
    pub targets_db: Vec<f64>,
    /// Training seconds of the accelerated run.
    pub accelerated_s: f64,
    /// Training seconds of the dense run (at most).
    pub dense_s: f64,
    /// Evaluation frames from `test_same` (evenly spaced; 0: all).
    pub eval_frames: usize,
    /// Training seconds between evaluations (`None`: gaps growing with the time trained,
    /// see [`eval_marks`]).
    pub eval_every_s: Option<f64>,
    /// The dense run's candidate learning rates; with more than one, each trains for
    /// `dense_sweep_s` and the best PSNR picks the rate.
    pub dense_lrs: Vec<f64>,
    /// Training seconds of each sweep run.
    pub dense_sweep_s: f64,
    /// The recipe both samplers share (sampler, budget and learning rate are set per run;
    /// the accelerated run keeps the recipe's rate).
    pub train: TrainOptions,
    /// LPIPS weights for the evaluation (`None`: LPIPS is not reported).
    pub lpips_dir: Option<PathBuf>,
}

/// `count` frames of `split` evenly spaced over the split (all when `count` is 0 or
/// larger than the split).
pub fn spread_frames(dataset: &Dataset, split: Split, count: usize) -> Vec<usize> {
    crate::shared::thin(&dataset.split_indices(split), count)
}

/// Runs the benchmark, writing `out/summary.json`, `out/report.md`,
/// `out/speed_vs_error.csv`, `out/speed_vs_error.png` and every run under `out/runs/`.
/// `progress` hears what is happening.
pub fn speed_vs_error(
    dataset: &Dataset,
    out: &Path,
    opts: &SpeedVsErrorOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Summary, SpeedVsErrorError> {
    check(opts)?;
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
    let ctx = RunContext {
        dataset,
        out,
        train: &opts.train,
        eval_frames: &eval_frames,
        eval: EvalOptions {
            renders_dir: None,
            lpips_dir: opts.lpips_dir.clone(),
            smooth: false,
            anchors: false,
        },
    };
    let highest_target = opts.targets_db.iter().copied().fold(f64::MIN, f64::max);

    let acc_marks = eval_marks(opts.accelerated_s, opts.eval_every_s);
    let acc = train_and_score(
        &ctx,
        &RunSpec {
            name: "accelerated".into(),
            sampler: SamplerKind::Accelerated,
            lr: opts.train.initial_lr(),
            budget_s: opts.accelerated_s,
            marks: &acc_marks,
            stop_at_psnr: Some(highest_target),
            save: true,
        },
        progress,
    )?;
    let reached = highest_reached(&opts.targets_db, &acc.curve());
    progress(&match reached {
        Some(t) => format!("accelerated reached {t:.1} dB; dense trains until it does"),
        None => "accelerated reached no target; dense trains for its whole budget".into(),
    });

    let (dense_lr, sweep, mut points) = sweep_dense_lr(&ctx, opts, progress)?;
    let dense_marks = eval_marks(opts.dense_s, opts.eval_every_s);
    let dense = train_and_score(
        &ctx,
        &RunSpec {
            name: "dense".into(),
            sampler: SamplerKind::Dense,
            lr: dense_lr,
            budget_s: opts.dense_s,
            marks: &dense_marks,
            stop_at_psnr: reached,
            save: true,
        },
        progress,
    )?;

    let rows = compare_at_targets(
        &opts.targets_db,
        &acc.curve(),
        &dense.curve(),
        RunTotals {
            seconds: dense.trained_s,
            steps: dense.steps as f64,
        },
    );
    let common = highest_common(&rows);
    let summary = Summary {
        targets_db: opts.targets_db.clone(),
        eval_split: Split::TestSame.name().into(),
        eval_frames: eval_frames.clone(),
        accelerated: sampler_summary(
            &acc,
            SamplerKind::Accelerated,
            opts,
            opts.train.initial_lr(),
        ),
        dense: sampler_summary(&dense, SamplerKind::Dense, opts, dense_lr),
        speedup_at_target: rows.iter().map(|r| r.speedup).collect(),
        is_lower_bound: rows.iter().map(|r| r.is_lower_bound).collect(),
        highest_common_target_db: common.map(|r| r.target_db),
        speedup_at_highest_common_target: common.and_then(|r| r.speedup),
        highest_common_is_lower_bound: common.is_some_and(|r| r.is_lower_bound),
        targets: rows.clone(),
        dense_lr_sweep: sweep,
        dense_sweep_s: opts.dense_sweep_s,
        lpips_note: acc.lpips_note.clone().or(dense.lpips_note.clone()),
        points: {
            let mut all = acc.points.clone();
            all.append(&mut points);
            all.extend(dense.points.iter().cloned());
            all
        },
    };
    write_outputs(out, &summary)?;
    Ok(summary)
}

/// The dense learning rate: the only one given, or the sweep's best (its rows and points
/// are returned with it).
fn sweep_dense_lr(
    ctx: &RunContext,
    opts: &SpeedVsErrorOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<(f64, Vec<SweepRow>, Vec<Point>), SpeedVsErrorError> {
    if let [lr] = opts.dense_lrs[..] {
        return Ok((lr, Vec::new(), Vec::new()));
    }
    let sweep_s = opts.dense_sweep_s.min(opts.dense_s);
    let mut rows: Vec<SweepRow> = Vec::new();
    let mut points = Vec::new();
    for &lr in &opts.dense_lrs {
        let run = train_and_score(
            ctx,
            &RunSpec {
                name: format!("dense-sweep-lr-{lr:e}"),
                sampler: SamplerKind::Dense,
                lr,
                budget_s: opts.dense_s,
                marks: &[sweep_s],
                stop_at_psnr: None,
                save: false,
            },
            progress,
        )?;
        let last = run.points.last().expect("a run has its last mark");
        rows.push(SweepRow {
            lr,
            seconds: last.seconds,
            steps: last.steps,
            psnr: last.psnr,
            chosen: false,
        });
        points.extend(run.points);
    }
    // The first of the best (a NaN PSNR never wins).
    let best = (0..rows.len())
        .filter(|&k| rows[k].psnr.is_finite())
        .fold(None::<usize>, |b, k| match b {
            Some(b) if rows[b].psnr >= rows[k].psnr => Some(b),
            _ => Some(k),
        })
        .unwrap_or(0);
    rows[best].chosen = true;
    progress(&format!(
        "dense learning rate: {:e} ({:.2} dB after {sweep_s:.0} s)",
        rows[best].lr, rows[best].psnr
    ));
    Ok((rows[best].lr, rows, points))
}

fn sampler_summary(
    run: &RunResult,
    sampler: SamplerKind,
    opts: &SpeedVsErrorOptions,
    lr: f64,
) -> SamplerSummary {
    let curve = run.curve();
    let crossings: Vec<_> = opts
        .targets_db
        .iter()
        .map(|&t| first_crossing(&curve, t))
        .collect();
    SamplerSummary {
        sampler: sampler.name().into(),
        lr,
        budget_s: match sampler {
            SamplerKind::Accelerated => opts.accelerated_s,
            SamplerKind::Dense => opts.dense_s,
        },
        trained_s: run.trained_s,
        steps: run.steps,
        stopped: run.stop,
        seconds_to_target: crossings.iter().map(|c| c.map(|c| c.seconds)).collect(),
        steps_to_target: crossings.iter().map(|c| c.map(|c| c.steps)).collect(),
        best_psnr: curve.iter().map(|p| p.psnr).fold(f64::NAN, f64::max),
        final_psnr: curve.last().map_or(f64::NAN, |p| p.psnr),
        cost: run.cost.clone(),
        setup_s: run.setup_s,
        eval_s: run.eval_s,
    }
}

fn bad(field: &'static str, problem: &str) -> SpeedVsErrorError {
    SpeedVsErrorError::BadOption {
        field,
        problem: problem.to_string(),
    }
}

/// Checks every option; errors name the option.
fn check(opts: &SpeedVsErrorOptions) -> Result<(), SpeedVsErrorError> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if opts.targets_db.is_empty()
        || opts.targets_db.iter().any(|t| !t.is_finite())
        || opts.targets_db.windows(2).any(|w| w[0] >= w[1])
    {
        return Err(bad(
            "targets",
            "expected ascending PSNRs in dB, e.g. 18,20,22,24,26",
        ));
    }
    for (field, v) in [
        ("accelerated-minutes", opts.accelerated_s),
        ("dense-minutes", opts.dense_s),
        ("dense-sweep-minutes", opts.dense_sweep_s),
    ] {
        if !positive(v) {
            return Err(bad(field, "expected a positive number"));
        }
    }
    if opts.eval_every_s.is_some_and(|s| !positive(s)) {
        return Err(bad("eval-every-s", "expected a positive number of seconds"));
    }
    if opts.dense_lrs.is_empty() || opts.dense_lrs.iter().any(|&lr| !positive(lr)) {
        return Err(bad(
            "dense-lrs",
            "expected one or more positive learning rates, e.g. 5e-3,1e-2,2e-2",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> SpeedVsErrorOptions {
        SpeedVsErrorOptions {
            targets_db: vec![18.0, 20.0],
            accelerated_s: 60.0,
            dense_s: 120.0,
            eval_frames: 3,
            eval_every_s: None,
            dense_lrs: vec![1e-2],
            dense_sweep_s: 30.0,
            train: TrainOptions::default(),
            lpips_dir: None,
        }
    }

    #[test]
    fn bad_options_name_their_flag() {
        let field = |o: SpeedVsErrorOptions| match check(&o) {
            Err(SpeedVsErrorError::BadOption { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        assert!(check(&opts()).is_ok());
        for targets in [vec![], vec![20.0, 18.0], vec![f64::NAN]] {
            assert_eq!(
                field(SpeedVsErrorOptions {
                    targets_db: targets,
                    ..opts()
                }),
                "targets"
            );
        }
        let o = SpeedVsErrorOptions {
            dense_s: 0.0,
            ..opts()
        };
        assert_eq!(field(o), "dense-minutes");
        let o = SpeedVsErrorOptions {
            eval_every_s: Some(-1.0),
            ..opts()
        };
        assert_eq!(field(o), "eval-every-s");
        for lrs in [vec![], vec![1e-2, 0.0]] {
            assert_eq!(
                field(SpeedVsErrorOptions {
                    dense_lrs: lrs,
                    ..opts()
                }),
                "dense-lrs"
            );
        }
    }

    /// `summary.json` keeps the keys readers of the report rely on, and no longer
    /// carries the old single ratio.
    #[test]
    fn summary_json_has_the_report_keys() {
        let cost = StepCost::default();
        let side = |sampler: &str| SamplerSummary {
            sampler: sampler.into(),
            lr: 1e-2,
            budget_s: 60.0,
            trained_s: 60.0,
            steps: 10,
            stopped: Stop::Budget,
            seconds_to_target: vec![Some(5.0), None],
            steps_to_target: vec![Some(50.0), None],
            best_psnr: 19.0,
            final_psnr: 19.0,
            cost: cost.clone(),
            setup_s: 1.0,
            eval_s: 1.0,
        };
        let summary = Summary {
            targets_db: vec![18.0, 20.0],
            eval_split: "test_same".into(),
            eval_frames: vec![1],
            accelerated: side("accelerated"),
            dense: side("dense"),
            speedup_at_target: vec![Some(1.0), None],
            is_lower_bound: vec![false, false],
            highest_common_target_db: Some(18.0),
            speedup_at_highest_common_target: Some(1.0),
            highest_common_is_lower_bound: false,
            targets: Vec::new(),
            dense_lr_sweep: Vec::new(),
            dense_sweep_s: 30.0,
            lpips_note: None,
            points: Vec::new(),
        };
        let json = serde_json::to_value(&summary).unwrap();
        for key in [
            "targets_db",
            "speedup_at_target",
            "highest_common_target_db",
            "speedup_at_highest_common_target",
            "highest_common_is_lower_bound",
            "is_lower_bound",
            "dense_lr_sweep",
        ] {
            assert!(json.get(key).is_some(), "{key} missing: {json}");
        }
        assert!(json.get("speedup_to_dense_final_psnr").is_none());
        for sampler in ["accelerated", "dense"] {
            for key in ["seconds_to_target", "steps_to_target", "lr", "cost"] {
                assert!(json[sampler].get(key).is_some(), "{sampler}.{key}: {json}");
            }
            assert!(json[sampler]["seconds_to_target"][1].is_null());
            for key in [
                "median_step_s",
                "samples_per_ray",
                "bones_per_sample",
                "sampling_share",
            ] {
                assert!(
                    json[sampler]["cost"].get(key).is_some(),
                    "{sampler}.cost.{key}"
                );
            }
        }
        assert_eq!(json["accelerated"]["stopped"], "budget");

        // The report marks a highest common target that dense only bounds.
        let line = "Highest common target: 18.0 dB; speed-up there: ";
        assert!(format_summary(&summary).contains(&format!("{line}1.00x.")));
        let bounded = Summary {
            highest_common_is_lower_bound: true,
            ..summary
        };
        assert!(format_summary(&bounded).contains(&format!("{line}>= 1.00x.")));
    }
}
