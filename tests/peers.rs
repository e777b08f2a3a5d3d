//! Data-parallel training: two peers as two processes under Open MPI's `mpirun` on
//! loopback, against one process with the same batch; a peer killed or hung mid-run; a
//! peer on another dataset; launches that cannot run. Needs `mpirun` (Open MPI; `.ci/run`
//! installs it).

#![cfg(all(target_os = "linux", feature = "mpi"))]

mod common;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::cli::{TINY_TRAIN_FLAGS, p, stderr, talkin};
use talkin::avatar::checkpoint::{CHECKPOINT_DIR, LATEST_FILE};
use talkin::train::LOG_FILE;

const BIN: &str = env!("CARGO_BIN_EXE_talkin");

/// `mpirun` for the tests: as root where CI runs, more processes than cores allowed,
/// `marker` in every peer's environment (to find a peer's pid).
fn mpirun(marker: &str) -> Command {
    let mut c = Command::new("mpirun");
    c.env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .args([
            "--oversubscribe",
            "-x",
            &format!("TALKIN_TEST_PEERS={marker}"),
        ]);
    c
}

/// `talkin -q train` on `data` into `out` with the tiny flags and `extra`.
fn train_args<'a>(data: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![BIN, "-q", "train", "--data", p(data), "--out", p(out)];
    args.extend(TINY_TRAIN_FLAGS);
    args.extend(extra);
    args
}

fn both(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The loss and MSE column of a run's log, by step.
fn losses(run: &Path) -> Vec<(usize, f64, f64)> {
    let text = std::fs::read_to_string(run.join(LOG_FILE)).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].parse().unwrap(),
                f[2].parse().unwrap(),
                f[3].parse().unwrap(),
            )
        })
        .collect()
}

/// The pid of the peer of rank `rank` among the processes carrying `marker`.
fn peer_pid(marker: &str, rank: usize) -> u32 {
    let want_marker = format!("TALKIN_TEST_PEERS={marker}");
    let want_rank = format!("OMPI_COMM_WORLD_RANK={rank}");
    let start = Instant::now();
    loop {
        for entry in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            let Ok(env) = std::fs::read(entry.path().join("environ")) else {
                continue;
            };
            let vars: Vec<&[u8]> = env.split(|&b| b == 0).collect();
            let has = |s: &str| vars.contains(&s.as_bytes());
            if has(&want_marker) && has(&want_rank) {
                return pid;
            }
        }
        assert!(start.elapsed() < Duration::from_secs(60), "no peer {rank}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Waits for `child` at most `within`; its output, and how long it took.
fn wait_within(child: Child, within: Duration) -> (Output, Duration) {
    let start = Instant::now();
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || tx.send(child.wait_with_output().unwrap()));
    match rx.recv_timeout(within) {
        Ok(out) => (out, start.elapsed()),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("mpirun still running after {within:?}");
        }
    }
}

