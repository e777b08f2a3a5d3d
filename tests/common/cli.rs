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
