//! Time to quality: when a run's evaluated PSNR first reaches each target (interpolated
//! between evaluations), and the speed-up at each target split into its two factors,
//!
//! `speedup = dense_seconds / accelerated_seconds
//!          = (dense_steps / accelerated_steps) x (dense s/step / accelerated s/step)`,
//!
//! with each run's seconds a step taken as its mean up to the target, so the product is
//! exact. A target the dense run never reached within its budget gives a lower bound:
//! the dense run's training seconds over the accelerated run's time to the target.

use serde::Serialize;

/// One evaluation of a run: training seconds, steps and PSNR (dB).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvePoint {
    pub seconds: f64,
    pub steps: f64,
    pub psnr: f64,
}

/// Where a run first reached a target: training seconds and steps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Crossing {
    pub seconds: f64,
    pub steps: f64,
}

/// What a run trained in all: the dense run's totals bound a target it never reached.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunTotals {
    pub seconds: f64,
    pub steps: f64,
}

/// The first time `curve` (evaluations in training order, the untrained start first)
/// reaches `target`, linearly interpolated in seconds and steps between the last
/// evaluation below it and the first at or above it; `None` if it never does. A start
/// already at the target reaches it at the start.
pub fn first_crossing(curve: &[CurvePoint], target: f64) -> Option<Crossing> {
    let first = curve.first()?;
    if first.psnr >= target {
        return Some(Crossing {
            seconds: first.seconds,
            steps: first.steps,
        });
    }
    curve.windows(2).find_map(|w| {
        let (a, b) = (w[0], w[1]);
        (b.psnr >= target).then(|| {
            // a.psnr < target <= b.psnr here (the first window whose end reaches it).
            let f = ((target - a.psnr) / (b.psnr - a.psnr)).clamp(0.0, 1.0);
            Crossing {
                seconds: a.seconds + f * (b.seconds - a.seconds),
                steps: a.steps + f * (b.steps - a.steps),
            }
        })
    })
}

/// The highest of `targets` that `curve` reaches, if any.
pub fn highest_reached(targets: &[f64], curve: &[CurvePoint]) -> Option<f64> {
    targets
        .iter()
        .copied()
        .filter(|&t| first_crossing(curve, t).is_some())
        .max_by(f64::total_cmp)
}

/// One target: both runs' crossings, the speed-up and its two factors.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TargetRow {
    pub target_db: f64,
    pub accelerated: Option<Crossing>,
    pub dense: Option<Crossing>,
    /// Dense seconds over accelerated seconds to the target; with `is_lower_bound`, the
    /// dense run's training seconds over the accelerated run's (dense never got there).
    /// `None` when the accelerated run never got there.
    pub speedup: Option<f64>,
    pub is_lower_bound: bool,
    /// Dense steps over accelerated steps to the target (a lower bound with
    /// `is_lower_bound`).
    pub steps_ratio: Option<f64>,
    /// Dense seconds a step over accelerated seconds a step, each run's mean up to the
    /// target (the dense run's mean over its whole run with `is_lower_bound`).
    pub step_cost_ratio: Option<f64>,
}

/// Every target's row. `dense_totals`: what the dense run trained in all.
pub fn compare_at_targets(
    targets: &[f64],
    accelerated: &[CurvePoint],
    dense: &[CurvePoint],
    dense_totals: RunTotals,
) -> Vec<TargetRow> {
    targets
        .iter()
        .map(|&target| {
            let a = first_crossing(accelerated, target);
            let d = first_crossing(dense, target);
            let is_lower_bound = a.is_some() && d.is_none();
            let dense_side = d.unwrap_or(Crossing {
                seconds: dense_totals.seconds,
                steps: dense_totals.steps,
            });
            let ratios = a.filter(|a| a.seconds > 0.0 && a.steps > 0.0).map(|a| {
                let steps_ratio = dense_side.steps / a.steps;
                let per_step = |c: Crossing| c.seconds / c.steps.max(1e-9);
                (
                    dense_side.seconds / a.seconds,
                    steps_ratio,
                    per_step(dense_side) / per_step(a),
                )
            });
            TargetRow {
                target_db: target,
                accelerated: a,
                dense: d,
                speedup: ratios.map(|r| r.0),
                is_lower_bound: is_lower_bound && ratios.is_some(),
                steps_ratio: ratios.map(|r| r.1),
                step_cost_ratio: ratios.map(|r| r.2),
            }
        })
        .collect()
}

