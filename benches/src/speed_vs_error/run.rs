//! One run of the benchmark: a sampler trained at a learning rate for a budget, paused at
//! evaluation marks to score test_same frames rendered by its own sampler, stopped at the
//! end of its budget or once it reaches a PSNR; and what its steps cost.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;
use talkin_data::dataset::Dataset;
use talkin_grids::SamplerKind;
use talkin_render::eval::{EvalOptions, evaluate};
use talkin_train::{Budget, StepLog, TrainOptions, Trainer};

use super::targets::CurvePoint;
use crate::error::BenchError;
use crate::shared::avatar_of;

/// The smallest gap between evaluations (training seconds) when no period is given.
pub const MIN_EVAL_GAP_S: f64 = 5.0;
/// The gap between evaluations as a share of the training seconds so far, when no period
/// is given: a time to a target is then interpolated over at most a 25% stretch.
pub const EVAL_GAP_SHARE: f64 = 0.25;

/// The training seconds at which a run of `budget_s` is evaluated: 0 (the untrained
/// field), then every `every_s`, or (`None`) gaps growing with the time trained
/// ([`EVAL_GAP_SHARE`] of it, at least [`MIN_EVAL_GAP_S`]): a curve rises fastest early.
/// The budget is always a mark. A run skips the marks that come sooner after its last
/// evaluation than that evaluation took (a dense evaluation costs about 20 s a frame).
pub fn eval_marks(budget_s: f64, every_s: Option<f64>) -> Vec<f64> {
    let mut marks = vec![0.0];
    let mut t = 0.0;
    loop {
        let gap = every_s.unwrap_or((EVAL_GAP_SHARE * t).max(MIN_EVAL_GAP_S));
        t += gap;
        // A last stretch shorter than a fifth of a gap joins the one before.
        if t >= budget_s - 0.2 * gap {
            break;
        }
        marks.push(t);
    }
    marks.push(budget_s);
    marks
}

/// When and for how long a run was last evaluated.
#[derive(Clone, Copy, Debug)]
struct LastEval {
    /// Training seconds at the evaluation.
    at_s: f64,
    /// Wall seconds it took.
    took_s: f64,
}

/// Whether to evaluate at `mark`: always at the first and the last mark, otherwise only
/// once the run has trained at least as long as its last evaluation took. A dense
/// evaluation (tens of seconds) then never takes longer than the training between two,
/// while the accelerated run's (a few seconds) keeps every mark.
fn worth_evaluating(mark: f64, last: Option<LastEval>, is_last_mark: bool) -> bool {
    match last {
        None => true,
        Some(_) if is_last_mark => true,
        Some(last) => mark - last.at_s >= last.took_s,
    }
}

/// What to run.
pub(crate) struct RunSpec<'a> {
    /// Run directory name under `out/runs/`, and its label in the report.
    pub name: String,
    pub sampler: SamplerKind,
    pub lr: f64,
    /// Training seconds of the schedule (the learning-rate decay and the paper's phases
    /// follow it) and at most of the run.
    pub budget_s: f64,
    /// Evaluate at these training seconds (ascending; the last ends the run).
    pub marks: &'a [f64],
    /// Stop after the first evaluation at or above this PSNR that follows a step: an
    /// untrained field that already scores it is 0 s to the target on the curve, and the
    /// run still trains to its next mark so that its steps' cost is measured.
    pub stop_at_psnr: Option<f64>,
    /// Write the final checkpoint (for the runs the report is about).
    pub save: bool,
}

/// What the shared recipe and evaluation are.
pub(crate) struct RunContext<'a> {
    pub dataset: &'a Dataset,
    pub out: &'a Path,
    pub train: &'a TrainOptions,
    pub eval_frames: &'a [usize],
    pub eval: EvalOptions,
}

/// One evaluation of a run (a row of the CSV).
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    /// The run's name: `accelerated`, `dense` or `dense-sweep-lr-<lr>`.
    pub run: String,
    pub sampler: String,
    pub lr: f64,
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
    /// Seconds the evaluation took (not training time).
    pub eval_s: f64,
}

