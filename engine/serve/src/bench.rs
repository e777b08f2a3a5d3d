//! A bounded load test: `clients` threads post requests until `requests` have been sent
//! (or until told to stop), each waiting for its answer before the next (closed loop), so
//! the number of requests in flight is exactly the client count.
//!
//! Every request carries its own `x-request-id`; an answer that does not echo it, or whose
//! body fails the caller's check, counts as `wrong` (behind a balancer that retries, a
//! mixed-up connection would show here), never as a success.

use std::net::SocketAddr;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use talkin_data::params_json::ParamsJson;
use talkin_human::body::FrameParams;

use super::client::{self, HttpResponse};
use super::routes::REQUEST_ID_HEADER;

/// Decides whether a 200 answer to `bodies[i]` is the right one (its frame, say).
pub type AnswerCheck<'a> = &'a (dyn Fn(usize, &HttpResponse) -> bool + Sync);

/// What a load test sends.
#[derive(Clone, Copy)]
pub struct Load<'a> {
    /// Path every request is posted to.
    pub path: &'a str,
    /// The bodies, posted in turn: request `n` posts `bodies[n % bodies.len()]`.
    pub bodies: &'a [Vec<u8>],
    pub clients: usize,
    /// Most requests to send.
    pub requests: usize,
    /// Longest a client waits for one answer (then the request counts as lost).
    pub timeout: Duration,
    /// Checks each 200 answer beyond its request id (None: any body will do).
    pub check: Option<AnswerCheck<'a>>,
    /// Once set, clients send no more requests (those in flight are still counted).
    pub stop: Option<&'a AtomicBool>,
}

/// Throughput and latency at one concurrency.
#[derive(Clone, Debug, Serialize)]
pub struct LoadReport {
    pub clients: usize,
    /// Requests sent (each is counted once below).
    pub requests: usize,
    /// 200 answers to the request they were sent for.
    pub ok: usize,
    /// 503 answers (queue full).
    pub refused: usize,
    /// Other statuses.
    pub failed: usize,
    /// No answer: the connection failed, closed early or timed out.
    pub lost: usize,
    /// 200 answers carrying another request's id, or a body the check refused.
    pub wrong: usize,
    pub seconds: f64,
    /// Successful requests per second of wall time.
    pub throughput: f64,
    /// Latency percentiles of the successful requests (milliseconds).
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

/// What became of one request.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Ok,
    Refused,
    Failed,
    Lost,
    Wrong,
}

/// Posts `body` to `path` on `addr`, `requests` times from `clients` concurrent clients.
pub fn load_test(
    addr: SocketAddr,
    path: &str,
    body: &[u8],
    clients: usize,
    requests: usize,
    timeout: Duration,
) -> LoadReport {
    run_load(
        addr,
        &Load {
            path,
            bodies: &[body.to_vec()],
            clients,
            requests,
            timeout,
            check: None,
            stop: None,
        },
    )
}

/// Runs `load` against `addr` and reports what came back.
pub fn run_load(addr: SocketAddr, load: &Load) -> LoadReport {
    assert!(!load.bodies.is_empty(), "a load test needs a body to send");
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(Outcome, f64)>> =
        Mutex::new(Vec::with_capacity(load.requests.min(1 << 16)));
    // Ids unique across runs too, so an answer left over from another run cannot pass.
    let tag = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let stopped = || load.stop.is_some_and(|s| s.load(Ordering::SeqCst));
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..load.clients.max(1) {
            s.spawn(|| {
                loop {
                    if stopped() {
                        break;
                    }
                    let n = next.fetch_add(1, Ordering::Relaxed);
                    if n >= load.requests {
                        break;
                    }
                    let i = n % load.bodies.len();
                    let id = format!("{tag:x}-{n}");
                    let t = Instant::now();
                    let answer = client::request_with_headers(
                        addr,
                        "POST",
                        load.path,
                        &[(REQUEST_ID_HEADER, &id)],
                        Some(&load.bodies[i]),
                        load.timeout,
                    );
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    let outcome = match answer {
                        Err(_) => Outcome::Lost,
                        Ok(r) if r.status == 503 => Outcome::Refused,
                        Ok(r) if r.status != 200 => Outcome::Failed,
                        Ok(r) => {
                            let right = r.header(REQUEST_ID_HEADER) == Some(id.as_str())
                                && load.check.is_none_or(|check| check(i, &r));
                            if right { Outcome::Ok } else { Outcome::Wrong }
                        }
                    };
                    results.lock().unwrap().push((outcome, ms));
                }
            });
        }
    });
    let seconds = start.elapsed().as_secs_f64();
    let results = results.into_inner().unwrap();
    let count = |o: Outcome| results.iter().filter(|(r, _)| *r == o).count();
    let mut ok_ms: Vec<f64> = results
        .iter()
        .filter(|(r, _)| *r == Outcome::Ok)
        .map(|(_, ms)| *ms)
        .collect();
    ok_ms.sort_by(f64::total_cmp);
    LoadReport {
        clients: load.clients,
        requests: results.len(),
        ok: ok_ms.len(),
        refused: count(Outcome::Refused),
        failed: count(Outcome::Failed),
        lost: count(Outcome::Lost),
        wrong: count(Outcome::Wrong),
        seconds,
        throughput: ok_ms.len() as f64 / seconds,
        p50_ms: percentile(&ok_ms, 0.50),
        p99_ms: percentile(&ok_ms, 0.99),
        max_ms: ok_ms.last().copied().unwrap_or(f64::NAN),
    }
}

