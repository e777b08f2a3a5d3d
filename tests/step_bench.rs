//! `talkin bench step` on a tiny scene: every stage of the step is timed, the stages of
//! the whole step account for it, the fused kernels count their work, and each kernel is
//! set against a measured ceiling. Its own test binary: the stage timers are global to
//! the process.

mod common;

use talkin::benches::step::{StepBenchOptions, run, table};
use talkin::grids::SamplerKind;

#[test]
fn the_step_bench_times_every_stage_and_sets_the_kernels_against_the_ceilings() {
    let dataset = common::synthetic_scene("step_bench_scene", 1, 64, 2);
    let work = common::temp_dir("step_bench_work");
    let opts = StepBenchOptions {
        run: None,
        warmup: 2,
        steps: 3,
        train: common::small_train_opts(SamplerKind::Accelerated, 5),
    };
    let r = run(&dataset, &work, &opts, &mut |_| {}).unwrap();
    assert!(
        r.samples_per_step > 0.0 && r.rays_per_step == 256.0,
        "{r:?}"
    );
    for rate in [
        r.peaks.matmul_gflops,
        r.peaks.gather_gbs,
        r.peaks.stream_gbs,
    ] {
        assert!(rate.is_finite() && rate > 0.0, "{:?}", r.peaks);
    }
    // The step's stages and the rest make up the step.
    let shares: f64 = r.wall.iter().map(|w| w.share).sum();
    assert!((shares - 1.0).abs() < 0.05, "{:?}", r.wall);
    for stage in ["field, loss and gradients", "sampling", "Adam", "rays"] {
        assert!(
            r.wall.iter().any(|w| w.stage == stage),
            "no wall row {stage}"
        );
    }
    // The kernels a fast-preset step runs, each with its work counted and a bound.
    let kernel = |name: &str| {
        r.work
            .iter()
            .find(|w| w.stage == name)
            .unwrap_or_else(|| panic!("no row {name}: {:?}", r.work))
    };
    for name in [
        "kernel: MLP forward",
        "kernel: MLP backward",
        "kernel: hash forward (lookup)",
        "kernel: hash backward (table)",
        "kernel: Adam",
    ] {
        let k = kernel(name);
        assert!(
            k.flops_per_sample > 0.0 && k.bytes_per_sample > 0.0,
            "{k:?}"
        );
        assert!(k.efficiency.is_finite() && k.efficiency > 0.0, "{k:?}");
        assert!(
            ["compute", "stream", "gather"].contains(&k.bound.as_str()),
            "{k:?}"
        );
    }
    // A 2x64 MLP's forward is at least a row's two 64-wide layers: 2 x 64 x 64 x 2.
    assert!(kernel("kernel: MLP forward").flops_per_sample >= 2.0 * 64.0 * 64.0 * 2.0);
    for stage in [
        "step: field forward",
        "step: backward",
        "field: F_body",
        "field: skinning",
    ] {
        assert!(kernel(stage).thread_ms_per_step > 0.0, "{stage}");
    }
    let md = table(&r);
    assert!(
        md.contains("| kernel: Adam |") && md.contains("GFLOP/s"),
        "{md}"
    );
    // Recording is off once the bench returns.
    assert!(!talkin::nets::profile::enabled());
}

#[test]
fn the_step_bench_refuses_zero_timed_steps() {
    let dataset = common::synthetic_scene("step_bench_zero", 1, 48, 2);
    let opts = StepBenchOptions {
        run: None,
        warmup: 0,
        steps: 0,
        train: common::small_train_opts(SamplerKind::Accelerated, 1),
    };
    let e = run(
        &dataset,
        &common::temp_dir("step_bench_zero_work"),
        &opts,
        &mut |_| {},
    )
    .unwrap_err();
    assert!(e.to_string().contains("--timed-steps"), "{e}");
}
