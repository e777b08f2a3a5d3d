//! The device path: `--device` parses and refuses what it cannot open, and (with the
//! `wgpu` feature, on any Vulkan adapter, Mesa's lavapipe included) a few training steps
//! and a render on wgpu match the CPU from the same seed.
//!
//! The equivalence test is ignored by `cargo test` (it needs the `wgpu` feature and an
//! adapter); run it with
//! `cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored`.

mod common;

use std::process::Command;

use talkin::nets::ComputeDevice;
use talkin::render::avatar::RenderFrame;

#[test]
fn a_device_that_cannot_be_opened_is_a_named_error_and_a_nonzero_exit() {
    let data = common::temp_dir("device_cli");
    for (device, says) in [
        ("cuda", "expected `cpu`, `wgpu` or `wgpu:N`"),
        ("wgpu:x", "expected `cpu`, `wgpu` or `wgpu:N`"),
        #[cfg(not(feature = "wgpu"))]
        ("wgpu", "--features wgpu"),
        #[cfg(feature = "wgpu")]
        ("wgpu:64", "adapter"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(["eval", "--run", "nowhere", "--split", "test_same", "--json"])
            .arg(data.join("e.json"))
            .arg("--data")
            .arg(&data)
            .args(["--device", device])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{device}: exit 0");
        assert!(stderr.contains(says), "{device}: {stderr}");
        assert!(!stderr.contains("panicked"), "{device}: {stderr}");
    }
    // The CPU is always there.
    assert!(ComputeDevice::Cpu.open().is_ok());
}

/// `bench device --avatar RUN` renders the run's own avatar (its checkpoint, its grid) on
/// each device, the shot the training rows render, and names a run it cannot load.
#[test]
fn the_device_bench_renders_a_trained_avatar() {
    use talkin::avatar::Avatar;
    use talkin::benches::device::{DeviceBenchOptions, render_shot, run, table};
    use talkin::grids::SamplerKind;
    use talkin::train::{Preset, Trainer};

    let dataset = common::synthetic_scene("device_bench_scene", 1, 64, 5);
    let trained = common::temp_dir("device_bench_run");
    let train = common::small_train_opts(SamplerKind::Accelerated, 2);
    // Trained with the dense sampler, so its frames sample unlike the fresh fields'.
    let dense = common::small_train_opts(SamplerKind::Dense, 1);
    let mut trainer = Trainer::new(&dataset, &trained, &dense).unwrap();
    while !trainer.done() {
        trainer.step().unwrap();
    }
    trainer.save().unwrap();
    drop(trainer);

    let opts = DeviceBenchOptions {
        devices: vec![ComputeDevice::Cpu],
        presets: vec![Preset::Fast],
        warmup: 1,
        steps: 1,
        renders: 1,
        render_side: 32,
        avatar: Some(trained.clone()),
        train: train.clone(),
    };
    let work = common::temp_dir("device_bench_work");
    let report = run(&dataset, &work, &opts, &mut |_| {}).unwrap();
    assert_eq!(report.render_size, [32, 32]);
    assert_eq!(report.rows.len(), 1);
    assert_eq!(report.avatar_rows.len(), 1);
    let row = &report.avatar_rows[0];
    assert_eq!(row.run, trained);
    assert!(row.render.render_ms_median > 0.0, "{row:?}");
    // The samples of the run's avatar rendering that shot itself.
    let (frame, camera) = render_shot(&dataset, 32).unwrap();
    let direct = Avatar::load(&trained)
        .unwrap()
        .render(frame.subject, &frame.params, &camera, None)
        .unwrap();
    assert!(direct.samples > 0);
    assert_eq!(row.render.render_samples, direct.samples);
    assert_ne!(direct.samples, report.rows[0].render.render_samples);
    assert!(
        table(&report).contains("A trained avatar"),
        "{}",
        table(&report)
    );

    let missing = work.join("no_such_run");
    let err = run(
        &dataset,
        &work,
        &DeviceBenchOptions {
            avatar: Some(missing.clone()),
            ..opts
        },
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("no_such_run"), "{err}");
    assert!(render_shot(&dataset, 8).is_err());
}

#[cfg(feature = "wgpu")]
mod wgpu {
    use burn::module::{Module, ModuleVisitor, Param};
    use burn::prelude::*;
    use talkin::avatar::Avatar;
    use talkin::benches::shared::avatar_of;
    use talkin::grids::SamplerKind;
    use talkin::nets::{ComputeDevice, TalkinField};
    use talkin::render::avatar::RenderFrame;
    use talkin::render::metrics::{Rect, psnr};
    use talkin::train::{StepLog, Trainer};

    use super::common;

    const STEPS: usize = 8;

    /// Every float parameter of a field, in visiting order, on the host.
    fn parameters(field: &TalkinField) -> Vec<Vec<f32>> {
        struct Collect(Vec<Vec<f32>>);
        impl ModuleVisitor for Collect {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                self.0.push(param.val().try_to_vec_as::<f32>().unwrap());
            }
        }
        let mut c = Collect(Vec::new());
        field.visit(&mut c);
        c.0
    }

    /// `STEPS` steps on `device`, the per-step logs and the trainer.
    fn train<'a>(
        dataset: &'a talkin::data::dataset::Dataset,
        name: &str,
        device: ComputeDevice,
    ) -> (Vec<StepLog>, Trainer<'a>) {
        let out = common::temp_dir(name);
        let mut opts = common::small_train_opts(SamplerKind::Accelerated, STEPS);
        opts.device = device;
        let mut t = Trainer::new(dataset, &out, &opts).unwrap();
        let mut logs: Vec<StepLog> = (0..STEPS).flat_map(|_| t.step().unwrap()).collect();
        logs.extend(t.settle().unwrap());
        assert_eq!(logs.len(), STEPS);
        (logs, t)
    }

    /// Tolerances, stated: the two devices add in different orders (the CPU's fused
    /// kernels, wgpu's composed ops and atomic scatter-adds), so losses agree to 2%
    /// relative and each parameter to 2 x lr per step taken (Adam moves a parameter at
    /// most ~lr a step, whatever its gradient, so a sign flip in a near-zero gradient moves
    /// it that much) plus 1e-4 relative. The renders agree to 0.5 dB of PSNR against the
    /// ground truth, and to 35 dB against each other.
    #[test]
    #[ignore = "needs the wgpu feature and a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn wgpu_matches_cpu() {
        let dataset = common::synthetic_scene("device_scene", 1, 48, 1);
        let (cpu_logs, cpu) = train(&dataset, "device_run_cpu", ComputeDevice::Cpu);
        let gpu_device = ComputeDevice::Wgpu { index: 0 };
        let (gpu_logs, gpu) = train(&dataset, "device_run_wgpu", gpu_device);

        // The same start: the initial weights are drawn on the CPU for every device, the
        // rays and samples on the host.
        for (c, g) in cpu_logs.iter().zip(&gpu_logs) {
            assert_eq!(c.samples, g.samples, "step {}: the batches differ", c.step);
            let rel = (c.loss - g.loss).abs() / c.loss.abs().max(1e-6);
            println!(
                "step {}: loss cpu {:.6} wgpu {:.6} ({:.2e} relative)",
                c.step, c.loss, g.loss, rel
            );
            assert!(rel < 0.02, "step {}: loss {} vs {}", c.step, c.loss, g.loss);
        }

        let lr = cpu_logs[0].lr as f32;
        let (a, b) = (
            parameters(&cpu.inference_field()),
            parameters(&gpu.inference_field()),
        );
        assert_eq!(a.len(), b.len());
        let mut worst = 0.0f32;
        for (i, (a, b)) in a.iter().zip(&b).enumerate() {
            assert_eq!(a.len(), b.len(), "parameter {i}");
            for (x, y) in a.iter().zip(b) {
                let allowed = 2.0 * lr * STEPS as f32 + 1e-4 * x.abs();
                worst = worst.max((x - y).abs() / allowed);
                assert!((x - y).abs() <= allowed, "parameter {i}: {x} vs {y}");
            }
        }
        println!("largest parameter gap: {worst:.3} of the allowed");

        // The dataset's last frame rendered on both.
        let f = &dataset.frames[dataset.frames.len() - 1];
        let truth = image::open(dataset.root.join(&f.image)).unwrap().to_rgb8();
        let render = |t: &Trainer| {
            avatar_of(t)
                .render(0, &f.params, &f.camera, None)
                .unwrap()
                .to_image()
        };
        let (on_cpu, on_gpu) = (render(&cpu), render(&gpu));
        let full = Rect::full(&truth);
        let (p_cpu, p_gpu) = (psnr(&on_cpu, &truth, full), psnr(&on_gpu, &truth, full));
        let between = psnr(&on_cpu, &on_gpu, full);
        println!(
            "PSNR against the truth: cpu {p_cpu:.3} dB, wgpu {p_gpu:.3} dB; between {between:.1} dB"
        );
        assert!((p_cpu - p_gpu).abs() <= 0.5, "{p_cpu} vs {p_gpu}");
        assert!(between >= 35.0, "the renders differ: {between} dB");

        // A checkpoint trained on one device renders on the other.
        let cpu_run = common::temp_dir("device_ckpt_cpu");
        let mut opts = common::small_train_opts(SamplerKind::Accelerated, 2);
        talkin::train::train(&dataset, &cpu_run, &opts, &mut |_| {}).unwrap();
        opts.device = gpu_device;
        let gpu_run = common::temp_dir("device_ckpt_wgpu");
        talkin::train::train(&dataset, &gpu_run, &opts, &mut |_| {}).unwrap();
        let wgpu = gpu_device.open().unwrap();
        for run in [&cpu_run, &gpu_run] {
            let here = Avatar::load(run).unwrap();
            let there = Avatar::load_on(run, &wgpu).unwrap();
            let a = here.render(0, &f.params, &f.camera, None).unwrap();
            let b = there.render(0, &f.params, &f.camera, None).unwrap();
            let gap = psnr(&a.to_image(), &b.to_image(), full);
            println!(
                "{}: cpu vs wgpu render of one checkpoint: {gap:.1} dB",
                run.display()
            );
            assert!(gap >= 40.0, "{}: {gap} dB", run.display());
        }
    }
}

