use std::path::PathBuf;
use std::time::Duration;

use talkin_serve::{ServeConfig, Server};

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Run directory (its newest checkpoint is loaded once).
    #[arg(long)]
    pub run: PathBuf,
    /// Address to listen on (port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    #[command(flatten)]
    pub limits: LimitArgs,
}

/// The server's limits, shared with `bench serve`.
#[derive(clap::Args, Debug, Clone)]
pub struct LimitArgs {
    /// Render threads (default: one per core).
    #[arg(long)]
    pub workers: Option<usize>,
    /// Requests that may wait for a free render thread; beyond, 503 with Retry-After.
    #[arg(long, default_value_t = ServeConfig::default().queue)]
    pub queue: usize,
    /// Largest image a request may ask for, in pixels (413 beyond).
    #[arg(long, default_value_t = ServeConfig::default().max_pixels)]
    pub max_pixels: u64,
    /// Seconds a request may wait for and spend in one frame's render (504 beyond).
    #[arg(long, default_value_t = ServeConfig::default().render_timeout.as_secs_f64())]
    pub timeout: f64,
    /// Default image size (WIDTHxHEIGHT) when a request brings no camera.
    #[arg(long, default_value = "144x192")]
    pub size: String,
}

impl LimitArgs {
    pub fn config(&self) -> anyhow::Result<ServeConfig> {
        let (w, h) = self
            .size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .ok_or_else(|| anyhow::anyhow!("--size: expected WIDTHxHEIGHT, found {}", self.size))?;
        anyhow::ensure!(
            self.timeout.is_finite() && self.timeout > 0.0,
            "--timeout: expected positive seconds, found {}",
            self.timeout
        );
        let default = ServeConfig::default();
        let config = ServeConfig {
            workers: self.workers.unwrap_or(default.workers),
            queue: self.queue,
            max_pixels: self.max_pixels,
            render_timeout: Duration::from_secs_f64(self.timeout),
            default_width: w,
            default_height: h,
            ..default
        };
        config.validate()?;
        Ok(config)
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = args.limits.config()?;
    let (workers, queue) = (config.workers, config.queue);
    let server = Server::load_and_start(&args.run, &args.addr, config)?;
    eprintln!(
        "serving {} on http://{} ({workers} render threads, queue {queue}); Ctrl-C stops",
        args.run.display(),
        server.addr()
    );
    server.run_until_signal()?;
    eprintln!("stopped: in-flight requests finished");
    Ok(())
}
