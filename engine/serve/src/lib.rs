//! The render server: loads a run's checkpoint once and renders frames for posted poses,
//! cameras and identities over HTTP (axum on a small tokio runtime).
//!
//! Rendering is CPU-bound, so it runs on [`pool::Pool`]'s fixed render threads behind a
//! bounded queue; the async threads only parse, validate and wait. A full queue answers
//! 503 with `Retry-After`; bad input answers 400/404/405/413 with `{"error", "field"}`
//! naming the JSON path at fault, and the server keeps serving. Connections are bounded
//! in number and in how long they may idle or take to send their headers (see
//! `connections`). Shutdown (SIGINT/SIGTERM or [`Server::shutdown`]) stops accepting,
//! gives the requests in flight `shutdown_grace` to finish, drops what is left and joins
//! the render threads that are done.
//!
//! Readiness is separate from liveness, for a load balancer in front of replicas: the
//! listener is bound before the checkpoint loads, and `GET /health` answers 503 with its
//! reason while it loads and from the moment a shutdown begins (for `drain_delay` before
//! the listener closes, so a balancer's health check sees it first); `GET /live` answers
//! 200 as long as the process serves HTTP at all.
//!
//! Routes: `GET /` (a page with sliders), `GET /health`, `GET /live`, `GET /subjects`,
//! `POST /render`, `GET /motions`, `GET`/`POST /motion/poses` (a motion's prepared poses,
//! for the page's player),
//! `POST /render/sequence` (a zip of PNGs, for a JSON list of poses or a posted BEAT2/AMASS
//! motion file, see [`motion`]). `docs/server-api.md` has the request format.
//!
//! The only crate with tokio and axum; it must not know about training or datasets
//! beyond reading poses: it renders what `talkin-render` loads.

pub mod bench;
pub mod client;
mod config;
mod connections;
mod encode;
mod error;
mod json;
pub mod motion;
pub mod pool;
pub mod request;
mod routes;
mod subjects;

use std::net::{SocketAddr, TcpListener};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, RwLock};
use std::thread::JoinHandle;
use std::time::Instant;

use tokio::sync::{Notify, Semaphore};

pub use config::{ConfigError, ServeConfig, checked_seconds};
pub use error::{RequestError, ServeError};
pub use motion::NamedMotion;
pub use routes::REQUEST_ID_HEADER;
pub use subjects::{ServedSubject, default_camera, served_subjects};

use pool::Pool;
use talkin_avatar::Avatar;
use talkin_data::smplx_model::SmplxModel;
use talkin_nets::ComputeDevice;

/// What every handler shares.
struct App {
    /// What the server renders, set once the checkpoint has loaded.
    loaded: OnceLock<Loaded>,
    /// A [`Readiness`] as its `u8`.
    readiness: AtomicU8,
    /// The motion files the server offers by name (`GET /motions`).
    motions: RwLock<Vec<Arc<NamedMotion>>>,
    /// Jobs a render thread skipped because their client had gone (cancelled, timed out).
    skipped: Arc<AtomicU64>,
    config: ServeConfig,
    pool: Pool,
    /// One permit per connection the server may hold open.
    connections: Arc<Semaphore>,
}

/// The avatar and what is derived from it.
struct Loaded {
    avatar: Arc<Avatar>,
    /// The SMPL-X model file for motion files (mean hands, the performer's rest pelvis).
    body_model: Option<Arc<SmplxModel>>,
    subjects: Vec<ServedSubject>,
}

/// Whether a server wants new requests, as `GET /health` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Readiness {
    /// The listener is up but the checkpoint is still loading: 503.
    Loading = 0,
    /// Serving: 200.
    Ready = 1,
    /// A shutdown has begun; the listener closes after the drain delay: 503.
    Draining = 2,
}

impl Readiness {
    /// Why a server in this state wants no requests (None when it does).
    pub fn reason(self) -> Option<&'static str> {
        match self {
            Readiness::Loading => Some("loading the checkpoint"),
            Readiness::Ready => None,
            Readiness::Draining => Some("shutting down: draining before the listener closes"),
        }
    }
}

impl App {
    fn readiness(&self) -> Readiness {
        match self.readiness.load(Ordering::SeqCst) {
            0 => Readiness::Loading,
            1 => Readiness::Ready,
            _ => Readiness::Draining,
        }
    }

    /// What the server renders, or 503 while it loads.
    fn loaded(&self) -> Result<&Loaded, RequestError> {
        self.loaded.get().ok_or(RequestError::NotReady {
            reason: "the server is loading its checkpoint",
        })
    }
}

/// How a shutdown went.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShutdownReport {
    /// Connections still open when the grace period ended, dropped without an answer.
    pub dropped_connections: usize,
    /// Render threads still busy when the grace period ended, left to finish unjoined.
    pub detached_workers: usize,
}

