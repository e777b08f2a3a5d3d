//! Progress on stderr through `indicatif`: a bar with count, rate and ETA on a terminal;
//! elsewhere (a log file, CI) an info line every 15 s and the final one, so logs show
//! progress without carriage returns. `-q` hides both.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

pub struct Progress {
    bar: ProgressBar,
    label: String,
    unit: &'static str,
    /// When stderr is not a terminal: the last time a log line was written.
    last_line: Option<Mutex<Instant>>,
}

/// How often a log line is written where no bar can be drawn.
const LOG_PERIOD: Duration = Duration::from_secs(15);

impl Progress {
    /// `total` units of `unit` (e.g. "frames", "steps", "s").
    pub fn new(label: impl Into<String>, total: usize, unit: &'static str) -> Progress {
        let label = label.into();
        let target = ProgressDrawTarget::stderr_with_hz(5);
        let drawn = !target.is_hidden() && !crate::verbosity::quiet();
        let bar = ProgressBar::with_draw_target(Some(total as u64), target);
        if drawn {
            let template = format!(
                "{{prefix}} [{{bar:30}}] {{pos}}/{{len}} {unit} ({{per_sec}}, {{elapsed}} \
                 elapsed, ETA {{eta}}) {{wide_msg}}"
            );
            if let Ok(style) = ProgressStyle::with_template(&template) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(label.clone());
        } else {
            bar.set_draw_target(ProgressDrawTarget::hidden());
        }
        let last_line = (!drawn).then(|| Mutex::new(Instant::now()));
        Progress {
            bar,
            label,
            unit,
            last_line,
        }
    }

    /// Reports `done` of the total finished, with an optional message.
    pub fn update(&self, done: usize, message: &str) {
        self.bar.set_position(done as u64);
        self.bar.set_message(message.to_owned());
        let total = self.bar.length().unwrap_or(0);
        let finished = done as u64 >= total;
        if finished && !self.bar.is_finished() {
            self.bar.finish();
        }
        let Some(last) = &self.last_line else {
            return;
        };
        {
            let mut last = last.lock().unwrap_or_else(|p| p.into_inner());
            if !finished && last.elapsed() < LOG_PERIOD {
                return;
            }
            *last = Instant::now();
        }
        let elapsed = self.bar.elapsed().as_secs_f64();
        let rate = done as f64 / elapsed.max(1e-9);
        tracing::info!(
            "{}: {done}/{total} {} ({rate:.1}/s, {elapsed:.0} s elapsed, ETA {:.0} s) {message}",
            self.label,
            self.unit,
            self.bar.eta().as_secs_f64(),
        );
    }
}
