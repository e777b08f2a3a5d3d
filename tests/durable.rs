//! A run is never lost: an `--out` holding a run is refused (and `--force` starts over), a
//! signal ends a run with a checkpoint and a complete log that `--resume` continues, a
//! damaged newest checkpoint falls back to the previous one, weights that are not finite
//! are refused by name, another dataset is refused, `--resume --steps` extends a
//! finished run, and paths that are not UTF-8 round-trip.

mod common;

use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use talkin::avatar::Avatar;
use talkin::avatar::checkpoint::{self, Checkpoint, MANIFEST_FILE, MODEL_FILE};
use talkin::data::dataset::Dataset;
use talkin::grids::SamplerKind;
use talkin::train::{Budget, LOG_FILE, TrainOptions, Trainer, schedule, train};

fn talkin(args: &[&OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(args)
        .output()
        .unwrap()
}

/// `talkin train` on a tiny scene: 256 rays, no perceptual term, a 32-cell grid.
fn train_args(data: &Path, out: &Path, extra: &[&str]) -> Vec<OsString> {
    let mut args: Vec<OsString> = vec!["train".into(), "--data".into(), data.into()];
    args.extend(["--out".into(), out.into()]);
    for a in common::cli::TINY_TRAIN_FLAGS.iter().chain(extra) {
        args.push(a.into());
    }
    args
}

fn run_cli(args: &[OsString]) -> (Option<i32>, String, String) {
    let args: Vec<&OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    let out = talkin(&args);
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The steps of the log's rows, checking that every row has every column.
fn log_steps(run: &Path) -> Vec<usize> {
    let text = std::fs::read_to_string(run.join(LOG_FILE)).unwrap();
    let mut lines = text.lines();
    let columns = lines.next().unwrap().split(',').count();
    lines
        .map(|l| {
            assert_eq!(l.split(',').count(), columns, "{l}");
            l.split(',').next().unwrap().parse().unwrap()
        })
        .collect()
}

fn steps_of_checkpoints(run: &Path) -> Vec<usize> {
    checkpoint::step_dirs(run).iter().map(|(s, _)| *s).collect()
}

fn scene(name: &str, seed: u64) -> Dataset {
    common::synthetic_scene(name, 1, 48, seed)
}

fn small_opts(steps: usize) -> TrainOptions {
    common::small_train_opts(SamplerKind::Accelerated, steps)
}

/// Flips one byte in the middle of `file`.
fn flip_a_byte(file: &Path) {
    let mut bytes = std::fs::read(file).unwrap();
    let i = bytes.len() / 2;
    bytes[i] ^= 0x5A;
    std::fs::write(file, bytes).unwrap();
}

#[test]
fn an_out_holding_a_run_is_refused_unless_resume_or_force() {
    let dataset = scene("durable_scene_overwrite", 1);
    let base = common::temp_dir("durable_overwrite");
    let run = base.join("run");
    let (code, _, err) = run_cli(&train_args(&dataset.root, &run, &["--steps", "2"]));
    assert_eq!(code, Some(0), "{err}");
    let log = std::fs::read(run.join(LOG_FILE)).unwrap();

    // Again without --resume or --force: refused, nothing touched.
    let (code, _, err) = run_cli(&train_args(&dataset.root, &run, &["--steps", "3"]));
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("already holds a run") && err.contains("--resume") && err.contains("--force"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read(run.join(LOG_FILE)).unwrap(), log);
    assert_eq!(steps_of_checkpoints(&run), [2]);

    // A directory with only a log holds a run too; so does adapt's --out.
    let log_only = base.join("log_only");
    std::fs::create_dir_all(&log_only).unwrap();
    std::fs::write(log_only.join(LOG_FILE), "step\n1\n").unwrap();
    let (code, _, err) = run_cli(&train_args(&dataset.root, &log_only, &["--steps", "1"]));
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("already holds a run"), "{err}");
    let (code, _, err) = run_cli(&[
        "adapt".into(),
        "--run".into(),
        run.clone().into(),
        "--data".into(),
        dataset.root.clone().into(),
        "--subject".into(),
        dataset.subjects[0].name.clone().into(),
        "--out".into(),
        log_only.clone().into(),
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("already holds a run"), "{err}");

    // --force starts over, and says so: a fresh log and only the new run's checkpoint.
    let (code, _, err) = run_cli(&train_args(
        &dataset.root,
        &run,
        &["--steps", "3", "--force"],
    ));
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("--force: starting over"), "{err}");
    assert_eq!(log_steps(&run), [1, 2, 3]);
    assert_eq!(steps_of_checkpoints(&run), [3]);
}

/// SIGTERM during training: the step finishes, a checkpoint is written and the log is
/// flushed up to it, the exit is 143 with a message saying how to resume; `--resume
/// --steps` then continues the log without a gap.
#[cfg(unix)]
#[test]
fn a_signal_ends_the_run_with_a_checkpoint_and_resume_continues() {
    let dataset = scene("durable_scene_signal", 1);
    let base = common::temp_dir("durable_signal");
    let run = base.join("run");
    let mut child = common::cli::start_trainer(&dataset.root, &run, &base.join("stderr.txt"));
    let killed = Command::new("kill")
        .args(["-s", "TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "still running 2 minutes after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let err = std::fs::read_to_string(base.join("stderr.txt")).unwrap();
    assert_eq!(status.code(), Some(143), "{err}");
    assert!(
        err.contains("interrupted by SIGTERM") && err.contains("--resume"),
        "{err}"
    );
    let step = *steps_of_checkpoints(&run).first().unwrap();
    assert!(step >= 1);
    assert_eq!(log_steps(&run), (1..=step).collect::<Vec<_>>());

    let more = (step + 3).to_string();
    let (code, out, err) = run_cli(&[
        "train".into(),
        "--data".into(),
        dataset.root.clone().into(),
        "--out".into(),
        run.clone().into(),
        "--resume".into(),
        "--steps".into(),
        more.clone().into(),
    ]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("trained 3 steps"), "{out}");
    assert_eq!(log_steps(&run), (1..=step + 3).collect::<Vec<_>>());
    // The last two checkpoints are kept (the run checkpoints every 0.3 s).
    let kept = steps_of_checkpoints(&run);
    assert!(
        kept.len() == 2 && kept[0] == step + 3 && kept[1] >= step,
        "{kept:?}"
    );
}

#[test]
fn a_damaged_newest_checkpoint_falls_back_to_the_previous() {
    let dataset = scene("durable_scene_damage", 1);
    let run = common::temp_dir("durable_damage");
    let mut t = Trainer::new(&dataset, &run, &small_opts(6)).unwrap();
    for _ in 0..2 {
        t.step().unwrap();
    }
    t.save().unwrap();
    for _ in 0..2 {
        t.step().unwrap();
    }
    let newest = t.save().unwrap();
    drop(t);
    assert_eq!(steps_of_checkpoints(&run), [4, 2]);

    flip_a_byte(&newest.join(MODEL_FILE));
    let c = Checkpoint::load(&run).unwrap();
    assert!(c.dir.ends_with("step-000002"), "{:?}", c.dir);
    let warning = c.notes.join("\n");
    assert!(
        warning.contains("step-000004")
            && warning.contains(MODEL_FILE)
            && warning.contains("previous checkpoint"),
        "{warning}"
    );
    // Rendering loads the previous one too; resuming continues from it and says so.
    Avatar::load(&run).unwrap();
    let resumed = Trainer::resume(&dataset, &run).unwrap();
    assert_eq!(resumed.steps_taken(), 2);
    let report = resumed.run(&mut |_| {}).unwrap();
    assert!(report.notes.join("\n").contains("step-000004"));
    assert_eq!(report.steps, 6);
    // The damaged one is gone; the new one and the one it resumed from are kept.
    assert_eq!(steps_of_checkpoints(&run), [6, 2]);
    assert_eq!(log_steps(&run), [1, 2, 3, 4, 5, 6]);

    // With every checkpoint damaged: an error naming each.
    for (_, dir) in checkpoint::step_dirs(&run) {
        flip_a_byte(&dir.join(MODEL_FILE));
    }
    let e = Checkpoint::load(&run).err().unwrap().to_string();
    assert!(
        e.contains("no usable checkpoint")
            && e.contains("step-000006")
            && e.contains("step-000002"),
        "{e}"
    );
}

/// Sets every value of the first float parameter to NaN.
struct Poison {
    done: bool,
}

impl ModuleMapper for Poison {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        if self.done {
            return param;
        }
        self.done = true;
        param.map(|t| t.mul_scalar(f32::NAN))
    }
}

#[test]
fn non_finite_weights_are_refused_naming_the_file() {
    let dataset = scene("durable_scene_nan", 1);
    let run = common::temp_dir("durable_nan");
    train(&dataset, &run, &small_opts(2), &mut |_| {}).unwrap();
    let c = Checkpoint::load(&run).unwrap();
    let field = c.field(&Device::flex()).unwrap();
    let bytes = field
        .map(&mut Poison { done: false })
        .into_record()
        .into_bytes()
        .unwrap()
        .to_vec();
    // Written with a matching manifest entry: only the values are wrong.
    let model = c.dir.join(MODEL_FILE);
    std::fs::write(&model, &bytes).unwrap();
    let manifest_file = c.dir.join(MANIFEST_FILE);
    let mut manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest_file).unwrap()).unwrap();
    manifest["files"][MODEL_FILE] = serde_json::json!({
        "bytes": bytes.len(),
        "sha256": checkpoint::sha256_hex(&bytes),
    });
    std::fs::write(&manifest_file, serde_json::to_vec(&manifest).unwrap()).unwrap();

    let e = Avatar::load(&run).err().unwrap().to_string();
    assert!(e.contains("model.bpk") && e.contains("not finite"), "{e}");
    let e = Trainer::resume(&dataset, &run).err().unwrap().to_string();
    assert!(e.contains("model.bpk") && e.contains("not finite"), "{e}");
}