/// A running server. Dropping it shuts it down gracefully.
pub struct Server {
    addr: SocketAddr,
    app: Arc<App>,
    stop: Arc<Notify>,
    thread: Option<JoinHandle<Result<ShutdownReport, ServeError>>>,
}

impl Loaded {
    fn new(
        avatar: Arc<Avatar>,
        body_model: Option<Arc<SmplxModel>>,
        config: &ServeConfig,
    ) -> Result<Loaded, ServeError> {
        let subjects = served_subjects(&avatar, config.default_width, config.default_height)
            .map_err(|e| ConfigError {
                field: "default_width",
                problem: format!("no default camera of that size: {e}"),
            })?;
        if subjects.is_empty() {
            return Err(ServeError::NoSubjects);
        }
        Ok(Loaded {
            avatar,
            body_model,
            subjects,
        })
    }
}

impl Server {
    /// Serves `avatar` on `addr` (`127.0.0.1:0` picks a free port; see [`Server::addr`]).
    /// Returns once the socket is bound.
    pub fn start(
        avatar: Arc<Avatar>,
        addr: &str,
        config: ServeConfig,
    ) -> Result<Server, ServeError> {
        Server::start_with_body_model(avatar, None, addr, config)
    }

    /// [`Server::start`] with the SMPL-X model posted motion files are prepared with
    /// (without one, hands stored relative to the mean hand are used as given, with a note).
    pub fn start_with_body_model(
        avatar: Arc<Avatar>,
        body_model: Option<Arc<SmplxModel>>,
        addr: &str,
        config: ServeConfig,
    ) -> Result<Server, ServeError> {
        config.validate()?;
        // Checked before binding: a bad avatar or size never opens the port.
        let loaded = Loaded::new(avatar, body_model, &config)?;
        let server = Server::bind(addr, config)?;
        server.set_loaded(loaded);
        Ok(server)
    }

    /// Binds `addr` and starts serving with nothing loaded yet: `/health` answers 503
    /// (loading) and `/live` 200 until [`Server::load`] or [`Server::serve_avatar`].
    pub fn bind(addr: &str, config: ServeConfig) -> Result<Server, ServeError> {
        config.validate()?;
        let bind_err = |source| ServeError::Bind {
            addr: addr.to_string(),
            source,
        };
        let listener = TcpListener::bind(addr).map_err(bind_err)?;
        listener.set_nonblocking(true).map_err(bind_err)?;
        let local = listener.local_addr().map_err(bind_err)?;
        let pool = Pool::new(config.workers, config.queue).map_err(ServeError::Runtime)?;
        let app = Arc::new(App {
            loaded: OnceLock::new(),
            readiness: AtomicU8::new(Readiness::Loading as u8),
            motions: RwLock::new(Vec::new()),
            skipped: Arc::new(AtomicU64::new(0)),
            connections: Arc::new(Semaphore::new(config.max_connections)),
            config,
            pool,
        });
        // Two async threads are plenty: they only move bytes and wait on the pool.
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("talkin-http")
            .enable_io()
            .enable_time()
            .build()
            .map_err(ServeError::Runtime)?;
        let stop = Arc::new(Notify::new());
        let stopped = stop.clone();
        let served = app.clone();
        let thread = std::thread::Builder::new()
            .name("talkin-serve".into())
            .spawn(move || {
                let app = served;
                let grace_ends = std::sync::OnceLock::new();
                let dropped = runtime.block_on(async {
                    let listener = tokio::net::TcpListener::from_std(listener)?;
                    let stop = async {
                        stopped.notified().await;
                        let _ = grace_ends.set(Instant::now() + app.config.shutdown_grace);
                    };
                    let router = routes::router(app.clone());
                    let permits = app.connections.clone();
                    Ok::<_, std::io::Error>(
                        connections::serve(listener, router, &app.config, permits, stop).await,
                    )
                });
                // Every connection is closed: no handler waits on the pool any more. A
                // render whose client is gone may still run; it gets what is left of the
                // grace period.
                let deadline = grace_ends.get().copied().unwrap_or_else(Instant::now);
                let detached_workers = app.pool.shutdown_until(deadline);
                Ok(ShutdownReport {
                    dropped_connections: dropped.map_err(ServeError::Serve)?,
                    detached_workers,
                })
            })
            .map_err(ServeError::Runtime)?;
        Ok(Server {
            addr: local,
            app,
            stop,
            thread: Some(thread),
        })
    }

