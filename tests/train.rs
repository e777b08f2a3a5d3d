//! Training on a tiny synthetic scene: both samplers learn, the log and checkpoint are
//! complete, a checkpoint renders without the dataset, a resumed run is bit-identical to
//! an uninterrupted one, and bad input gives named errors.

mod common;

use std::path::Path;
use std::process::Command;

use talkin::avatar::Avatar;
use talkin::avatar::checkpoint::{self, CHECKPOINT_DIR, LATEST_FILE};
use talkin::data::atomic::write_atomic;
use talkin::data::dataset::Dataset;
use talkin::grids::SamplerKind;
use talkin::render::avatar::RenderFrame;
use talkin::train::{LOG_FILE, StepLog, TrainOptions, train};

/// Steps of each smoke run. The dense sampler fills the whole box at the start, so its
/// opacity saturates and the silhouette term leaves it at the first 15 steps' loss; 30
/// show progress.
const STEPS: usize = 30;

fn mean(logs: &[StepLog], f: impl Fn(&StepLog) -> f32) -> f32 {
    logs.iter().map(f).sum::<f32>() / logs.len() as f32
}

fn no_temp_files(dir: &Path) -> bool {
    std::fs::read_dir(dir)
        .unwrap()
        .all(|e| !e.unwrap().file_name().to_string_lossy().ends_with(".tmp"))
}

fn scene(name: &str) -> Dataset {
    common::synthetic_scene(name, 1, 48, 1)
}

fn small_opts(sampler: SamplerKind, steps: usize) -> TrainOptions {
    common::small_train_opts(sampler, steps)
}

fn check_run(dataset: &Dataset, sampler: SamplerKind) {
    let out = common::temp_dir(&format!("train_run_{}", sampler.name()));
    let mut seen = 0;
    let report = train(dataset, &out, &small_opts(sampler, STEPS), &mut |log| {
        seen += 1;
        assert_eq!(log.step, seen);
    })
    .unwrap();
    let logs = &report.logs;
    assert_eq!(logs.len(), STEPS);
    for l in logs {
        assert!(l.loss.is_finite() && l.psnr.is_finite(), "{l:?}");
        assert_eq!(l.rays, 256);
        assert!(l.samples > 0 && l.rays_per_s > 0.0, "{l:?}");
        // The sampler's share of the step: timed, and a part of it.
        let step_s = l.rays as f64 / l.rays_per_s;
        assert!(l.sampling_s > 0.0 && l.sampling_s < step_s, "{l:?}");
        // Skinning's candidate bones: all 22 body bones for a dense sample, the few of the
        // capsules holding it for an accelerated one.
        match sampler {
            SamplerKind::Dense => assert_eq!(l.bones_per_sample, 22.0, "{l:?}"),
            SamplerKind::Accelerated => {
                assert!(
                    l.bones_per_sample >= 1.0 && l.bones_per_sample < 6.0,
                    "{l:?}"
                )
            }
        }
    }
    assert_eq!(logs[STEPS - 1].progress, 1.0);
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
    // The occupancy grid is updated every `occ_every` (4) steps, accelerated only; an
    // update can occupy at most the support (the capsule marks), never the whole box.
    let every = small_opts(sampler, STEPS).occ_every as usize;
    for l in logs {
        let updated = sampler == SamplerKind::Accelerated && l.step >= every;
        assert_eq!(l.grid_occupied < 1.0, updated, "{l:?}");
    }

    // The log: a header and one row per step.
    let csv = std::fs::read_to_string(out.join(LOG_FILE)).unwrap();
    assert!(csv.starts_with("step,seconds,loss,"), "{csv}");
    assert!(csv.lines().all(|l| l.split(',').count() == 13), "{csv}");
    assert_eq!(csv.lines().count(), STEPS + 1);

    // The checkpoint: LATEST names a complete directory, nothing temporary is left.
    let root = out.join(CHECKPOINT_DIR);
    let dir = checkpoint::latest_dir(&out).unwrap();
    assert_eq!(dir, report.checkpoint);
    for f in [
        checkpoint::MODEL_FILE,
        checkpoint::OPTIMIZER_FILE,
        checkpoint::CONFIG_FILE,
        checkpoint::SUBJECTS_FILE,
        checkpoint::STATE_FILE,
        "grid-0.safetensors",
    ] {
        let len = std::fs::metadata(dir.join(f)).unwrap().len();
        assert!(len > 0, "{f} is empty");
    }
    assert!(no_temp_files(&root));

    // It renders a frame on its own (no dataset), deterministically and finitely.
    let avatar = Avatar::load(&out).unwrap();
    assert_eq!(avatar.sampler, sampler);
    let f = &dataset.frames[0];
    let a = avatar.render(0, &f.params, &f.camera, None).unwrap();
    let b = avatar.render(0, &f.params, &f.camera, None).unwrap();
    assert_eq!(a.rgb, b.rgb);
    assert_eq!(a.rgb.len(), (3 * f.camera.width * f.camera.height) as usize);
    assert!(a.rgb.iter().chain(&a.opacity).all(|v| v.is_finite()));
    assert!(a.samples > 0);
}

