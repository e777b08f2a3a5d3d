//! A one-line progress display on stderr: count, rate and ETA, redrawn at most 5 times a
//! second on a terminal; elsewhere (a log file) a line every 15 s and the final one.

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
            // A terminal is redrawn 5 times a second; a log file gets a line every 15 s.
            let period = if self.interactive {
                Duration::from_millis(200)
            } else {
                Duration::from_secs(15)
            };
            if !finished && last.elapsed() < period {
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
        let line = format!(
            "{}: {done}/{} ({:.1}/s, {:.0}s elapsed, ETA {:.0}s) {extra}",
            self.label, self.total, rate, elapsed, eta
        );
        if self.interactive {
            let _ = write!(err, "\r{line}\x1b[K");
            if finished {
                let _ = writeln!(err);
            }
        } else {
            let _ = writeln!(err, "{line}");
        }
    }
}
