//! Faults behind HAProxy (ignored: needs `haproxy`): three `talkin serve` replicas of the
//! tiny run behind `deploy/haproxy.cfg` on 127.0.0.1, under closed-loop load from the
//! bench client, while one replica is SIGKILLed, all three are restarted one by one
//! (SIGTERM, start again), and one hangs (SIGSTOP, then SIGCONT). Each phase must answer
//! every request 200 with its own request id and the frame of its own pose (four poses,
//! checked byte for byte against a replica's answer before the load): 0 failed, 0 lost,
//! 0 wrong. Prints each phase's latency.
//!
//! `cargo test --test serve -- --ignored replicas_behind_haproxy --nocapture` (Debian's
//! `/usr/sbin/haproxy`, `haproxy` on PATH, or `$HAPROXY`); CI installs Debian's package.
//! About 40 s.

use std::net::{SocketAddr, TcpListener};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde_json::json;
use talkin::data::params_json::ParamsJson;
use talkin::serve::bench::{self, Load, LoadReport};
use talkin::serve::client;

use super::{WAIT, fixture, signal, subject};

/// HAProxy's timeout for one frame here: a hung replica's requests move on after it.
const FRAME_TIMEOUT: &str = "2s";
/// Each replica's drain delay: HAProxy checks every second and needs two failures.
const DRAIN_DELAY: &str = "2.5";
const CLIENTS: usize = 4;

/// A free port on 127.0.0.1 (free when asked; nothing else here binds ports at random).
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A `talkin serve` replica on a fixed port; killed (and continued first) when dropped.
struct Replica {
    addr: SocketAddr,
    child: Option<Child>,
}

impl Replica {
    fn start(port: u16) -> Replica {
        let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        let mut r = Replica { addr, child: None };
        r.restart();
        r
    }

    /// Starts the process (again) and waits until it is ready.
    fn restart(&mut self) {
        let child = Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(["serve", "--run"])
            .arg(&fixture().run)
            .args(["--addr", &self.addr.to_string(), "--workers", "1"])
            .args(["--size", "24x32", "--drain-delay", DRAIN_DELAY])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        self.child = Some(child);
        super::wait_until_ready(self.addr);
    }

    fn child(&self) -> &Child {
        self.child.as_ref().expect("the replica runs")
    }

    /// Waits for the process to exit; true if it exited 0.
    fn wait(&mut self) -> bool {
        let mut child = self.child.take().expect("the replica runs");
        child.wait().unwrap().success()
    }
}

impl Drop for Replica {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            signal(&child, "CONT");
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// HAProxy with `deploy/haproxy.cfg`, its addresses set through the environment.
struct Balancer {
    child: Child,
    addr: SocketAddr,
    stats: SocketAddr,
}

impl Balancer {
    fn start(replicas: &[Replica]) -> Balancer {
        // Debian installs it in /usr/sbin, which a user's PATH may lack.
        let haproxy = std::env::var("HAPROXY").unwrap_or_else(|_| {
            let debian = "/usr/sbin/haproxy";
            if Path::new(debian).exists() {
                debian
            } else {
                "haproxy"
            }
            .into()
        });
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/haproxy.cfg");
        let addr: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let stats: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        let mut command = Command::new(&haproxy);
        command
            .arg("-db")
            .arg("-f")
            .arg(&config)
            .env("TALKIN_LB", addr.to_string())
            .env("TALKIN_LB_STATS", stats.to_string())
            .env("TALKIN_FRAME_TIMEOUT", FRAME_TIMEOUT)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        for (i, r) in replicas.iter().enumerate() {
            command.env(format!("TALKIN_R{}", i + 1), r.addr.to_string());
        }
        let child = command
            .spawn()
            .unwrap_or_else(|e| panic!("starting `{haproxy}` (install Debian's haproxy): {e}"));
        let b = Balancer { child, addr, stats };
        b.wait_until_up(replicas.len());
        b
    }

    /// The `frames` backend's rows of HAProxy's stats CSV, split into fields.
    fn stats(&self, rows: &str) -> Vec<Vec<String>> {
        let Ok(r) = client::request(self.stats, "GET", "/;csv", None, WAIT) else {
            return Vec::new();
        };
        String::from_utf8_lossy(&r.body)
            .lines()
            .filter(|l| l.starts_with(rows))
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect()
    }

    /// The state HAProxy gives each server of the `frames` backend (UP, DOWN, ...).
    fn states(&self) -> Vec<String> {
        self.stats("frames,r")
            .into_iter()
            .filter_map(|row| row.get(17).cloned())
            .collect()
    }

    /// The `frames` backend's retries and redispatches so far (fields 15 and 16).
    fn retries(&self) -> (u64, u64) {
        let rows = self.stats("frames,BACKEND");
        let field = |i: usize| {
            rows.first()
                .and_then(|r| r.get(i))
                .and_then(|v| v.parse().ok())
                .unwrap_or(0)
        };
        (field(15), field(16))
    }