fn wait_for_checkpoint(run: &Path) {
    let latest = run.join(CHECKPOINT_DIR).join(LATEST_FILE);
    let start = Instant::now();
    while !latest.exists() {
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoint");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn two_peers_on_loopback_train_the_single_process_run_and_only_peer_0_writes() {
    let data = common::synthetic_scene("peers_scene_same", 1, 48, 1).root;
    let base = common::temp_dir("peers_same");
    let (one, two, elsewhere) = (base.join("one"), base.join("two"), base.join("peer1"));
    // One process: 20 steps, then resumed to 40.
    let out = talkin(&train_args(&data, &one, &["--steps", "20"])[1..]);
    assert!(out.status.success(), "{}", stderr(&out));
    fn resume<'a>(data: &'a Path, run: &'a Path) -> Vec<&'a str> {
        let args = ["-q", "train", "--data", p(data), "--out", p(run)];
        [&[BIN][..], &args, &["--resume", "--steps", "40"]].concat()
    }
    let out = talkin(&resume(&data, &one)[1..]);
    assert!(out.status.success(), "{}", stderr(&out));
    // Two peers for the first 20 steps; peer 1 is told another --out, and must not even
    // create it.
    let mut args = vec!["-n", "1"];
    args.extend(train_args(&data, &two, &["--steps", "20", "--nodes", "2"]));
    args.extend([":", "-n", "1"]);
    args.extend(train_args(
        &data,
        &elsewhere,
        &["--steps", "20", "--nodes", "2"],
    ));
    let out = mpirun("same").args(&args).output().unwrap();
    assert!(out.status.success(), "{}", both(&out));
    let text = both(&out);
    assert!(text.contains("peer 0 of 2: 20 steps exchanged"), "{text}");
    assert!(text.contains("MB all-reduced a step"), "{text}");
    assert!(!elsewhere.exists(), "peer 1 wrote into its --out");
    assert!(two.join(CHECKPOINT_DIR).join("step-000020").is_dir());
    // Three peers resume it to 40: the batch does not depend on the peers, so another
    // count re-partitions the same run.
    let out = mpirun("same3")
        .args(["-n", "3"])
        .args(resume(&data, &two))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", both(&out));
    // The same steps, each loss within 1e-4 of the single process's (the float sums'
    // order differs; measured below 2e-6 on this scene).
    let (a, b) = (losses(&one), losses(&two));
    assert_eq!(a.len(), 40);
    assert_eq!(a.len(), b.len());
    for ((sa, la, ma), (sb, lb, mb)) in a.iter().zip(&b) {
        assert_eq!(sa, sb);
        assert!(
            (la - lb).abs() <= 1e-4 * la.abs(),
            "step {sa}: loss {la} vs {lb}"
        );
        assert!(
            (ma - mb).abs() <= 1e-4 * ma.abs(),
            "step {sa}: mse {ma} vs {mb}"
        );
    }
}

#[test]
fn a_killed_peer_stops_the_other_and_both_resume_the_run_exactly() {
    let data = common::synthetic_scene("peers_scene_kill", 1, 48, 1).root;
    let base = common::temp_dir("peers_kill");
    let (run, reference) = (base.join("run"), base.join("reference"));
    let flags = ["--steps", "150", "--nodes", "2"];
    let child = mpirun("kill")
        .args(["-n", "2"])
        .args(train_args(
            &data,
            &run,
            &[&flags[..], &["--checkpoint-every", "0.5"]].concat(),
        ))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&run);
    let victim = peer_pid("kill", 1);
    let killed = Instant::now();
    assert!(
        Command::new("kill")
            .args(["-9", &victim.to_string()])
            .status()
            .unwrap()
            .success()
    );
    let (out, _) = wait_within(child, Duration::from_secs(60));
    let took = killed.elapsed();
    assert!(!out.status.success());
    let text = both(&out);
    assert!(
        text.contains("rank 1"),
        "the lost peer is not named: {text}"
    );
    assert!(took < Duration::from_secs(60), "{took:?}");
    // Both peers again, --resume: the run continues from its last checkpoint and ends
    // as the same run never interrupted.
    let out = mpirun("kill2")
        .args([
            "-n",
            "2",
            BIN,
            "-q",
            "train",
            "--data",
            p(&data),
            "--out",
            p(&run),
            "--resume",
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", both(&out));
    let out = mpirun("kill3")
        .args(["-n", "2"])
        .args(train_args(&data, &reference, &flags))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", both(&out));
    assert_eq!(losses(&run), losses(&reference));
}

#[test]
fn a_hung_peer_stops_the_other_within_its_timeout_naming_it() {
    let data = common::synthetic_scene("peers_scene_hang", 1, 48, 1).root;
    let run = common::temp_dir("peers_hang").join("run");
    let child = mpirun("hang")
        .args(["-n", "2"])
        .args(train_args(
            &data,
            &run,
            &[
                "--steps",
                "100000",
                "--checkpoint-every",
                "0.5",
                "--peer-timeout",
                "3",
            ],
        ))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&run);
    let victim = peer_pid("hang", 1);
    let stopped = Instant::now();
    assert!(
        Command::new("kill")
            .args(["-STOP", &victim.to_string()])
            .status()
            .unwrap()
            .success()
    );
    let (out, _) = wait_within(child, Duration::from_secs(60));
    let took = stopped.elapsed();
    let _ = Command::new("kill")
        .args(["-9", &victim.to_string()])
        .status();
    assert_eq!(out.status.code(), Some(1), "{}", both(&out));
    let text = both(&out);
    assert!(text.contains("peer 0 of 2 waited 3 s"), "{text}");
    assert!(text.contains("peer 1 died or hangs"), "{text}");
    assert!(took < Duration::from_secs(30), "{took:?}");
}

#[test]
fn a_peer_on_another_dataset_is_refused_before_the_first_step() {
    let data = common::synthetic_scene("peers_scene_a", 1, 48, 1).root;
    let other = common::synthetic_scene("peers_scene_b", 1, 48, 2).root;
    let run = common::temp_dir("peers_other").join("run");
    let mut args = vec!["-n", "1"];
    args.extend(train_args(&data, &run, &["--steps", "5"]));
    args.extend([":", "-n", "1"]);
    args.extend(train_args(&other, &run, &["--steps", "5"]));
    let out = mpirun("other").args(&args).output().unwrap();
    assert!(!out.status.success());
    let text = both(&out);
    assert!(
        text.contains("refused before the first step: peer 1 differs from peer 0 in its dataset"),
        "{text}"
    );
    assert_eq!(losses(&run).len(), 0, "a step was logged");
    assert!(!run.join(CHECKPOINT_DIR).exists());
}

#[test]
fn launches_that_cannot_run_exit_1_naming_the_flag() {
    let data = common::synthetic_scene("peers_scene_bad", 1, 48, 1).root;
    let base = common::temp_dir("peers_bad");
    let run = base.join("run");
    let alone = |extra: &[&str]| {
        let args = train_args(&data, &run, &[&["--steps", "2"], extra].concat());
        talkin(&args[1..])
    };
    for (extra, says) in [
        (&["--nodes", "2"][..], "not started by an MPI launcher"),
        (
            &["--nodes", "2", "--node-rank", "2"][..],
            "--node-rank 2 is out of range",
        ),
        (&["--node-rank", "1"][..], "needs --nodes"),
        (&["--peer-timeout", "0"][..], "--peer-timeout"),
        (&["--peer-timeout", "90"][..], "--peer-timeout"),
    ] {
        let out = alone(extra);
        assert_eq!(out.status.code(), Some(1), "{extra:?}");
        assert!(stderr(&out).contains(says), "{extra:?}: {}", stderr(&out));
    }
    let start = Instant::now();
    let out = mpirun("bad")
        .args(["-n", "2"])
        .args(train_args(&data, &run, &["--steps", "2", "--nodes", "3"]))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(both(&out).contains("--nodes says 3, but Open MPI's mpirun started this process as 2"));
    assert!(start.elapsed() < Duration::from_secs(30));
    assert!(!run.join(CHECKPOINT_DIR).exists());
}

#[test]
fn pose_corrections_learn_from_the_whole_batch_among_peers() {
    let data = common::synthetic_scene("peers_scene_pose", 1, 48, 1).root;
    let base = common::temp_dir("peers_pose");
    let (one, two) = (base.join("one"), base.join("two"));
    // Two steps of pose learning after a 10-step warm-up.
    let flags = [
        "--steps",
        "12",
        "--refine-poses",
        "on",
        "--pose-warmup",
        "10",
    ];
    let out = talkin(&train_args(&data, &one, &flags)[1..]);
    assert!(out.status.success(), "{}", stderr(&out));
    let out = mpirun("pose")
        .args(["-n", "2"])
        .args(train_args(
            &data,
            &two,
            &[&flags[..], &["--nodes", "2"]].concat(),
        ))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", both(&out));
    // The corrections' Adam moments: `v` holds the squared pose gradients, so it matches
    // only if every peer's share of them was summed.
    let moments = |run: &Path, key: &str| -> Vec<f64> {
        let state = run
            .join(CHECKPOINT_DIR)
            .join("step-000012")
            .join("state.json");
        let state: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(state).unwrap()).unwrap();
        fn flat(v: &serde_json::Value, out: &mut Vec<f64>) {
            match v {
                serde_json::Value::Number(n) => out.push(n.as_f64().unwrap()),
                serde_json::Value::Array(a) => a.iter().for_each(|x| flat(x, out)),
                _ => {}
            }
        }
        let mut out = Vec::new();
        flat(&state["pose_refinement"][key], &mut out);
        out
    };
    for key in ["m", "v"] {
        let (a, b) = (moments(&one, key), moments(&two, key));
        assert_eq!(a.len(), b.len());
        let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(scale > 0.0, "no pose gradient was learned");
        for (x, y) in a.iter().zip(&b) {
            // Measured within 1.2e-4 of each sizable value.
            assert!(
                (x - y).abs() <= 1e-3 * x.abs().max(1e-3 * scale),
                "{key}: {x} vs {y}"
            );
        }
    }
}
