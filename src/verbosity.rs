//! Diagnostics through `tracing`: the level from `-q` (warnings only, no progress) and
//! `-v`/`-vv` (debug, trace), written to stderr as `warning: ...` or a plain line.

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};

use tracing::{Event, Level, Subscriber};
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields};
use tracing_subscriber::registry::LookupSpan;

static QUIET: AtomicBool = AtomicBool::new(false);

/// Whether `-q` was given: progress bars and info lines stay hidden.
pub fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// The level `-q` and `-v` (counted) ask for.
pub fn level(quiet: bool, verbose: u8) -> Level {
    match (quiet, verbose) {
        (true, _) => Level::WARN,
        (false, 0) => Level::INFO,
        (false, 1) => Level::DEBUG,
        (false, _) => Level::TRACE,
    }
}

/// Installs the stderr subscriber once, at the start of `main`.
pub fn init(quiet: bool, verbose: u8) {
    QUIET.store(quiet, Ordering::Relaxed);
    // A second install (tests calling main's setup twice) keeps the first one.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(level(quiet, verbose))
        .event_format(Plain)
        .try_init();
}

/// `warning: message` for warnings and errors, `debug: message` below info, the bare
/// message for info: the lines read like the rest of the command's output.
struct Plain;

impl<S, N> FormatEvent<S, N> for Plain
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> fmt::Result {
        match *event.metadata().level() {
            Level::ERROR => write!(writer, "error: ")?,
            Level::WARN => write!(writer, "warning: ")?,
            Level::INFO => {}
            Level::DEBUG => write!(writer, "debug: ")?,
            Level::TRACE => write!(writer, "trace: ")?,
        }
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_pick_the_level() {
        assert_eq!(level(false, 0), Level::INFO);
        assert_eq!(level(false, 1), Level::DEBUG);
        assert_eq!(level(false, 5), Level::TRACE);
        assert_eq!(level(true, 3), Level::WARN);
    }
}
