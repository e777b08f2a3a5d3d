//! A one-line progress display on stderr: count, rate and ETA, redrawn at most 5 times a
//! second (and not at all when stderr is not a terminal, except the final line).

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

pub struct Progress {
    label: String,
    total: usize,
    start: Instant,
    last_draw: Mutex<Instant>,
    interactive: bool,
}

impl Progress {
    pub fn new(label: impl Into<String>, total: usize) -> Progress {
        let now = Instant::now();
        Progress {
            label: label.into(),
            total,
            start: now,
            last_draw: Mutex::new(now - Duration::from_secs(1)),
            interactive: std::io::stderr().is_terminal(),
        }
    }

    /// Reports `done` of `total` units finished, with an optional extra message.
    pub fn update(&self, done: usize, extra: &str) {
        let finished = done >= self.total;
        {
            let mut last = self.last_draw.lock().unwrap_or_else(|p| p.into_inner());
            if !finished && (!self.interactive || last.elapsed() < Duration::from_millis(200)) {
                return;
            }
            *last = Instant::now();
        }
        let elapsed = self.start.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        let eta = if done > 0 {
            (self.total.saturating_sub(done)) as f64 / rate
        } else {
            f64::NAN
        };
        let mut err = std::io::stderr().lock();
        let _ = write!(
            err,
            "\r{}: {done}/{} ({:.1}/s, {:.0}s elapsed, ETA {:.0}s) {extra}\x1b[K",
            self.label, self.total, rate, elapsed, eta
        );
        if finished {
            let _ = writeln!(err);
        }
    }
}
