//! Headless Chromium for the ignored browser tests (`chromium`, or `$CHROMIUM`).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// How long Chromium may take before the test fails (it has hung on a page, rarely; a
/// test that waits forever would hold CI to its limit).
const CHROMIUM_TIMEOUT: Duration = Duration::from_secs(240);

/// Loads `url` in headless Chromium with the profile directory `profile` and the test's
/// own `flags` (window size, virtual-time budget, `--dump-dom` or `--screenshot=`),
/// fails the test unless Chromium succeeds within [`CHROMIUM_TIMEOUT`], and returns what
/// it printed.
pub fn headless_chromium(url: &str, profile: &Path, flags: &[&str]) -> String {
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let stdout = profile.with_extension("stdout");
    let stderr = profile.with_extension("stderr");
    let mut child = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--no-first-run",
            "--run-all-compositor-stages-before-draw",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(flags)
        .arg(url)
        .stdout(Stdio::from(std::fs::File::create(&stdout).unwrap()))
        .stderr(Stdio::from(std::fs::File::create(&stderr).unwrap()))
        .spawn()
        .unwrap_or_else(|e| panic!("running {chromium}: {e}"));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > CHROMIUM_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{chromium} did not finish {url} in {CHROMIUM_TIMEOUT:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let read = |path: &Path| String::from_utf8_lossy(&std::fs::read(path).unwrap()).into_owned();
    assert!(status.success(), "{}", read(&stderr));
    read(&stdout)
}