/// Puts `value` into the last element of the `target`-th float tensor (in visiting order).
struct PoisonOne {
    seen: usize,
    target: usize,
    value: f32,
}

impl ModuleMapper for PoisonOne {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        self.seen += 1;
        if self.seen != self.target + 1 {
            return param;
        }
        let value = self.value;
        param.map(|t| {
            let shape = t.shape();
            let device = t.device();
            let mut v = t.try_to_vec_as::<f32>().unwrap();
            *v.last_mut().unwrap() = value;
            Tensor::from_data(TensorData::new(v, shape), &device)
        })
    }
}

/// The module paths of `field`'s float tensors, in visiting order.
struct Paths {
    path: Vec<String>,
    all: Vec<String>,
}

impl burn::module::ModuleVisitor for Paths {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_string());
    }
    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }
    fn visit_float<const D: usize>(&mut self, _param: &Param<Tensor<D>>) {
        self.all.push(self.path.join("."));
    }
}

#[test]
fn the_first_non_finite_tensor_is_named() {
    let dataset = scene("durable_scene_inf", 1);
    let run = common::temp_dir("durable_inf");
    train(&dataset, &run, &small_opts(2), &mut |_| {}).unwrap();
    let field = Checkpoint::load(&run)
        .unwrap()
        .field(&Device::flex())
        .unwrap();
    assert_eq!(checkpoint::first_non_finite(&field), None);
    let mut paths = Paths {
        path: Vec::new(),
        all: Vec::new(),
    };
    field.visit(&mut paths);
    assert!(paths.all.len() > 4);
    for (target, value) in [
        (3, f32::INFINITY),
        (paths.all.len() - 1, f32::NAN),
        (0, f32::NEG_INFINITY),
    ] {
        let poisoned = field.clone().map(&mut PoisonOne {
            seen: 0,
            target,
            value,
        });
        assert_eq!(
            checkpoint::first_non_finite(&poisoned).as_deref(),
            Some(paths.all[target].as_str()),
            "{value} in tensor {target}"
        );
    }
}

