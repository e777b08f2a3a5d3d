//! The report's rows from the recorded stage totals and the measured ceilings.

use std::collections::BTreeMap;

use talkin_nets::profile::StageTotal;

use super::{Peaks, StepReport, WallRow, WorkRow};

/// Stages of the whole step, on its thread.
const WALL: &str = "step (wall): ";
/// The whole step's own stage (the denominator of the wall rows).
const WHOLE: &str = "step (wall): whole step";
/// The field's stretch of the step (its chunks, joined).
const FIELD_WALL: &str = "step (wall): field, loss and gradients";
/// Kernels: counted work.
const KERNEL: &str = "kernel: ";
/// The kernel that runs on the step's thread alone, not inside the chunks.
const ADAM: &str = "kernel: Adam";

/// What the timed steps gave besides the stage totals.
pub(super) struct Measured {
    pub source: String,
    pub warmup: usize,
    pub steps: usize,
    pub rays_per_step: f64,
    pub samples_per_step: f64,
    pub wall_s: f64,
}

pub(super) fn build(m: Measured, totals: &BTreeMap<&str, StageTotal>, peaks: Peaks) -> StepReport {
    let steps = m.steps as f64;
    let per_step_ms = |s: f64| s * 1e3 / steps;
    let whole_s = totals.get(WHOLE).map_or(m.wall_s, |t| t.seconds);
    let field_wall_s = totals.get(FIELD_WALL).map_or(0.0, |t| t.seconds);

    let mut wall: Vec<WallRow> = totals
        .iter()
        .filter(|(name, _)| name.starts_with(WALL) && **name != WHOLE)
        .map(|(name, t)| WallRow {
            stage: name.trim_start_matches(WALL).to_string(),
            ms_per_step: per_step_ms(t.seconds),
            share: t.seconds / whole_s.max(1e-12),
        })
        .collect();
    wall.sort_by(|a, b| b.ms_per_step.total_cmp(&a.ms_per_step));
    let listed: f64 = wall.iter().map(|r| r.ms_per_step).sum();
    let whole_ms = per_step_ms(whole_s);
    wall.push(WallRow {
        stage: "the rest (the log, pose refinement, the step's own copies)".into(),
        ms_per_step: (whole_ms - listed).max(0.0),
        share: ((whole_ms - listed) / whole_ms.max(1e-12)).max(0.0),
    });

    // The chunks' field work: every `step:` stage.
    let field_thread_s: f64 = totals
        .iter()
        .filter(|(name, _)| name.starts_with("step: "))
        .map(|(_, t)| t.seconds)
        .sum();
    let field_threads = if field_wall_s > 0.0 {
        (field_thread_s / field_wall_s).max(1.0)
    } else {
        1.0
    };
    let samples = (m.samples_per_step * steps).max(1.0);
    let work_row = |name: &str, t: &StageTotal| {
        let (threads, denominator) = if name == ADAM {
            (1.0, whole_s)
        } else {
            (field_threads, field_thread_s)
        };
        let time_s = (t.seconds / threads).max(1e-12);
        let w = t.work;
        let streamed = (w.bytes - w.gathered).max(0.0);
        let ceilings = [
            ("compute", w.flops / (peaks.matmul_gflops * 1e9)),
            ("stream", streamed / (peaks.stream_gbs * 1e9)),
            ("gather", w.gathered / (peaks.gather_gbs * 1e9)),
        ];
        let (bound, ideal_s) = ceilings
            .iter()
            .copied()
            .filter(|(_, s)| s.is_finite())
            .fold(("-", 0.0), |best, c| if c.1 > best.1 { c } else { best });
        WorkRow {
            stage: name.to_string(),
            thread_ms_per_step: per_step_ms(t.seconds),
            share: t.seconds / denominator.max(1e-12),
            calls_per_step: t.calls as f64 / steps,
            flops_per_sample: w.flops / samples,
            bytes_per_sample: w.bytes / samples,
            gathered_per_sample: w.gathered / samples,
            gflops: w.flops / time_s / 1e9,
            gbs: w.bytes / time_s / 1e9,
            ideal_ms_per_step: per_step_ms(ideal_s),
            efficiency: ideal_s / time_s,
            bound: bound.to_string(),
        }
    };
    // The chunks' stages, then what the forward is made of, then the kernels.
    let mut work = Vec::new();
    for prefix in ["step: ", "field: ", KERNEL] {
        let mut rows: Vec<WorkRow> = totals
            .iter()
            .filter(|(name, _)| name.starts_with(prefix))
            .map(|(name, t)| work_row(name, t))
            .collect();
        rows.sort_by(|a, b| b.thread_ms_per_step.total_cmp(&a.thread_ms_per_step));
        work.extend(rows);
    }
    let counted_ideal_ms = work
        .iter()
        .filter(|r| r.stage.starts_with(KERNEL))
        .map(|r| r.ideal_ms_per_step)
        .sum();
    StepReport {
        source: m.source,
        warmup: m.warmup,
        steps: m.steps,
        rays_per_step: m.rays_per_step,
        samples_per_step: m.samples_per_step,
        samples_per_ray: m.samples_per_step / m.rays_per_step.max(1.0),
        step_ms: m.wall_s * 1e3 / steps,
        steps_per_s: steps / m.wall_s.max(1e-12),
        samples_per_s: m.samples_per_step * steps / m.wall_s.max(1e-12),
        field_threads,
        peaks,
        wall,
        work,
        counted_ideal_ms,
    }
}

