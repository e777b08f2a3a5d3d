//! The faults a long run meets beyond a signal or a damaged file: a second writer on the
//! same run (refused while the first lives, free once it is killed).

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::cli::{p, stderr, talkin};
use talkin::avatar::checkpoint::{self, CHECKPOINT_DIR, LATEST_FILE};
use talkin::render::avatar::Avatar;
use talkin::train::LOG_FILE;

/// `talkin train` on a tiny scene: 256 rays, no perceptual term, a 32-cell grid.
fn train_args<'a>(data: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["train", "--data", p(data), "--out", p(out)];
    args.extend([
        "--batch",
        "256",
        "--patches",
        "0",
        "--occ-every",
        "4",
        "--grid-resolution",
        "32",
        "--seed",
        "3",
    ]);
    args.extend(extra);
    args
}

fn steps_of_checkpoints(run: &Path) -> Vec<usize> {
    checkpoint::step_dirs(run).iter().map(|(s, _)| *s).collect()
}

/// Starts a long `talkin train` into `run` and waits for its first checkpoint.
fn start_trainer(data: &Path, run: &Path, stderr_file: &Path) -> Child {
    let mut child = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(train_args(
            data,
            run,
            &["--steps", "100000", "--checkpoint-every", "0.3"],
        ))
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(stderr_file).unwrap())
        .spawn()
        .unwrap();
    let latest = run.join(CHECKPOINT_DIR).join(LATEST_FILE);
    let start = Instant::now();
    while !latest.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no checkpoint after 2 minutes"
        );
        if child.try_wait().unwrap().is_some() {
            panic!(
                "the trainer ended early: {}",
                std::fs::read_to_string(stderr_file).unwrap()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child
}

#[cfg(unix)]
#[test]
fn a_second_writer_is_refused_and_a_killed_one_leaves_no_lock() {
    let dataset = common::synthetic_scene("faults_scene_lock", 1, 48, 1);
    let base = common::temp_dir("faults_lock");
    let run = base.join("run");
    let mut first = start_trainer(&dataset.root, &run, &base.join("stderr.txt"));
    let pid = first.id();

    // Every writer is refused, naming the run and the holder, and touches nothing.
    let resume = train_args(&dataset.root, &run, &["--resume"]);
    let force = train_args(&dataset.root, &run, &["--steps", "2", "--force"]);
    let adapt_base = base.join("other");
    let adapt = [
        "adapt",
        "--run",
        p(&adapt_base),
        "--data",
        p(&dataset.root),
        "--subject",
        &dataset.subjects[0].name,
        "--out",
        p(&run),
    ];
    for args in [&resume[..], &force[..], &adapt[..]] {
        let out = talkin(args);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains(&format!("{} is being written by another", run.display()))
                && err.contains(&format!("pid {pid}")),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            !steps_of_checkpoints(&run).is_empty(),
            "{args:?} cleared it"
        );
        assert!(run.join(LOG_FILE).is_file());
    }
    // A reader takes no lock: the newest verified checkpoint loads while the run writes.
    Avatar::load(&run).unwrap();

    // SIGKILL: no handler runs, the kernel drops the lock, and the next writer starts.
    first.kill().unwrap();
    first.wait().unwrap();
    let step = steps_of_checkpoints(&run)[0];
    let more = (step + 2).to_string();
    let out = talkin(&train_args(
        &dataset.root,
        &run,
        &["--resume", "--steps", &more],
    ));
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(steps_of_checkpoints(&run)[0], step + 2);
}