/// What a run's steps cost, over every step it took.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StepCost {
    pub median_step_s: f64,
    /// Training seconds over steps (grid updates and first visits of a frame included).
    pub mean_step_s: f64,
    /// Field samples per training ray.
    pub samples_per_ray: f64,
    /// Body bones inverse skinning evaluates per sample (its candidates).
    pub bones_per_sample: f64,
    /// Share of the training seconds spent drawing samples.
    pub sampling_share: f64,
}

/// Accumulates [`StepCost`] from step logs.
#[derive(Default)]
struct CostMeter {
    step_s: Vec<f64>,
    last_seconds: f64,
    rays: f64,
    samples: f64,
    bone_evaluations: f64,
    sampling_s: f64,
}

impl CostMeter {
    fn add(&mut self, log: &StepLog) {
        self.step_s.push(log.seconds - self.last_seconds);
        self.last_seconds = log.seconds;
        self.rays += log.rays as f64;
        self.samples += log.samples as f64;
        self.bone_evaluations += log.bones_per_sample * log.samples as f64;
        self.sampling_s += log.sampling_s;
    }

    fn samples_per_ray(&self) -> f64 {
        self.samples / self.rays.max(1.0)
    }

    fn cost(&self) -> StepCost {
        let mut sorted = self.step_s.clone();
        sorted.sort_by(f64::total_cmp);
        let median = match sorted.len() {
            0 => 0.0,
            n if n % 2 == 1 => sorted[n / 2],
            n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
        };
        StepCost {
            median_step_s: median,
            mean_step_s: self.last_seconds / sorted.len().max(1) as f64,
            samples_per_ray: self.samples_per_ray(),
            bones_per_sample: self.bone_evaluations / self.samples.max(1.0),
            sampling_share: self.sampling_s / self.last_seconds.max(1e-9),
        }
    }
}

/// Why a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// Its last mark (the budget, or the sweep's length).
    Budget,
    /// It reached the PSNR it was asked to reach.
    ReachedTarget,
}

/// A finished run.
pub(crate) struct RunResult {
    pub points: Vec<Point>,
    pub cost: StepCost,
    pub trained_s: f64,
    pub steps: usize,
    pub setup_s: f64,
    pub eval_s: f64,
    pub stop: Stop,
    pub lpips_note: Option<String>,
}

impl RunResult {
    /// The run's curve for [`super::targets`].
    pub fn curve(&self) -> Vec<CurvePoint> {
        self.points
            .iter()
            .map(|p| CurvePoint {
                seconds: p.seconds,
                steps: p.steps as f64,
                psnr: p.psnr,
            })
            .collect()
    }
}

