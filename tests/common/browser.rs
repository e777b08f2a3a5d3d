//! Headless Chromium for the ignored browser tests (`chromium`, or `$CHROMIUM`).

use std::path::Path;
use std::process::Command;

/// Loads `url` in headless Chromium with the profile directory `profile` and the test's
/// own `flags` (window size, virtual-time budget, `--dump-dom` or `--screenshot=`),
/// fails the test unless Chromium succeeds, and returns what it printed.
pub fn headless_chromium(url: &str, profile: &Path, flags: &[&str]) -> String {
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let out = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--no-first-run",
            "--run-all-compositor-stages-before-draw",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(flags)
        .arg(url)
        .output()
        .unwrap_or_else(|e| panic!("running {chromium}: {e}"));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}
