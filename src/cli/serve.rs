use std::path::PathBuf;

use talkin_serve::{ConfigError, ServeConfig, Server, checked_seconds};

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Run directory (its newest checkpoint is loaded once).
    #[arg(long)]
    pub run: PathBuf,
    /// Address to listen on (port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    /// The SMPL-X model file (SMPLX_NEUTRAL.npz, ...) for posted motion files: adds its
    /// mean hand to BEAT2's hand poses and places a motion by the performer's rest pelvis,
    /// as `render --motion --body-model` does. Loaded once at start.
    #[arg(long)]
    pub body_model: Option<PathBuf>,
    /// A BEAT2 or AMASS `.npz` motion the page offers to play, by its file stem
    /// (repeatable). Read once at start.
    #[arg(long = "motion", value_name = "FILE")]
    pub motions: Vec<PathBuf>,
    #[command(flatten)]
    pub limits: LimitArgs,
    #[command(flatten)]
    pub device: super::DeviceArg,
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
    /// Largest request body in bytes, a posted motion file included (413 beyond).
    #[arg(long, default_value_t = ServeConfig::default().max_body_bytes)]
    pub max_body_bytes: usize,
    /// Seconds a request may wait for and spend in one frame's render (504 beyond).
    #[arg(long, default_value_t = ServeConfig::default().render_timeout.as_secs_f64())]
    pub timeout: f64,
    /// Default image size (WIDTHxHEIGHT) when a request brings no camera.
    #[arg(long, default_value = "144x192")]
    pub size: String,
    /// Seconds a client may take from a request's first byte to the end of its headers;
    /// the connection is closed beyond.
    #[arg(long, default_value_t = ServeConfig::default().header_timeout.as_secs_f64())]
    pub header_timeout: f64,
    /// Seconds a connection may wait for a request (or stay blocked on a client that does
    /// not read its answer); it is closed beyond.
    #[arg(long, default_value_t = ServeConfig::default().idle_timeout.as_secs_f64())]
    pub idle_timeout: f64,
    /// Connections open at once; one more is answered 503 and closed.
    #[arg(long, default_value_t = ServeConfig::default().max_connections)]
    pub max_connections: usize,
    /// Seconds the requests in flight get to finish on SIGINT/SIGTERM; the connections
    /// still open after it are dropped (0: at once).
    #[arg(long, default_value_t = ServeConfig::default().shutdown_grace.as_secs_f64())]
    pub shutdown_grace: f64,
    /// Seconds the server keeps serving on SIGINT/SIGTERM while `GET /health` already
    /// answers 503 (draining), before its listener closes: long enough for a load
    /// balancer's health checks to take it out of rotation (0: close at once).
    #[arg(long, default_value_t = ServeConfig::default().drain_delay.as_secs_f64())]
    pub drain_delay: f64,
}

/// The command-line flag that sets a [`ServeConfig`] field.
fn flag(field: &str) -> &str {
    match field {
        "render_timeout" => "--timeout",
        "default_width" | "default_height" => "--size",
        "workers" => "--workers",
        "queue" => "--queue",
        "max_pixels" => "--max-pixels",
        "max_body_bytes" => "--max-body-bytes",
        "header_timeout" => "--header-timeout",
        "idle_timeout" => "--idle-timeout",
        "max_connections" => "--max-connections",
        "shutdown_grace" => "--shutdown-grace",
        "drain_delay" => "--drain-delay",
        other => other,
    }
}

impl LimitArgs {
    /// The server's configuration; every value checked, each error naming its flag.
    pub fn config(&self) -> anyhow::Result<ServeConfig> {
        let (w, h) = self
            .size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .ok_or_else(|| anyhow::anyhow!("--size: expected WIDTHxHEIGHT, found {}", self.size))?;
        let default = ServeConfig::default();
        let config = ServeConfig {
            workers: self.workers.unwrap_or(default.workers),
            queue: self.queue,
            max_pixels: self.max_pixels,
            max_body_bytes: self.max_body_bytes,
            render_timeout: checked_seconds("--timeout", self.timeout, false)?,
            header_timeout: checked_seconds("--header-timeout", self.header_timeout, false)?,
            idle_timeout: checked_seconds("--idle-timeout", self.idle_timeout, false)?,
            max_connections: self.max_connections,
            shutdown_grace: checked_seconds("--shutdown-grace", self.shutdown_grace, true)?,
            drain_delay: checked_seconds("--drain-delay", self.drain_delay, true)?,
            default_width: w,
            default_height: h,
            ..default
        };
        config.validate().map_err(|e| ConfigError {
            field: flag(e.field),
            ..e
        })?;
        Ok(config)
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = args.limits.config()?;
    let (workers, queue, grace) = (
        config.workers,
        config.queue,
        config.shutdown_grace.as_secs_f64(),
    );
    let device = args.device.device;
    // SIGINT/SIGTERM are handled from before the server starts: one that comes while it
    // loads or before `run_until_signal` listens is kept here, not left to kill the
    // process mid-request.
    let caught_early = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, caught_early.clone())
            .map_err(|e| anyhow::anyhow!("installing the SIGINT/SIGTERM handlers: {e}"))?;
    }
    // Listening before the checkpoint loads: `/health` answers 503 (loading) meanwhile,
    // so a load balancer's checks see a replica that is starting, not one that is down.
    // Motion files are small: read before binding, so a bad one never opens the port.
    let motions = talkin_serve::motion::read_named(&args.motions)
        .map_err(|e| anyhow::anyhow!("--motion: {e}"))?;
    let server = Server::bind(&args.addr, config)?;
    server.add_motions(motions)?;
    tracing::info!(
        "listening on http://{} (loading {}; /health answers 503 until it is ready)",
        server.addr(),
        args.run.display()
    );
    server.load(&args.run, args.body_model.as_deref(), device)?;
    tracing::info!(
        "serving {} on http://{} ({workers} render threads, queue {queue}); Ctrl-C stops",
        args.run.display(),
        server.addr()
    );
    let report = server.run_until_signal(&caught_early)?;
    if report.dropped_connections == 0 {
        tracing::info!("stopped: in-flight requests finished");
    } else {
        tracing::warn!(
            "stopped: {} connections still open after the {grace} s grace period were dropped",
            report.dropped_connections
        );
    }
    Ok(())
}