#[test]
fn resume_refuses_another_dataset() {
    let trained_on = scene("durable_scene_a", 1);
    let other = scene("durable_scene_b", 2);
    let run = common::temp_dir("durable_other_dataset");
    train(&trained_on, &run, &small_opts(2), &mut |_| {}).unwrap();
    let e = Trainer::resume(&other, &run).err().unwrap().to_string();
    assert!(
        e.contains(&trained_on.root.display().to_string())
            && e.contains(&other.root.display().to_string())
            && e.contains("--force"),
        "{e}"
    );
    assert!(Trainer::resume(&trained_on, &run).is_ok());
}

/// `set_budget` after a finished run trains the difference at the schedule's end (the
/// virtual step never goes back); after an unfinished one it spreads the schedule's
/// remainder over the new budget, ending at the paper's last iteration.
#[test]
fn resume_with_a_new_budget_extends_the_run_and_keeps_the_schedule() {
    let dataset = scene("durable_scene_extend", 1);
    let run = common::temp_dir("durable_extend");
    let opts = small_opts(4);
    train(&dataset, &run, &opts, &mut |_| {}).unwrap();
    let mut t = Trainer::resume(&dataset, &run).unwrap();
    assert!(t.done());
    assert_eq!(t.field_step(), schedule::PAPER_ITERATIONS);
    t.set_budget(Budget::Steps(4)).unwrap();
    assert!(t.done(), "the same budget changes nothing");
    t.set_budget(Budget::Steps(8)).unwrap();
    assert!(!t.done());
    assert_eq!(t.field_step(), schedule::PAPER_ITERATIONS);
    let report = t.run(&mut |_| {}).unwrap();
    let end_lr = schedule::learning_rate(opts.initial_lr(), schedule::PAPER_ITERATIONS);
    assert_eq!(report.logs.len(), 4);
    for l in &report.logs {
        assert!((l.lr - end_lr).abs() < 1e-12, "{l:?}");
    }
    assert_eq!(log_steps(&run), (1..=8).collect::<Vec<_>>());
    // The new budget is the run's from now on: a plain resume has nothing left to do.
    assert!(Trainer::resume(&dataset, &run).unwrap().done());

    // Unfinished: 4 of 8 steps, then a budget of 12 from the checkpoint.
    let run = common::temp_dir("durable_extend_unfinished");
    let mut t = Trainer::new(&dataset, &run, &small_opts(8)).unwrap();
    for _ in 0..4 {
        t.step().unwrap();
    }
    t.save().unwrap();
    drop(t);
    let mut t = Trainer::resume(&dataset, &run).unwrap();
    let at = t.field_step();
    assert_eq!(at, schedule::PAPER_ITERATIONS / 2);
    t.set_budget(Budget::Steps(12)).unwrap();
    assert_eq!(t.field_step(), at, "no jump at the change");
    let mut virtual_steps = Vec::new();
    while !t.done() {
        t.step().unwrap();
        virtual_steps.push(t.field_step());
    }
    assert_eq!(virtual_steps.len(), 8);
    assert!(
        virtual_steps.windows(2).all(|w| w[0] < w[1]),
        "{virtual_steps:?}"
    );
    assert_eq!(*virtual_steps.last().unwrap(), schedule::PAPER_ITERATIONS);
    assert_eq!(virtual_steps[3], at + (schedule::PAPER_ITERATIONS - at) / 2);
}

