//! Running the `talkin` binary from a test: its output, its errors, `talkin import`.

use std::path::Path;
use std::process::{Command, Output};

use talkin::data::dataset::{Dataset, Frame};

/// Runs `talkin` with `args` and waits for it.
pub fn talkin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(args)
        .output()
        .unwrap()
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A path as a command-line argument.
pub fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// `import FORMAT SRC --out OUT --body-model MODEL`.
pub fn import_args<'a>(
    format: &'a str,
    src: &'a Path,
    out: &'a Path,
    model: &'a Path,
) -> Vec<&'a str> {
    vec![
        "import",
        format,
        p(src),
        "--out",
        p(out),
        "--body-model",
        p(model),
    ]
}

/// Runs `talkin import`, which must succeed and write `import.json`, and loads the result.
pub fn import_ok(args: &[&str]) -> Dataset {
    let out = talkin(args);
    assert!(out.status.success(), "import failed: {}", stderr(&out));
    let dir = args[args.iter().position(|a| *a == "--out").unwrap() + 1];
    assert!(Path::new(dir).join("import.json").is_file());
    Dataset::load(dir).unwrap()
}

/// The scene the end-to-end training tests compare against, written by `talkin synth
/// --identities 1 --frames 20 --size 96 --seed 1` into `dir` and loaded.
pub fn synth_training_scene(dir: &Path) -> Dataset {
    let o = talkin(&[
        "synth",
        "--out",
        p(dir),
        "--identities",
        "1",
        "--frames",
        "20",
        "--size",
        "96",
        "--seed",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    Dataset::load(dir).unwrap()
}

/// `ds`'s train and test_same frames, in order (what a fitter's layout holds).
pub fn train_and_test_same(ds: &Dataset) -> Vec<&Frame> {
    ds.frames
        .iter()
        .filter(|f| matches!(f.split.name(), "train" | "test_same"))
        .collect()
}

/// `talkin train`'s flags for a tiny scene in the end-to-end tests: 256 rays, no
/// perceptual term, a 32-cell grid, a fixed seed.
pub const TINY_TRAIN_FLAGS: [&str; 10] = [
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
];

/// Starts a long `talkin train` (the tiny-scene flags, a checkpoint every 0.3 s) of `data`
/// into `run`, its stderr into `stderr_file`, and waits for its first checkpoint; fails
/// the test if none comes in 2 minutes or the trainer ends first.
pub fn start_trainer(data: &Path, run: &Path, stderr_file: &Path) -> std::process::Child {
    use talkin::avatar::checkpoint::{CHECKPOINT_DIR, LATEST_FILE};
    let mut child = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["train", "--data", p(data), "--out", p(run)])
        .args(TINY_TRAIN_FLAGS)
        .args(["--steps", "100000", "--checkpoint-every", "0.3"])
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(stderr_file).unwrap())
        .spawn()
        .unwrap();
    let latest = run.join(CHECKPOINT_DIR).join(LATEST_FILE);
    let start = std::time::Instant::now();
    while !latest.exists() {
        assert!(
            start.elapsed() < std::time::Duration::from_secs(120),
            "no checkpoint after 2 minutes"
        );
        if child.try_wait().unwrap().is_some() {
            panic!(
                "the trainer ended early: {}",
                std::fs::read_to_string(stderr_file).unwrap()
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child
}