#[test]
fn trains_with_both_samplers_and_renders_from_the_checkpoint() {
    let dataset = scene("train_scene");
    check_run(&dataset, SamplerKind::Accelerated);
    check_run(&dataset, SamplerKind::Dense);
}

#[test]
fn perceptual_patches_fall_back_to_ssim_and_say_so() {
    let dataset = scene("train_scene_perceptual");
    let out = common::temp_dir("train_run_perceptual");
    let opts = TrainOptions {
        patches: 2,
        batch_rays: 64,
        perceptual: Some(out.join("no_lpips_here")),
        ..small_opts(SamplerKind::Accelerated, 3)
    };
    let report = train(&dataset, &out, &opts, &mut |_| {}).unwrap();
    assert!(report.perceptual_note.is_some());
    for l in &report.logs {
        // 64 random rays + two 32x32 patches; the loss holds 0.2 MSE + the perceptual term.
        assert_eq!(l.rays, 64 + 2 * 32 * 32);
        assert!(l.loss.is_finite() && l.loss > 0.2 * l.mse, "{l:?}");
    }
}

#[test]
fn missing_and_damaged_checkpoints_are_named() {
    let dataset = scene("train_scene_damage");
    let run = common::temp_dir("train_damage");
    let e = Avatar::load(&run).err().unwrap().to_string();
    assert!(e.contains("no checkpoint"), "{e}");
    train(
        &dataset,
        &run,
        &small_opts(SamplerKind::Accelerated, 2),
        &mut |_| {},
    )
    .unwrap();
    let dir = checkpoint::latest_dir(&run).unwrap();
    // A truncated grid and a LATEST escaping the directory: errors naming the file.
    let grid = dir.join("grid-0.safetensors");
    let bytes = std::fs::read(&grid).unwrap();
    std::fs::write(&grid, &bytes[..bytes.len() / 2]).unwrap();
    let e = Avatar::load(&run).err().unwrap().to_string();
    assert!(e.contains("grid-0.safetensors"), "{e}");
    std::fs::write(&grid, &bytes).unwrap();
    let latest = run.join(CHECKPOINT_DIR).join(LATEST_FILE);
    std::fs::write(&latest, "../../etc").unwrap();
    let e = Avatar::load(&run).err().unwrap().to_string();
    assert!(e.contains("LATEST"), "{e}");
}

#[test]
fn atomic_write_replaces_whole_files_and_leaves_no_temp() {
    let dir = common::temp_dir("train_atomic");
    let file = dir.join("x.json");
    write_atomic(&file, b"first").unwrap();
    write_atomic(&file, b"second, longer").unwrap();
    assert_eq!(std::fs::read(&file).unwrap(), b"second, longer");
    assert!(no_temp_files(&dir));
    // A target that cannot be written (a directory in the way) fails and leaves neither
    // the target nor a temp file changed.
    let blocked = dir.join("blocked");
    std::fs::create_dir_all(blocked.join("inner")).unwrap();
    assert!(write_atomic(&blocked, b"data").is_err());
    assert!(blocked.is_dir());
    assert!(no_temp_files(&dir));
}

#[test]
fn cli_reports_a_missing_dataset_and_a_missing_checkpoint() {
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["train", "--data", "/nonexistent"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("/nonexistent"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