    /// Waits until HAProxy sees `n` replicas up.
    fn wait_until_up(&self, n: usize) {
        let t = Instant::now();
        while self.states().iter().filter(|s| *s == "UP").count() < n {
            assert!(t.elapsed() < WAIT, "HAProxy states: {:?}", self.states());
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Balancer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `poses` render requests whose frames all differ (the jaw and the body turn move).
fn bodies(poses: usize) -> Vec<Vec<u8>> {
    (0..poses)
        .map(|k| {
            let mut p = fixture().dataset.frames[0].params.clone();
            p.jaw_pose.x = 0.1 * k as f64;
            p.global_orient.y += 0.3 * k as f64;
            let body =
                json!({"subject": subject(), "params": p.to_json(), "width": 48, "height": 48});
            serde_json::to_vec(&body).unwrap()
        })
        .collect()
}

/// Runs closed-loop load through `balancer` while `fault` runs on this thread, then
/// stops the load; every request must have been answered right.
fn under_load(
    name: &str,
    balancer: &Balancer,
    bodies: &[Vec<u8>],
    frames: &[Vec<u8>],
    fault: impl FnOnce(),
) -> LoadReport {
    let stop = AtomicBool::new(false);
    let check = |i: usize, r: &client::HttpResponse| r.body == frames[i];
    let load = Load {
        path: "/render",
        bodies,
        clients: CLIENTS,
        requests: usize::MAX,
        timeout: WAIT,
        check: Some(&check),
        stop: Some(&stop),
    };
    let (retries, redispatches) = balancer.retries();
    let report = std::thread::scope(|s| {
        let running = s.spawn(|| bench::run_load(balancer.addr, &load));
        std::thread::sleep(Duration::from_secs(1));
        fault();
        std::thread::sleep(Duration::from_secs(1));
        stop.store(true, Ordering::SeqCst);
        running.join().unwrap()
    });
    let after = balancer.retries();
    eprintln!(
        "{name:<16} {:>5} requests  ok {:>5}  503 {}  failed {}  lost {}  wrong {}  {:>5.1} s  \
         {:>5.1} frames/s  p50 {:>5.0} ms  p99 {:>5.0} ms  max {:>5.0} ms  \
         (HAProxy: {} retries, {} redispatched)",
        report.requests,
        report.ok,
        report.refused,
        report.failed,
        report.lost,
        report.wrong,
        report.seconds,
        report.throughput,
        report.p50_ms,
        report.p99_ms,
        report.max_ms,
        after.0 - retries,
        after.1 - redispatches
    );
    assert!(report.requests > 0, "{name}: no request sent");
    assert_eq!(report.ok, report.requests, "{name}: {report:?}");
    report
}

#[test]
#[ignore = "needs haproxy"]
fn replicas_behind_haproxy_lose_nothing_when_one_dies_restarts_or_hangs() {
    let t0 = Instant::now();
    let mut replicas: Vec<Replica> = (0..3).map(|_| Replica::start(free_port())).collect();
    let balancer = Balancer::start(&replicas);
    let bodies = bodies(4);
    // The expected frames, straight from one replica.
    let frames: Vec<Vec<u8>> = bodies
        .iter()
        .map(|b| {
            let r = client::request(replicas[0].addr, "POST", "/render", Some(b), WAIT).unwrap();
            assert_eq!(r.status, 200);
            r.body
        })
        .collect();
    for i in 0..frames.len() {
        for j in 0..i {
            assert_ne!(frames[i], frames[j], "poses {i} and {j} render alike");
        }
    }
    eprintln!(
        "3 replicas behind HAProxy, {CLIENTS} closed-loop clients, 48x48 PNG frames, \
         frame timeout {FRAME_TIMEOUT}"
    );
    under_load("steady", &balancer, &bodies, &frames, || {
        std::thread::sleep(Duration::from_secs(2))
    });

    under_load("SIGKILL r1", &balancer, &bodies, &frames, || {
        signal(replicas[0].child(), "KILL");
        assert!(!replicas[0].wait());
        std::thread::sleep(Duration::from_secs(3));
    });
    replicas[0].restart();
    balancer.wait_until_up(3);

    under_load("rolling restart", &balancer, &bodies, &frames, || {
        for r in replicas.iter_mut() {
            signal(r.child(), "TERM");
            assert!(r.wait(), "a replica exits 0 after SIGTERM");
            r.restart();
            balancer.wait_until_up(3);
        }
    });

    under_load("SIGSTOP r2", &balancer, &bodies, &frames, || {
        signal(replicas[1].child(), "STOP");
        std::thread::sleep(Duration::from_secs(5));
        signal(replicas[1].child(), "CONT");
    });
    balancer.wait_until_up(3);
    eprintln!("behind HAProxy: {:.0} s in all", t0.elapsed().as_secs_f64());
}
