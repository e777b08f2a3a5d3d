//! Connections: the accept loop and what bounds each connection. `axum::serve` sets no
//! header or idle timeout, caps no connections and waits without end on shutdown, so each
//! connection is served here by hyper's HTTP/1 builder with a watchdog beside it.
//!
//! A connection is always in one of three phases, and the watchdog closes it when its
//! phase lasts too long:
//! - idle, waiting for the first byte of a request (after it opened, or after its
//!   previous answer): `idle_timeout`;
//! - reading a request's head, from its first byte to the end of its headers:
//!   `header_timeout` (a client that trickles its headers is cut off);
//! - a request in flight, from the end of its headers until its answer's last byte is
//!   handed to the socket: no connection limit, since the body and render timeouts bound
//!   the handler; but a write blocked on a client that does not read lasts at most
//!   `idle_timeout`.
//!
//! hyper's own `header_read_timeout` (idle + header) backs the watchdog up. Beyond
//! `max_connections`, a new connection is answered 503 and closed unread. On shutdown the
//! listener closes, idle connections close at once, and the others get `shutdown_grace`
//! to finish; those still open after it are dropped.

use std::convert::Infallible;
use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::body::{Body, Bytes};
use hyper::body::{Frame, Incoming, SizeHint};
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore, watch};
use tokio::task::JoinSet;
use tokio::time::Instant;

use super::config::ServeConfig;
use super::error::RequestError;

/// The per-connection limits the watchdog enforces.
#[derive(Clone, Copy, Debug)]
struct Limits {
    header: Duration,
    idle: Duration,
}

/// Serves `router` on `listener` until `stop` resolves, then shuts down within the grace
/// period. Returns how many connections were still open when it ended (dropped unanswered).
pub(crate) async fn serve(
    listener: TcpListener,
    router: Router,
    config: &ServeConfig,
    permits: Arc<Semaphore>,
    stop: impl Future<Output = ()>,
) -> usize {
    let limits = Limits {
        header: config.header_timeout,
        idle: config.idle_timeout,
    };
    let refusal = refusal(config.max_connections);
    let (closing_tx, closing) = watch::channel(false);
    let mut connections = JoinSet::new();
    let mut stop = std::pin::pin!(stop);
    loop {
        tokio::select! {
            () = &mut stop => break,
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => match permits.clone().try_acquire_owned() {
                    Ok(permit) => {
                        let conn = connection(stream, router.clone(), limits, closing.clone(), permit);
                        connections.spawn(conn);
                    }
                    // Best effort: a client that has already sent its request may see the
                    // connection reset instead.
                    Err(_) => {
                        let _ = stream.try_write(&refusal);
                    }
                },
                Err(e) => accept_failed(e).await,
            },
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
        }
    }
    drop(listener);
    let _ = closing_tx.send(true);
    let drain = async { while connections.join_next().await.is_some() {} };
    let _ = tokio::time::timeout(config.shutdown_grace, drain).await;
    let dropped = connections.len();
    connections.abort_all();
    while connections.join_next().await.is_some() {}
    dropped
}

