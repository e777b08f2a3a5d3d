//! What the server accepts, how much work it lets wait, and how long it holds a
//! connection.

use std::time::Duration;

use talkin_render::avatar::MAX_RENDER_PIXELS;

/// Longest any of the server's timeouts may be: a day. Past it a timeout is not a limit
/// any more, and a sequence's `render_timeout x frames` must stay far from `Duration`'s
/// and `Instant`'s range.
pub const MAX_TIMEOUT: Duration = Duration::from_secs(24 * 60 * 60);
/// Most render threads a server may start.
pub const MAX_WORKERS: usize = 1024;
/// Most requests that may wait for a render thread.
pub const MAX_QUEUE: usize = 65_536;
/// Most connections a server may hold open (the process would run out of file handles
/// long before).
pub const MAX_CONNECTIONS: usize = 65_536;
/// Most frames a sequence request may be allowed.
pub const MAX_SEQUENCE_FRAMES: usize = 10_000;
/// Largest request body a server may be allowed to read (bytes).
pub const MAX_BODY_BYTES: usize = 1 << 30;

/// Limits and sizes of a render server. Every limit answers a request that exceeds it with
/// a JSON error instead of work, or closes a connection that holds the server up.
#[derive(Clone, Debug, PartialEq)]
pub struct ServeConfig {
    /// Render threads (rendering never runs on the async executor's threads).
    pub workers: usize,
    /// Requests that may wait for a free worker beyond the busy ones; one more gets 503
    /// with `Retry-After`.
    pub queue: usize,
    /// Largest request body (bytes): 413 beyond.
    pub max_body_bytes: usize,
    /// Largest image (width x height): 413 beyond. At most [`MAX_RENDER_PIXELS`].
    pub max_pixels: u64,
    /// Most frames in one `/render/sequence` request: 413 beyond.
    pub max_sequence_frames: usize,
    /// Longest a request may wait for and spend in rendering one frame (a sequence gets
    /// this per frame): 504 beyond. A render that has not started by then is skipped.
    pub render_timeout: Duration,
    /// Longest a client may take to send its body: 408 beyond.
    pub body_timeout: Duration,
    /// Longest a client may take from the first byte of a request to the end of its
    /// headers; the connection is closed beyond (a client that trickles its headers holds
    /// a connection no longer than this).
    pub header_timeout: Duration,
    /// Longest a connection may wait for the first byte of a request (after it opens, or
    /// after its previous answer), and longest a write to a client that does not read may
    /// stay blocked; the connection is closed beyond.
    pub idle_timeout: Duration,
    /// Most connections open at once; a connection beyond is answered 503 and closed
    /// without its request being read.
    pub max_connections: usize,
    /// On shutdown, how long the requests in flight get to finish; the connections still
    /// open after it are dropped. Zero drops them at once.
    pub shutdown_grace: Duration,
    /// On shutdown, how long the server keeps serving while `GET /health` already answers
    /// 503 (draining), before the listener closes: a load balancer's health checks need
    /// this long to take it out of rotation. Zero closes the listener at once.
    pub drain_delay: Duration,
    /// Image size of the default camera, used when a request brings no camera.
    pub default_width: u32,
    pub default_height: u32,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            workers: std::thread::available_parallelism().map_or(1, |n| n.get()),
            queue: 8,
            max_body_bytes: 4 << 20,
            max_pixels: 512 * 512,
            max_sequence_frames: 120,
            render_timeout: Duration::from_secs(60),
            body_timeout: Duration::from_secs(10),
            header_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(30),
            max_connections: 256,
            shutdown_grace: Duration::from_secs(20),
            drain_delay: Duration::ZERO,
            default_width: 144,
            default_height: 192,
        }
    }
}

/// A configuration the server cannot run with. `field` is the [`ServeConfig`] field, or
/// the command-line flag when the value came from one (see [`checked_seconds`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("server option `{field}`: {problem}")]
pub struct ConfigError {
    pub field: &'static str,
    pub problem: String,
}

/// `secs` seconds as a [`Duration`] for the option `field`: finite, within
/// `0..=MAX_TIMEOUT`, and above zero unless `zero_ok`. Use it on every number a
/// user types: `Duration::from_secs_f64` panics on what it refuses.
pub fn checked_seconds(
    field: &'static str,
    secs: f64,
    zero_ok: bool,
) -> Result<Duration, ConfigError> {
    let max = MAX_TIMEOUT.as_secs_f64();
    let low_ok = if zero_ok { secs >= 0.0 } else { secs > 0.0 };
    if !(secs.is_finite() && low_ok && secs <= max) {
        let low = if zero_ok { "[0" } else { "(0" };
        return Err(ConfigError {
            field,
            problem: format!("expected seconds in {low}, {max}], found {secs}"),
        });
    }
    Ok(Duration::from_secs_f64(secs))
}

