//! A bounded load test: `clients` threads post the same request until `requests` have been
//! sent, each waiting for its answer before the next (closed loop), so the number of
//! requests in flight is exactly the client count.

use std::net::SocketAddr;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::client;

/// Throughput and latency at one concurrency.
#[derive(Clone, Debug, Serialize)]
pub struct LoadReport {
    pub clients: usize,
    pub requests: usize,
    /// 200 answers.
    pub ok: usize,
    /// 503 answers (queue full).
    pub refused: usize,
    /// Other statuses and connection errors.
    pub failed: usize,
    pub seconds: f64,
    /// Successful requests per second of wall time.
    pub throughput: f64,
    /// Latency percentiles of the successful requests (milliseconds).
    pub p50_ms: f64,
    pub p99_ms: f64,
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
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(u16, f64)>> = Mutex::new(Vec::with_capacity(requests));
    let start = Instant::now();
    std::thread::scope(|s| {
        for _ in 0..clients.max(1) {
            s.spawn(|| {
                while next.fetch_add(1, Ordering::Relaxed) < requests {
                    let t = Instant::now();
                    let status = client::request(addr, "POST", path, Some(body), timeout)
                        .map_or(0, |r| r.status);
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    results.lock().unwrap().push((status, ms));
                }
            });
        }
    });
    let seconds = start.elapsed().as_secs_f64();
    let results = results.into_inner().unwrap();
    let mut ok_ms: Vec<f64> = results
        .iter()
        .filter(|(s, _)| *s == 200)
        .map(|(_, ms)| *ms)
        .collect();
    ok_ms.sort_by(f64::total_cmp);
    let refused = results.iter().filter(|(s, _)| *s == 503).count();
    LoadReport {
        clients,
        requests,
        ok: ok_ms.len(),
        refused,
        failed: results.len() - ok_ms.len() - refused,
        seconds,
        throughput: ok_ms.len() as f64 / seconds,
        p50_ms: percentile(&ok_ms, 0.50),
        p99_ms: percentile(&ok_ms, 0.99),
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
    let mut out =
        String::from("clients  requests  ok  503  failed  seconds  frames/s  p50 ms  p99 ms\n");
    for r in reports {
        out += &format!(
            "{:>7}  {:>8}  {:>2}  {:>3}  {:>6}  {:>7.2}  {:>8.2}  {:>6.1}  {:>6.1}\n",
            r.clients,
            r.requests,
            r.ok,
            r.refused,
            r.failed,
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