/// A dataset and an LPIPS directory whose paths are not UTF-8: the run trains, saves,
/// records both so that they round-trip, and resumes.
#[cfg(unix)]
#[test]
fn paths_that_are_not_utf8_round_trip() {
    use std::os::unix::ffi::OsStrExt;
    let base = common::temp_dir("durable_non_utf8");
    let data: PathBuf = base.join(OsStr::from_bytes(b"data-\xff"));
    let cfg = talkin::synth::SynthConfig {
        identities: 1,
        frames: 4,
        size: 48,
        seed: 1,
        motion: None,
        capture: None,
        framing: None,
    };
    talkin::synth::generate(&cfg, &data, &mut |_, _| {}).unwrap();
    let dataset = Dataset::load(&data).unwrap();
    let lpips = base.join(OsStr::from_bytes(b"lpips-\xfe"));
    let run = base.join("run");
    let opts = TrainOptions {
        patches: 1,
        batch_rays: 64,
        perceptual: Some(lpips.clone()),
        ..small_opts(2)
    };
    let report = train(&dataset, &run, &opts, &mut |_| {}).unwrap();
    assert!(report.perceptual_note.is_some());
    let resumed = Trainer::resume(&dataset, &run).unwrap();
    assert_eq!(
        resumed.options().perceptual.as_deref(),
        Some(lpips.as_path())
    );
    assert_eq!(resumed.steps_taken(), 2);
    let state: serde_json::Value = serde_json::from_slice(
        &std::fs::read(
            checkpoint::latest_dir(&run)
                .unwrap()
                .join(checkpoint::STATE_FILE),
        )
        .unwrap(),
    )
    .unwrap();
    assert!(state["data"]["unix_bytes"].is_array(), "{}", state["data"]);
}
