//! Training on a tiny synthetic scene with both samplers: finite losses that go down, a
//! per-step log, and an atomic checkpoint whose config loads back. And the CLI's error on
//! a missing dataset.

mod common;

use std::path::Path;
use std::process::Command;

use talkin::engine::dataset::Dataset;
use talkin::engine::synth::{SynthConfig, generate};
use talkin::engine::train::{
    CONFIG_FILE, LOG_FILE, MODEL_FILE, STATE_FILE, StepLog, TrainOptions, load_config, load_state,
    train, write_atomic,
};
use talkin::grids::SamplerKind;

const STEPS: usize = 15;

fn mean(logs: &[StepLog], f: impl Fn(&StepLog) -> f32) -> f32 {
    logs.iter().map(f).sum::<f32>() / logs.len() as f32
}

fn no_temp_files(dir: &Path) -> bool {
    std::fs::read_dir(dir)
        .unwrap()
        .all(|e| !e.unwrap().file_name().to_string_lossy().ends_with(".tmp"))
}

fn check_run(dataset: &Dataset, sampler: SamplerKind) {
    let out = common::temp_dir(&format!("train_run_{}", sampler.name()));
    let opts = TrainOptions {
        sampler,
        steps: STEPS,
        seed: 3,
        batch_rays: 256,
        lr: 5e-3,
        occ_every: 4,
        grid_resolution: 32,
        ..TrainOptions::default()
    };
    let mut seen = 0;
    let report = train(dataset, &out, &opts, &mut |log, total| {
        seen += 1;
        assert_eq!(log.step, seen);
        assert_eq!(total, STEPS);
    })
    .unwrap();
    let logs = &report.logs;
    assert_eq!(logs.len(), STEPS);
    for l in logs {
        assert!(l.loss.is_finite() && l.psnr.is_finite(), "{l:?}");
        assert_eq!(l.rays, 256);
        assert!(l.samples > 0 && l.rays_per_s > 0.0, "{l:?}");
    }
    let (first, last) = (&logs[..4], &logs[STEPS - 4..]);
    assert!(
        mean(last, |l| l.loss) < mean(first, |l| l.loss)
            || mean(last, |l| l.psnr) > mean(first, |l| l.psnr),
        "{}: no progress: {logs:#?}",
        sampler.name()
    );
    if sampler == SamplerKind::Dense {
        // 128 samples on every ray that meets the box: most of the batch.
        assert!(logs[0].samples >= 128 * 100, "{:?}", logs[0]);
    }

    // The log: a header and one row per step.
    let csv = std::fs::read_to_string(out.join(LOG_FILE)).unwrap();
    assert!(csv.starts_with("step,loss,"), "{csv}");
    assert_eq!(csv.lines().count(), STEPS + 1);

    // The checkpoint: every file there, no temp file left, config and state load back.
    let dir = &report.checkpoint.dir;
    for f in [MODEL_FILE, CONFIG_FILE, STATE_FILE] {
        let len = std::fs::metadata(dir.join(f)).unwrap().len();
        assert!(len > 0, "{f} is empty");
    }
    assert!(no_temp_files(dir));
    let config = load_config(dir).unwrap();
    assert_eq!(config.n_identities, 1);
    assert!(
        config
            .aabb_min
            .iter()
            .zip(config.aabb_max)
            .all(|(a, b)| *a < b)
    );
    let state = load_state(dir).unwrap();
    assert_eq!(state.step, STEPS);
    assert_eq!(state.sampler, sampler.name());
}

#[test]
fn trains_with_both_samplers_and_checkpoints_atomically() {
    let data = common::temp_dir("train_scene");
    let cfg = SynthConfig {
        identities: 1,
        frames: 4,
        size: 48,
        seed: 1,
        motion: None,
    };
    generate(&cfg, &data, &mut |_, _| {}).unwrap();
    let dataset = Dataset::load(&data).unwrap();
    check_run(&dataset, SamplerKind::Accelerated);
    check_run(&dataset, SamplerKind::Dense);

    // The perceptual term on a 32x32 patch; without LPIPS weights it falls back to SSIM
    // and says so.
    let out = common::temp_dir("train_run_perceptual");
    let opts = TrainOptions {
        steps: 3,
        seed: 5,
        batch_rays: 64,
        grid_resolution: 32,
        perceptual: Some(out.join("no_lpips_here")),
        ..TrainOptions::default()
    };
    let report = train(&dataset, &out, &opts, &mut |_, _| {}).unwrap();
    assert!(report.perceptual_note.is_some());
    for l in &report.logs {
        // 64 random rays + the 32x32 patch; the loss holds 0.2 MSE + the perceptual term.
        assert_eq!(l.rays, 64 + 32 * 32);
        assert!(l.loss.is_finite() && l.loss > 0.2 * l.mse, "{l:?}");
    }
}

#[test]
fn atomic_write_replaces_whole_files_and_leaves_no_temp() {
    let dir = common::temp_dir("train_atomic");
    let file = dir.join("x.json");
    write_atomic(&file, b"first").unwrap();
    write_atomic(&file, b"second, longer").unwrap();
    assert_eq!(std::fs::read(&file).unwrap(), b"second, longer");
    assert!(no_temp_files(&dir));
    // A target that cannot be written (a directory in the way) fails with the file's name
    // and leaves neither the target nor a temp file changed.
    let blocked = dir.join("blocked");
    std::fs::create_dir_all(blocked.join("inner")).unwrap();
    let err = write_atomic(&blocked, b"data").unwrap_err();
    assert!(err.to_string().contains("blocked"), "{err}");
    assert!(blocked.is_dir());
    assert!(no_temp_files(&dir));
}

#[test]
fn cli_reports_a_missing_dataset() {
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["train", "--data", "/nonexistent"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("/nonexistent"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
