//! Running the `talkin` binary from a test: its output, its errors, `talkin import`.

use std::path::Path;
use std::process::{Command, Output};

use talkin::data::dataset::Dataset;

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