/// Trains `spec`, evaluating at its marks; `progress` hears each evaluation.
pub(crate) fn train_and_score(
    ctx: &RunContext,
    spec: &RunSpec,
    progress: &mut dyn FnMut(&str),
) -> Result<RunResult, BenchError> {
    let opts = TrainOptions {
        sampler: spec.sampler,
        lr: Some(spec.lr),
        budget: Budget::Seconds(spec.budget_s),
        // Checkpoints only at the end: writing them is not training.
        checkpoint_every_s: f64::INFINITY,
        ..ctx.train.clone()
    };
    let setup = Instant::now();
    let mut trainer = Trainer::new(ctx.dataset, &ctx.out.join("runs").join(&spec.name), &opts)?;
    let setup_s = setup.elapsed().as_secs_f64();
    let mut meter = CostMeter::default();
    let mut points = Vec::new();
    let (mut eval_s, mut lpips_note, mut stop) = (0.0, None, Stop::Budget);
    let mut last_eval = None;
    for (i, &mark) in spec.marks.iter().enumerate() {
        if !worth_evaluating(mark, last_eval, i + 1 == spec.marks.len()) {
            continue;
        }
        while trainer.elapsed_seconds() < mark && !trainer.done() {
            for log in trainer.step()? {
                meter.add(&log);
            }
        }
        for log in trainer.settle()? {
            meter.add(&log);
        }
        let start = Instant::now();
        // The run's own sampler renders it (the avatar keeps the trainer's).
        let report = evaluate(
            &avatar_of(&trainer),
            ctx.dataset,
            ctx.eval_frames,
            &ctx.eval,
        )?;
        let took = start.elapsed().as_secs_f64();
        eval_s += took;
        last_eval = Some(LastEval {
            at_s: trainer.elapsed_seconds(),
            took_s: took,
        });
        lpips_note = report.lpips_note.clone().or(lpips_note);
        progress(&format!(
            "{}: {:.2} dB at {:.0} s ({} steps; evaluating took {took:.0} s)",
            spec.name,
            report.psnr,
            trainer.elapsed_seconds(),
            trainer.steps_taken(),
        ));
        points.push(Point {
            run: spec.name.clone(),
            sampler: spec.sampler.name().into(),
            lr: spec.lr,
            seconds: trainer.elapsed_seconds(),
            steps: trainer.steps_taken(),
            psnr: report.psnr,
            ssim: report.ssim,
            lpips: report.lpips,
            psnr_face: report.psnr_face,
            psnr_hands: report.psnr_hands,
            samples_per_ray: meter.samples_per_ray(),
            eval_s: took,
        });
        if trainer.steps_taken() > 0 && spec.stop_at_psnr.is_some_and(|t| report.psnr >= t) {
            stop = Stop::ReachedTarget;
            break;
        }
    }
    if spec.save {
        trainer.save()?;
    }
    Ok(RunResult {
        points,
        cost: meter.cost(),
        trained_s: trainer.elapsed_seconds(),
        steps: trainer.steps_taken(),
        setup_s,
        eval_s,
        stop,
        lpips_note,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_start_untrained_grow_with_time_and_end_at_the_budget() {
        let marks = eval_marks(600.0, None);
        assert_eq!(&marks[..5], &[0.0, 5.0, 10.0, 15.0, 20.0]);
        assert_eq!(*marks.last().unwrap(), 600.0);
        for w in marks.windows(2) {
            let gap = w[1] - w[0];
            assert!(gap > 0.0 && gap <= (EVAL_GAP_SHARE * w[0]).max(MIN_EVAL_GAP_S) * 1.2);
        }
        // A fixed period, the last stretch joined to the one before when short.
        assert_eq!(
            eval_marks(100.0, Some(30.0)),
            vec![0.0, 30.0, 60.0, 90.0, 100.0]
        );
        assert_eq!(eval_marks(62.0, Some(30.0)), vec![0.0, 30.0, 62.0]);
        assert_eq!(eval_marks(3.0, None), vec![0.0, 3.0]);
    }

    #[test]
    fn slow_evaluations_skip_marks_but_never_the_first_or_last() {
        let slow = Some(LastEval {
            at_s: 10.0,
            took_s: 70.0,
        });
        assert!(worth_evaluating(0.0, None, false));
        assert!(!worth_evaluating(15.0, slow, false));
        assert!(!worth_evaluating(79.9, slow, false));
        assert!(worth_evaluating(80.0, slow, false));
        assert!(worth_evaluating(15.0, slow, true));
        let fast = Some(LastEval {
            at_s: 10.0,
            took_s: 3.0,
        });
        assert!(worth_evaluating(15.0, fast, false));
    }

    #[test]
    fn step_cost_is_taken_from_the_logs() {
        let mut meter = CostMeter::default();
        for (k, (dt, samples, bones)) in [(0.1, 100, 2.0), (0.3, 300, 4.0), (0.2, 100, 2.0)]
            .into_iter()
            .enumerate()
        {
            let seconds = meter.last_seconds + dt;
            meter.add(&StepLog {
                step: k + 1,
                seconds,
                loss: 0.0,
                mse: 0.0,
                psnr: 0.0,
                rays: 10,
                samples,
                rays_per_s: 0.0,
                samples_per_s: 0.0,
                lr: 0.0,
                progress: 0.0,
                grid_occupied: 1.0,
                sampling_s: dt / 10.0,
                bones_per_sample: bones,
            });
        }
        let c = meter.cost();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(
            close(c.median_step_s, 0.2) && close(c.mean_step_s, 0.2),
            "{c:?}"
        );
        assert!(close(c.samples_per_ray, 500.0 / 30.0), "{c:?}");
        // Weighted by samples: (200 + 1200 + 200) / 500.
        assert!(close(c.bones_per_sample, 3.2), "{c:?}");
        assert!(close(c.sampling_share, 0.1), "{c:?}");
    }
}
