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
/// it printed. A Chromium that hangs is killed and started once more with a fresh
/// profile (the same page has loaded in 11 s after a 240-s hang); the hung attempt's
/// last lines of stderr are printed.
pub fn headless_chromium(url: &str, profile: &Path, flags: &[&str]) -> String {
    match chromium_once(url, profile, flags) {
        Some(out) => out,
        None => {
            let retry = profile.with_extension("retry");
            let _ = std::fs::remove_dir_all(&retry);
            chromium_once(url, &retry, flags).unwrap_or_else(|| {
                panic!("chromium did not finish {url} in {CHROMIUM_TIMEOUT:?}, twice")
            })
        }
    }
}

/// One headless Chromium run; `None` if it had to be killed after [`CHROMIUM_TIMEOUT`].
fn chromium_once(url: &str, profile: &Path, flags: &[&str]) -> Option<String> {
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
    let read = |path: &Path| String::from_utf8_lossy(&std::fs::read(path).unwrap()).into_owned();
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > CHROMIUM_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            let said = read(&stderr);
            let tail: Vec<&str> = said.lines().rev().take(10).collect();
            eprintln!(
                "{chromium} did not finish {url} in {CHROMIUM_TIMEOUT:?}; the end of its \
                 stderr:\n{}",
                tail.into_iter().rev().collect::<Vec<_>>().join("\n")
            );
            return None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "{}", read(&stderr));
    Some(read(&stdout))
}