/// The answer a connection beyond the cap gets before it is closed.
fn refusal(limit: usize) -> Vec<u8> {
    let error = RequestError::TooManyConnections { limit };
    let body = error.json().to_string();
    format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n\
         retry-after: 1\r\nconnection: close\r\ncontent-length: {}\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

/// An accept that failed. A connection that went away before it was accepted is nothing;
/// anything else (out of file handles) gets a pause so the loop does not spin on it.
async fn accept_failed(e: io::Error) {
    use io::ErrorKind::{ConnectionAborted, ConnectionRefused, ConnectionReset};
    if !matches!(
        e.kind(),
        ConnectionAborted | ConnectionRefused | ConnectionReset
    ) {
        eprintln!("talkin-serve: accepting a connection failed: {e}; retrying");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// One connection, from accept to close; holds its slot (`_permit`) until it ends.
async fn connection(
    stream: TcpStream,
    router: Router,
    limits: Limits,
    mut closing: watch::Receiver<bool>,
    _permit: OwnedSemaphorePermit,
) {
    let activity = Arc::new(Activity::new(Instant::now()));
    let io = TokioIo::new(Watched {
        stream,
        activity: activity.clone(),
    });
    let service = Tracked {
        inner: TowerToHyperService::new(router),
        activity: activity.clone(),
    };
    let mut builder = http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .keep_alive(true)
        .header_read_timeout(limits.idle + limits.header);
    let conn = builder.serve_connection(io, service);
    let mut conn = std::pin::pin!(conn);
    let mut shutting_down = false;
    loop {
        let deadline = activity.deadline(limits);
        tokio::select! {
            _ = conn.as_mut() => return,
            () = activity.changed.notified() => {}
            () = sleep_until(deadline) => {
                if activity.deadline(limits).is_some_and(|d| d <= Instant::now()) {
                    return;
                }
            }
            _ = closing.changed(), if !shutting_down => {
                shutting_down = true;
                conn.as_mut().graceful_shutdown();
            }
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// Where a connection stands, updated by its socket and its requests.
struct Phase {
    /// Requests whose headers have arrived and whose answer is not yet handed over.
    in_flight: usize,
    /// When the connection last began to wait for a request.
    waiting_since: Instant,
    /// The first byte of the next request, once it has come.
    first_byte: Option<Instant>,
    /// Since when a write has been waiting for the client to read.
    write_blocked_since: Option<Instant>,
}

struct Activity {
    phase: Mutex<Phase>,
    /// Wakes the watchdog when the deadline may have moved.
    changed: Notify,
}

impl Activity {
    fn new(now: Instant) -> Self {
        Self {
            phase: Mutex::new(Phase {
                in_flight: 0,
                waiting_since: now,
                first_byte: None,
                write_blocked_since: None,
            }),
            changed: Notify::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Phase> {
        // The phase is plain data, consistent after every write.
        self.phase.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Changes the phase with `edit`; wakes the watchdog if `edit` says it changed.
    fn update(&self, edit: impl FnOnce(&mut Phase) -> bool) {
        if edit(&mut self.lock()) {
            self.changed.notify_one();
        }
    }

    /// When the connection must close if nothing changes before, or never.
    fn deadline(&self, limits: Limits) -> Option<Instant> {
        let p = self.lock();
        let phase = match (p.in_flight, p.first_byte) {
            (0, None) => Some(p.waiting_since + limits.idle),
            (0, Some(first)) => Some(first + limits.header),
            _ => None,
        };
        let stalled = p.write_blocked_since.map(|t| t + limits.idle);
        match (phase, stalled) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn read_some(&self, now: Instant) {
        self.update(|p| {
            let starts_a_request = p.in_flight == 0 && p.first_byte.is_none();
            if starts_a_request {
                p.first_byte = Some(now);
            }
            starts_a_request
        });
    }

    fn write_done(&self, blocked: bool, now: Instant) {
        self.update(|p| {
            let changed = p.write_blocked_since.is_some() != blocked;
            if changed {
                p.write_blocked_since = blocked.then_some(now);
            }
            changed
        });
    }

    fn request_started(self: &Arc<Self>) -> InFlight {
        self.begin_request();
        InFlight(self.clone())
    }

    fn begin_request(&self) {
        self.update(|p| {
            p.in_flight += 1;
            p.first_byte = None;
            true
        });
    }

    fn request_done(&self, now: Instant) {
        self.update(|p| {
            p.in_flight = p.in_flight.saturating_sub(1);
            if p.in_flight == 0 {
                p.waiting_since = now;
                p.first_byte = None;
            }
            true
        });
    }
}

/// A request in flight; dropped when its answer's body has been handed to hyper (or the
/// request was abandoned).
struct InFlight(Arc<Activity>);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.request_done(Instant::now());
    }
}

/// The socket, telling the watchdog what moves through it.
struct Watched {
    stream: TcpStream,
    activity: Arc<Activity>,
}

impl AsyncRead for Watched {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let read = Pin::new(&mut this.stream).poll_read(cx, buf);
        if matches!(read, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.activity.read_some(Instant::now());
        }
        read
    }
}

impl Watched {
    fn saw_write(&self, written: &Poll<io::Result<usize>>) {
        match written {
            Poll::Pending => self.activity.write_done(true, Instant::now()),
            Poll::Ready(Ok(n)) if *n > 0 => self.activity.write_done(false, Instant::now()),
            _ => {}
        }
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let written = Pin::new(&mut this.stream).poll_write(cx, buf);
        this.saw_write(&written);
        written
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let written = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        this.saw_write(&written);
        written
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }
}

/// The router as hyper's service, marking each request in flight until its answer's body
/// is done.
#[derive(Clone)]
struct Tracked {
    inner: TowerToHyperService<Router>,
    activity: Arc<Activity>,
}

type Answer = hyper::Response<TrackedBody>;

impl hyper::service::Service<hyper::Request<Incoming>> for Tracked {
    type Response = Answer;
    type Error = Infallible;
    type Future = Pin<Box<dyn Future<Output = Result<Answer, Infallible>> + Send>>;

    fn call(&self, request: hyper::Request<Incoming>) -> Self::Future {
        let in_flight = self.activity.request_started();
        let answer = self.inner.call(request);
        Box::pin(async move {
            let response = answer.await?;
            Ok(response.map(|body| TrackedBody {
                body,
                _in_flight: in_flight,
            }))
        })
    }
}

/// An answer's body that ends its request's time in flight when hyper drops it.
struct TrackedBody {
    body: Body,
    _in_flight: InFlight,
}

impl hyper::body::Body for TrackedBody {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.get_mut().body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.body.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        header: Duration::from_secs(2),
        idle: Duration::from_secs(5),
    };

    #[test]
    fn the_deadline_follows_the_phase() {
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let a = Arc::new(Activity::new(t0));
        assert_eq!(a.deadline(LIMITS), Some(t0 + LIMITS.idle));

        a.read_some(at(1));
        assert_eq!(a.deadline(LIMITS), Some(at(1) + LIMITS.header));
        // More bytes of the same head move nothing.
        a.read_some(at(2));
        assert_eq!(a.deadline(LIMITS), Some(at(1) + LIMITS.header));

        a.begin_request();
        assert_eq!(a.deadline(LIMITS), None);
        // Body bytes while in flight start no head.
        a.read_some(at(3));
        assert_eq!(a.deadline(LIMITS), None);
        a.write_done(true, at(4));
        assert_eq!(a.deadline(LIMITS), Some(at(4) + LIMITS.idle));
        a.write_done(true, at(5));
        assert_eq!(a.deadline(LIMITS), Some(at(4) + LIMITS.idle));
        a.write_done(false, at(6));
        assert_eq!(a.deadline(LIMITS), None);

        a.request_done(at(9));
        assert_eq!(a.deadline(LIMITS), Some(at(9) + LIMITS.idle));
        // A blocked write counts even while idle (the last bytes of an answer).
        a.write_done(true, at(10));
        assert_eq!(a.deadline(LIMITS), Some(at(9) + LIMITS.idle));
    }

    #[test]
    fn the_refusal_is_a_complete_json_answer() {
        let wire = String::from_utf8(refusal(7)).unwrap();
        let (head, body) = wire.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 503 "));
        assert!(head.contains(&format!("content-length: {}", body.len())));
        let json: serde_json::Value = serde_json::from_str(body).unwrap();
        assert!(json["error"].as_str().unwrap().contains("limit of 7"));
        assert!(json["field"].is_null());
    }
}