impl ServeConfig {
    /// Checks that every limit is in its range and that they make sense together.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |field, problem: String| Err(ConfigError { field, problem });
        for (field, n, max) in [
            ("workers", self.workers, MAX_WORKERS),
            ("max_connections", self.max_connections, MAX_CONNECTIONS),
            (
                "max_sequence_frames",
                self.max_sequence_frames,
                MAX_SEQUENCE_FRAMES,
            ),
            ("max_body_bytes", self.max_body_bytes, MAX_BODY_BYTES),
        ] {
            if n == 0 || n > max {
                return bad(field, format!("{n} is not in 1..={max}"));
            }
        }
        if self.queue > MAX_QUEUE {
            return bad("queue", format!("{} is not in 0..={MAX_QUEUE}", self.queue));
        }
        if self.max_pixels == 0 || self.max_pixels > MAX_RENDER_PIXELS {
            return bad(
                "max_pixels",
                format!("{} is not in 1..={MAX_RENDER_PIXELS}", self.max_pixels),
            );
        }
        let default_pixels = u64::from(self.default_width) * u64::from(self.default_height);
        if default_pixels == 0 || default_pixels > self.max_pixels {
            return bad(
                "default_width",
                format!(
                    "the default image {}x{} must be non-empty and within max_pixels {}",
                    self.default_width, self.default_height, self.max_pixels
                ),
            );
        }
        for (field, d, zero_ok) in [
            ("render_timeout", self.render_timeout, false),
            ("body_timeout", self.body_timeout, false),
            ("header_timeout", self.header_timeout, false),
            ("idle_timeout", self.idle_timeout, false),
            ("shutdown_grace", self.shutdown_grace, true),
            ("drain_delay", self.drain_delay, true),
        ] {
            if (d.is_zero() && !zero_ok) || d > MAX_TIMEOUT {
                let low = if zero_ok { "[0" } else { "(0" };
                return bad(
                    field,
                    format!(
                        "{} s is not in {low}, {}] s",
                        d.as_secs_f64(),
                        MAX_TIMEOUT.as_secs()
                    ),
                );
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_refuse_what_duration_would_panic_on() {
        for bad in [1e300, f64::INFINITY, f64::NAN, -1.0, -0.0, 0.0, 86_401.0] {
            let e = checked_seconds("--timeout", bad, false).unwrap_err();
            assert_eq!(e.field, "--timeout", "{bad}");
            assert!(e.to_string().contains("--timeout"), "{e}");
        }
        assert_eq!(
            checked_seconds("--timeout", 1.5, false),
            Ok(Duration::from_millis(1500))
        );
        assert_eq!(
            checked_seconds("--shutdown-grace", 0.0, true),
            Ok(Duration::ZERO)
        );
        assert!(checked_seconds("--shutdown-grace", -1e-9, true).is_err());
        assert!(checked_seconds("--shutdown-grace", f64::NAN, true).is_err());
    }

    #[test]
    fn every_limit_is_bounded() {
        let ok = ServeConfig::default();
        assert_eq!(ok.validate(), Ok(()));
        let cases: Vec<(&str, ServeConfig)> = vec![
            (
                "workers",
                ServeConfig {
                    workers: 0,
                    ..ok.clone()
                },
            ),
            (
                "workers",
                ServeConfig {
                    workers: 1 << 20,
                    ..ok.clone()
                },
            ),
            (
                "queue",
                ServeConfig {
                    queue: usize::MAX,
                    ..ok.clone()
                },
            ),
            (
                "max_connections",
                ServeConfig {
                    max_connections: 0,
                    ..ok.clone()
                },
            ),
            (
                "max_pixels",
                ServeConfig {
                    max_pixels: u64::MAX,
                    ..ok.clone()
                },
            ),
            (
                "max_body_bytes",
                ServeConfig {
                    max_body_bytes: usize::MAX,
                    ..ok.clone()
                },
            ),
            (
                "max_sequence_frames",
                ServeConfig {
                    max_sequence_frames: usize::MAX,
                    ..ok.clone()
                },
            ),
            (
                "render_timeout",
                ServeConfig {
                    render_timeout: Duration::MAX,
                    ..ok.clone()
                },
            ),
            (
                "body_timeout",
                ServeConfig {
                    body_timeout: Duration::ZERO,
                    ..ok.clone()
                },
            ),
            (
                "header_timeout",
                ServeConfig {
                    header_timeout: Duration::ZERO,
                    ..ok.clone()
                },
            ),
            (
                "idle_timeout",
                ServeConfig {
                    idle_timeout: Duration::MAX,
                    ..ok.clone()
                },
            ),
            (
                "shutdown_grace",
                ServeConfig {
                    shutdown_grace: Duration::MAX,
                    ..ok.clone()
                },
            ),
            (
                "drain_delay",
                ServeConfig {
                    drain_delay: Duration::MAX,
                    ..ok.clone()
                },
            ),
            (
                "default_width",
                ServeConfig {
                    default_width: 0,
                    ..ok.clone()
                },
            ),
        ];
        for (field, config) in cases {
            assert_eq!(config.validate().unwrap_err().field, field);
        }
        let zero_grace = ServeConfig {
            shutdown_grace: Duration::ZERO,
            ..ok
        };
        assert_eq!(zero_grace.validate(), Ok(()));
    }
}
