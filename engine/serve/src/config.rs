//! What the server accepts and how much work it lets wait.

use std::time::Duration;

use talkin_render::avatar::MAX_RENDER_PIXELS;

/// Limits and sizes of a render server. Every limit answers a request that exceeds it with
/// a JSON error instead of work.
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
            default_width: 144,
            default_height: 192,
        }
    }
}

/// A configuration the server cannot run with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("serve config `{field}`: {problem}")]
pub struct ConfigError {
    pub field: &'static str,
    pub problem: String,
}

impl ServeConfig {
    /// Checks that the limits make sense together.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |field, problem: String| Err(ConfigError { field, problem });
        if self.workers == 0 {
            return bad("workers", "needs at least one render thread".into());
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
        if self.max_sequence_frames == 0 {
            return bad("max_sequence_frames", "must be at least 1".into());
        }
        if self.render_timeout.is_zero() || self.body_timeout.is_zero() {
            return bad("render_timeout", "timeouts must be positive".into());
        }
        Ok(())
    }
}