/// The kernel census of the GPU path, from cubecl's profiling log of `talkin` runs on
/// wgpu: no `select_assign` kernel (`SelectAssignKernel`: burn-cubecl runs it with one
/// thread per column, each looping over every index, so the whole batch on one thread)
/// in a training step of at least 64k samples or in a render, how many kernels one
/// step and one frame launch, and how many times each reads the GPU back (`talkin -v`
/// counts the engine's reads: none in a step, whose losses are read a few steps at a
/// time, one per frame, and one when a checkpoint is loaded).
/// A step's kernels are the difference between a 2-step and a 1-step run (the same
/// setup and final checkpoint in both); a frame's, a render's kernels over its frames.
/// Autotune tries candidate kernels the first time a process meets a shape, how many
/// depending on timing, and keeps its choice in cubecl's persistent cache: so each
/// command is repeated (at most 5 times) until its log shows no autotune, and that run is
/// counted.
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs the wgpu feature and a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn kernel_census() {
    use std::collections::BTreeMap;
    use std::path::Path;

    let bin = env!("CARGO_BIN_EXE_talkin");
    // The kernels a command ran, by name (generics cut), from its profiling log.
    let census_once = |args: &[&str], log: &Path| -> (BTreeMap<String, usize>, bool, usize) {
        let _ = std::fs::remove_file(log);
        let out = Command::new(bin)
            .args(args)
            .env("CUBECL_DEBUG_LOG", log)
            .env("CUBECL_DEBUG_OPTION", "profile")
            .env("CUBECL_AUTOTUNE_LEVEL", "minimal")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "talkin {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        let readbacks = stderr
            .lines()
            .find_map(|l| l.strip_prefix("debug: device readbacks: "))
            .and_then(|n| n.trim().parse().ok())
            .unwrap_or_else(|| panic!("talkin {args:?} did not count its readbacks: {stderr}"));
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let mut kernels = BTreeMap::new();
        // A kernel's line is `| <duration> | <name>`; the summary's rows start with a
        // name instead.
        for line in text.lines() {
            let mut fields = line.splitn(3, '|').skip(1);
            let (Some(duration), Some(name)) = (fields.next(), fields.next()) else {
                continue;
            };
            let duration = duration.trim();
            if !(duration.starts_with(|c: char| c.is_ascii_digit()) || duration == "not measured") {
                continue;
            }
            *kernels.entry(name.trim().to_string()).or_insert(0) += 1;
        }
        (kernels, text.contains("Fastest result"), readbacks)
    };
    let census = |args: &[&str], log: &Path| -> (BTreeMap<String, usize>, usize) {
        for _ in 0..5 {
            let (kernels, tuned, readbacks) = census_once(args, log);
            if !tuned {
                return (kernels, readbacks);
            }
        }
        panic!(
            "talkin {args:?} still autotunes after 5 runs: see {}",
            log.display()
        );
    };
    let total = |k: &BTreeMap<String, usize>| k.values().sum::<usize>();
    let serial = |k: &BTreeMap<String, usize>| {
        k.iter()
            .filter(|(name, _)| {
                name.to_ascii_lowercase()
                    .replace('_', "")
                    .contains("selectassign")
            })
            .map(|(name, n)| format!("{name} x{n}"))
            .collect::<Vec<_>>()
    };

    let data = common::temp_dir("census_scene");
    let status = Command::new(bin)
        .args(["-q", "synth", "--out", data.to_str().unwrap()])
        .args(["--identities", "1", "--frames", "4", "--size", "256"])
        .status()
        .unwrap();
    assert!(status.success());
    let logs = common::temp_dir("census_logs");
    let mut per_run = Vec::new();
    for steps in [1, 2] {
        let run = common::temp_dir(&format!("census_run_{steps}"));
        let args = [
            "-v",
            "train",
            "--data",
            data.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--device",
            "wgpu",
            "--steps",
            &steps.to_string(),
            "--batch",
            "3072",
            "--patches",
            "0",
            "--occ-every",
            "1000",
            "--force",
        ];
        let (kernels, readbacks) = census(&args, &logs.join(format!("train_{steps}.log")));
        let csv = std::fs::read_to_string(run.join("train_log.csv")).unwrap();
        let samples: usize = csv
            .lines()
            .nth(steps)
            .and_then(|row| row.split(',').nth(6))
            .and_then(|s| s.parse().ok())
            .unwrap();
        assert!(samples >= 65536, "step {steps}: only {samples} samples");
        per_run.push((run, kernels, samples, readbacks));
    }
    let step = total(&per_run[1].1) as i64 - total(&per_run[0].1) as i64;
    let step_readbacks = per_run[1].3 as i64 - per_run[0].3 as i64;
    let frames = common::temp_dir("census_frames");
    let (render, render_readbacks) = census(
        &[
            "-v",
            "render",
            "--run",
            per_run[1].0.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--split",
            "train",
            "--out",
            frames.to_str().unwrap(),
            "--device",
            "wgpu",
        ],
        &logs.join("render.log"),
    );
    let n_frames = std::fs::read_dir(&frames)
        .unwrap()
        .filter(|e| {
            let name = e.as_ref().unwrap().file_name();
            let name = name.to_string_lossy();
            name.starts_with("frame_") && name.ends_with(".png")
        })
        .count();
    assert!(n_frames > 0);
    println!(
        "kernel census: a training step of {} samples launches {step} kernels and reads \
         the GPU back {step_readbacks} times; a 256 px frame {} kernels ({} frames, {} in \
         all) and {render_readbacks} readbacks in all",
        per_run[1].2,
        total(&render) / n_frames,
        n_frames,
        total(&render)
    );
    // A step's kernels by name: the two-step run's count less the one-step run's.
    let mut biggest: Vec<(&String, i64)> = per_run[1]
        .1
        .iter()
        .map(|(name, &n)| {
            (
                name,
                n as i64 - *per_run[0].1.get(name).unwrap_or(&0) as i64,
            )
        })
        .filter(|&(_, n)| n != 0)
        .collect();
    biggest.sort_by_key(|&(_, n)| std::cmp::Reverse(n));
    for (name, n) in biggest.iter().take(16) {
        println!("  {n:6} x {name}");
    }
    assert!(total(&per_run[0].1) > 0, "the profiling log is empty");
    // The composed ops made a step 1820 kernels; with the device kernels it is 187
    // (docs/results.md, "Devices"). A step of 200 or more means a device op fell back to
    // composed ops, or a change added launches the census should be shown.
    assert!(step < 200, "a training step launches {step} kernels");
    assert_eq!(step_readbacks, 0, "a training step waits on the GPU");
    // One a frame, and one to check the loaded checkpoint's parameters are finite.
    assert_eq!(
        render_readbacks,
        n_frames + 1,
        "readbacks of {n_frames} frames"
    );
    for (what, kernels) in [("training", &per_run[1].1), ("render", &render)] {
        let found = serial(kernels);
        assert!(found.is_empty(), "{what} ran serial kernels: {found:?}");
    }
}
