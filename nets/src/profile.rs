//! Where a step's time goes: named stages timed on the thread that runs them, with the
//! floating-point operations and bytes each call did where the code knows them (the fused
//! kernels count their own). Off by default: a timed call then costs one atomic load.
//! `talkin bench step` turns it on around the steps it measures.
//!
//! A stage's seconds are its calling thread's wall time, summed over calls: where two
//! chunks of a batch run at once on two threads, their stages add up to about twice the wall.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

static ENABLED: AtomicBool = AtomicBool::new(false);
static TOTALS: Mutex<BTreeMap<&'static str, StageTotal>> = Mutex::new(BTreeMap::new());

/// The work one call does: floating-point operations and bytes moved to or from memory
/// (what its inputs and outputs occupy, and the table rows it gathers or scatters).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Work {
    pub flops: f64,
    pub bytes: f64,
    /// Of `bytes`, those read or written at random rows (gathers, scatters), which the
    /// gather probe bounds rather than streaming bandwidth.
    pub gathered: f64,
}

/// A stage's totals since the last [`take`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTotal {
    pub seconds: f64,
    pub calls: u64,
    pub work: Work,
}

/// Starts (`true`) or stops recording; the totals so far are kept until [`take`].
pub fn set_enabled(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

/// Whether stages are being recorded.
pub fn enabled() -> bool {
    ENABLED.load(Ordering::Relaxed)
}

/// `f`, timed as `stage` when recording.
pub fn timed<T>(stage: &'static str, f: impl FnOnce() -> T) -> T {
    timed_work(stage, Work::default(), f)
}

/// `f`, timed as `stage` with the work it does, when recording.
pub fn timed_work<T>(stage: &'static str, work: Work, f: impl FnOnce() -> T) -> T {
    if !enabled() {
        return f();
    }
    let start = Instant::now();
    let out = f();
    add(stage, start.elapsed(), work);
    out
}

/// Adds a call of `stage` that took `took`, when recording (for a stretch timed by its
/// caller).
pub fn record(stage: &'static str, took: Duration) {
    if enabled() {
        add(stage, took, Work::default());
    }
}

fn add(stage: &'static str, took: Duration, work: Work) {
    let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
    let t = totals.entry(stage).or_default();
    t.seconds += took.as_secs_f64();
    t.calls += 1;
    t.work.flops += work.flops;
    t.work.bytes += work.bytes;
    t.work.gathered += work.gathered;
}

/// The totals recorded since the last call, by stage name, and resets them.
pub fn take() -> BTreeMap<&'static str, StageTotal> {
    std::mem::take(&mut *TOTALS.lock().unwrap_or_else(|e| e.into_inner()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_only_while_enabled_and_take_resets() {
        // One test owns the global switch (tests run on several threads).
        let _ = take();
        timed("off", || ());
        set_enabled(true);
        let work = Work {
            flops: 10.0,
            bytes: 4.0,
            gathered: 2.0,
        };
        let v = timed_work("on", work, || 7);
        timed_work("on", work, || ());
        set_enabled(false);
        assert_eq!(v, 7);
        let totals = take();
        assert!(!totals.contains_key("off"));
        let on = totals["on"];
        assert_eq!(on.calls, 2);
        assert_eq!(
            (on.work.flops, on.work.bytes, on.work.gathered),
            (20.0, 8.0, 4.0)
        );
        assert!(on.seconds >= 0.0);
        assert!(!take().contains_key("on"));
    }
}