    /// Loads the newest checkpoint of `run` (and the SMPL-X `body_model` file, if given)
    /// into a server started by [`Server::bind`], which then reports itself ready.
    pub fn load(
        &self,
        run: &Path,
        body_model: Option<&Path>,
        device: ComputeDevice,
    ) -> Result<(), ServeError> {
        let device = device.open()?;
        // The small file first: a wrong path is reported without loading the run.
        let model = body_model
            .map(|file| {
                SmplxModel::load(file).map_err(|source| ServeError::BodyModel {
                    file: file.to_path_buf(),
                    source,
                })
            })
            .transpose()?;
        let avatar = Avatar::load_on(run, &device).map_err(|source| ServeError::Avatar {
            run: run.to_path_buf(),
            source,
        })?;
        self.serve_avatar(Arc::new(avatar), model.map(Arc::new))
    }

    /// Serves `avatar` from a server started by [`Server::bind`]; it reports itself ready.
    pub fn serve_avatar(
        &self,
        avatar: Arc<Avatar>,
        body_model: Option<Arc<SmplxModel>>,
    ) -> Result<(), ServeError> {
        let loaded = Loaded::new(avatar, body_model, &self.app.config)?;
        self.set_loaded(loaded);
        Ok(())
    }

    fn set_loaded(&self, loaded: Loaded) {
        if self.app.loaded.set(loaded).is_ok() {
            // A shutdown that began while loading stays a shutdown.
            let _ = self.app.readiness.compare_exchange(
                Readiness::Loading as u8,
                Readiness::Ready as u8,
                Ordering::SeqCst,
                Ordering::SeqCst,
            );
        }
    }

    /// Offers `motions` by name (`GET /motions`, `GET /motion/poses?name=`), beside any
    /// offered before; a name already offered is refused.
    pub fn add_motions(&self, motions: Vec<NamedMotion>) -> Result<(), ServeError> {
        let mut offered = self.app.motions.write().unwrap_or_else(|p| p.into_inner());
        for m in motions {
            if offered.iter().any(|o| o.name == m.name) {
                return Err(ServeError::MotionName {
                    file: m.motion.file.clone(),
                    name: m.name,
                });
            }
            offered.push(Arc::new(m));
        }
        Ok(())
    }

    /// What `GET /health` reports now.
    pub fn readiness(&self) -> Readiness {
        self.app.readiness()
    }

    /// The bound address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Reports itself draining (`/health` 503) for the configured `drain_delay` while it
    /// still serves, then stops accepting, gives the requests in flight the configured
    /// grace period to finish, drops the connections still open after it, and joins the
    /// server's threads.
    pub fn shutdown(mut self) -> Result<ShutdownReport, ServeError> {
        let was = self
            .app
            .readiness
            .swap(Readiness::Draining as u8, Ordering::SeqCst);
        // A server that was still loading was never in a balancer's rotation.
        if was == Readiness::Ready as u8 {
            std::thread::sleep(self.app.config.drain_delay);
        }
        self.stop_and_join()
    }

    /// Serves until SIGINT or SIGTERM, then shuts down as [`Server::shutdown`] does.
    /// `caught_early` is a flag the caller's own handler set for a signal that came
    /// before this call (between the server's start and here): it stops at once. Without
    /// such a handler, that signal would have ended the process unhandled.
    pub fn run_until_signal(self, caught_early: &AtomicBool) -> Result<ShutdownReport, ServeError> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .build()
            .map_err(ServeError::Runtime)?;
        runtime.block_on(termination_signal(caught_early))?;
        self.shutdown()
    }

    fn stop_and_join(&mut self) -> Result<ShutdownReport, ServeError> {
        self.stop.notify_one();
        match self.thread.take() {
            Some(t) => t.join().unwrap_or_else(|_| {
                Err(ServeError::Serve(std::io::Error::other(
                    "the server thread panicked",
                )))
            }),
            None => Ok(ShutdownReport::default()),
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.stop_and_join();
    }
}

/// Waits for SIGINT (Ctrl-C) or SIGTERM (what `kill` and container runtimes send), or
/// returns at once when `caught_early` says one came before the listeners were set.
async fn termination_signal(caught_early: &AtomicBool) -> Result<(), ServeError> {
    let caught = Arc::new(Notify::new());
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        for kind in [SignalKind::interrupt(), SignalKind::terminate()] {
            let mut stream = signal(kind).map_err(ServeError::Runtime)?;
            let caught = caught.clone();
            tokio::spawn(async move {
                stream.recv().await;
                caught.notify_one();
            });
        }
    }
    #[cfg(not(unix))]
    {
        let caught = caught.clone();
        tokio::spawn(async move {
            let _ = tokio::signal::ctrl_c().await;
            caught.notify_one();
        });
    }
    // Checked after the listeners are set: a signal from here on reaches them.
    if !caught_early.load(Ordering::SeqCst) {
        caught.notified().await;
    }
    Ok(())
}