#[cfg(test)]
mod tests {
    use talkin_nets::profile::Work;

    use super::*;

    fn stage(seconds: f64, work: Work) -> StageTotal {
        StageTotal {
            seconds,
            calls: 10,
            work,
        }
    }

    #[test]
    fn a_kernel_at_the_ceiling_is_fully_efficient_and_names_its_bound() {
        let peaks = Peaks {
            threads: 2,
            matmul_gflops: 100.0,
            gather_gbs: 1.0,
            gather_table_mib: 4.0,
            stream_gbs: 10.0,
        };
        // Two chunks at once: 2 thread seconds of field work in 1 s of the field's wall.
        // The MLP's 1e11 FLOP in its 2 thread seconds (1 s at two threads) is the
        // ceiling; the lookup's 0.5 GB gathered takes 0.5 s at best, against its 1 s.
        let mlp = Work {
            flops: 1e11,
            bytes: 1e9,
            gathered: 0.0,
        };
        let lookup = Work {
            flops: 1e9,
            bytes: 1e9,
            gathered: 5e8,
        };
        let totals: BTreeMap<&str, StageTotal> = [
            ("step (wall): whole step", stage(2.0, Work::default())),
            (
                "step (wall): field, loss and gradients",
                stage(1.5, Work::default()),
            ),
            ("step: field forward", stage(3.0, Work::default())),
            ("kernel: MLP forward", stage(2.0, mlp)),
            ("kernel: hash forward (lookup)", stage(2.0, lookup)),
        ]
        .into_iter()
        .collect();
        let m = Measured {
            source: "test".into(),
            warmup: 0,
            steps: 10,
            rays_per_step: 100.0,
            samples_per_step: 1000.0,
            wall_s: 2.0,
        };
        let r = build(m, &totals, peaks);
        assert_eq!(r.field_threads, 2.0);
        let row = |name: &str| r.work.iter().find(|w| w.stage == name).unwrap();
        let mlp = row("kernel: MLP forward");
        assert_eq!(mlp.bound, "compute");
        assert!((mlp.efficiency - 1.0).abs() < 1e-9);
        assert!((mlp.flops_per_sample - 1e7).abs() < 1e-3);
        let lookup = row("kernel: hash forward (lookup)");
        assert_eq!(lookup.bound, "gather");
        assert!((lookup.efficiency - 0.5).abs() < 1e-9);
        // The wall rows: the field's 75% of the step, and the rest.
        assert_eq!(r.wall[0].stage, "field, loss and gradients");
        assert!((r.wall[0].share - 0.75).abs() < 1e-9);
        assert!((r.wall[1].share - 0.25).abs() < 1e-9);
        assert!((r.counted_ideal_ms - (100.0 + 50.0)).abs() < 1e-6);
    }
}