/// The row of the highest target the accelerated run reached with a speed-up to say:
/// measured where the dense run reached it too, a lower bound (`is_lower_bound`) where
/// the dense run trained its whole budget without reaching it. `None` if the accelerated
/// run reached no target.
pub fn highest_common(rows: &[TargetRow]) -> Option<&TargetRow> {
    rows.iter()
        .filter(|r| r.speedup.is_some())
        .max_by(|a, b| a.target_db.total_cmp(&b.target_db))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curve(points: &[(f64, f64, f64)]) -> Vec<CurvePoint> {
        points
            .iter()
            .map(|&(seconds, steps, psnr)| CurvePoint {
                seconds,
                steps,
                psnr,
            })
            .collect()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn crossings_interpolate_seconds_and_steps_between_evaluations() {
        let c = curve(&[(0.0, 0.0, 8.0), (10.0, 100.0, 16.0), (30.0, 300.0, 20.0)]);
        // 18 dB is halfway from 16 (10 s, 100 steps) to 20 (30 s, 300 steps).
        let x = first_crossing(&c, 18.0).unwrap();
        assert!(close(x.seconds, 20.0) && close(x.steps, 200.0), "{x:?}");
        // Exactly at an evaluation.
        assert_eq!(first_crossing(&c, 16.0).unwrap().seconds, 10.0);
        // From the untrained start: 12 dB is halfway to the first evaluation.
        assert!(close(first_crossing(&c, 12.0).unwrap().seconds, 5.0));
        // Never reached.
        assert_eq!(first_crossing(&c, 20.5), None);
        assert_eq!(first_crossing(&[], 10.0), None);
        // The first time counts, not a later dip and recovery.
        let dip = curve(&[(0.0, 0.0, 8.0), (10.0, 10.0, 20.0), (20.0, 20.0, 15.0)]);
        assert!(close(first_crossing(&dip, 14.0).unwrap().seconds, 5.0));
        assert_eq!(highest_reached(&[14.0, 18.0, 22.0], &dip), Some(18.0));
        assert_eq!(highest_reached(&[22.0], &dip), None);
    }

    #[test]
    fn speedup_splits_into_steps_and_step_cost_and_bounds_what_dense_missed() {
        // Accelerated: 1 s a step; dense: 5 s a step and twice the steps to 18 dB.
        let acc = curve(&[(0.0, 0.0, 8.0), (10.0, 10.0, 18.0), (40.0, 40.0, 24.0)]);
        let dense = curve(&[(0.0, 0.0, 8.0), (100.0, 20.0, 18.0), (300.0, 60.0, 21.0)]);
        let totals = RunTotals {
            seconds: 300.0,
            steps: 60.0,
        };
        let rows = compare_at_targets(&[18.0, 24.0, 26.0], &acc, &dense, totals);
        let r = &rows[0];
        assert!(
            close(r.speedup.unwrap(), 10.0) && !r.is_lower_bound,
            "{r:?}"
        );
        assert!(close(r.steps_ratio.unwrap(), 2.0), "{r:?}");
        assert!(close(r.step_cost_ratio.unwrap(), 5.0), "{r:?}");
        // 24 dB: dense never got there in its 300 s, so 300 / 40 is a lower bound.
        let r = &rows[1];
        assert!(r.is_lower_bound && r.dense.is_none(), "{r:?}");
        assert!(close(r.speedup.unwrap(), 7.5), "{r:?}");
        assert!(close(
            r.steps_ratio.unwrap() * r.step_cost_ratio.unwrap(),
            7.5
        ));
        // 26 dB: the accelerated run never got there either: nothing to say.
        let r = &rows[2];
        assert!(r.speedup.is_none() && !r.is_lower_bound && r.accelerated.is_none());
        // The highest common target is 24 dB, with its lower bound; without the rows the
        // accelerated run reached there is none.
        let common = highest_common(&rows).unwrap();
        assert!(
            common.target_db == 24.0 && common.is_lower_bound,
            "{common:?}"
        );
        assert_eq!(highest_common(&rows[..1]).unwrap().target_db, 18.0);
        assert_eq!(highest_common(&rows[2..]), None);
    }
}