/// Nearest-rank percentile of sorted values (NaN when empty).
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// The reports as a table.
pub fn format_report(reports: &[LoadReport]) -> String {
    let mut out = String::from(
        "clients  requests    ok  503  failed  lost  wrong  seconds  frames/s  p50 ms  p99 ms\n",
    );
    for r in reports {
        out += &format!(
            "{:>7}  {:>8}  {:>4}  {:>3}  {:>6}  {:>4}  {:>5}  {:>7.2}  {:>8.2}  {:>6.1}  {:>6.1}\n",
            r.clients,
            r.requests,
            r.ok,
            r.refused,
            r.failed,
            r.lost,
            r.wrong,
            r.seconds,
            r.throughput,
            r.p50_ms,
            r.p99_ms
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::percentile;

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.5), 50.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert!(percentile(&[], 0.5).is_nan());
    }
}

/// What [`bench_render`] measured: the subject and frame size it asked for, and a report
/// per client count.
#[derive(Clone, Debug, Serialize)]
pub struct RenderBench {
    pub subject: String,
    pub width: u32,
    pub height: u32,
    pub reports: Vec<LoadReport>,
}

/// Why [`bench_render`] could not start: the server did not name a subject to render.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("GET /subjects from {what}: {source}")]
    Subjects {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("GET /subjects from {what} answered {status}: {body}")]
    Status {
        what: String,
        status: u16,
        body: String,
    },
    #[error("{what} serves no subject")]
    NoSubject { what: String },
}

/// The render server's load bench (`talkin bench serve`): asks the server at `addr` (named
/// `what` in errors) for its first subject, then posts one frame of it (the rest pose,
/// the jaw a little open) as a PNG of `size` (default: the subject's own): once untimed
/// (first-touch allocations and page faults), then `requests` times at each client count
/// in `clients`, each client waiting up to `timeout` for an answer.
pub fn bench_render(
    addr: SocketAddr,
    what: &str,
    size: Option<(u32, u32)>,
    clients: &[usize],
    requests: usize,
    timeout: Duration,
) -> Result<RenderBench, BenchError> {
    let answer = client::request(addr, "GET", "/subjects", None, timeout).map_err(|source| {
        BenchError::Subjects {
            what: what.to_string(),
            source,
        }
    })?;
    if answer.status != 200 {
        return Err(BenchError::Status {
            what: what.to_string(),
            status: answer.status,
            body: String::from_utf8_lossy(&answer.body).into_owned(),
        });
    }
    let first = &answer.json()["subjects"][0];
    let subject = first["name"]
        .as_str()
        .ok_or_else(|| BenchError::NoSubject {
            what: what.to_string(),
        })?
        .to_string();
    let (width, height) = size.unwrap_or((
        first["width"].as_u64().unwrap_or(0) as u32,
        first["height"].as_u64().unwrap_or(0) as u32,
    ));
    let mut params = FrameParams::default();
    params.jaw_pose.x = 0.2;
    let body = serde_json::to_vec(&serde_json::json!({
        "subject": subject,
        "params": params.to_json(),
        "width": width,
        "height": height,
    }))
    .expect("a JSON value serialises");
    load_test(addr, "/render", &body, 1, 1, timeout);
    let reports = clients
        .iter()
        .map(|&c| load_test(addr, "/render", &body, c, requests, timeout))
        .collect();
    Ok(RenderBench {
        subject,
        width,
        height,
        reports,
    })
}
