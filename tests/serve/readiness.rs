//! Readiness for a load balancer: `/health` answers 503 with its reason while the
//! checkpoint loads and while a shutdown drains (the server still serving meanwhile),
//! `/live` answers 200 throughout; every answer echoes the request's id; `bench serve
//! --target` benches a server by its URL.

use std::process::Command;
use std::time::{Duration, Instant};

use talkin::data::params_json::ParamsJson;
use talkin::serve::client::{self, HttpResponse};
use talkin::serve::{REQUEST_ID_HEADER, Readiness, ServeConfig, Server};

use super::{WAIT, config, fixture, frame_body, get, post, signal, spawn_cli_with};

fn assert_not_ready(r: &HttpResponse, status: &str) {
    assert_eq!(r.status, 503, "{r:?}");
    let json = r.json();
    assert_eq!(json["status"], status, "{json}");
    assert!(
        json["reason"].as_str().is_some_and(|s| !s.is_empty()),
        "{json}"
    );
}

#[test]
fn health_is_503_while_loading_and_while_draining_and_live_stays_200() {
    let drain = Duration::from_millis(800);
    let server = Server::bind(
        "127.0.0.1:0",
        ServeConfig {
            drain_delay: drain,
            ..config()
        },
    )
    .unwrap();
    let addr = server.addr();
    assert_eq!(server.readiness(), Readiness::Loading);
    assert_not_ready(&get(addr, "/health"), "loading");
    assert_eq!(get(addr, "/live").status, 200);
    let refused = post(addr, "/render", &frame_body());
    assert_eq!(refused.status, 503, "{refused:?}");
    assert_eq!(refused.header("retry-after"), Some("1"));
    assert!(
        refused.json()["error"]
            .as_str()
            .unwrap()
            .contains("loading")
    );
    assert_eq!(get(addr, "/subjects").status, 503);

    server.serve_avatar(fixture().avatar.clone(), None).unwrap();
    let health = get(addr, "/health");
    assert_eq!(health.status, 200);
    assert_eq!(health.json()["status"], "ok");
    assert!(health.json()["reason"].is_null());

    std::thread::scope(|s| {
        let t = Instant::now();
        let stopping = s.spawn(|| server.shutdown().unwrap());
        // Draining: the balancer's check sees 503 while requests are still served.
        let health = loop {
            let h = get(addr, "/health");
            if h.status != 200 || t.elapsed() > drain {
                break h;
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        assert_not_ready(&health, "draining");
        assert_eq!(post(addr, "/render", &frame_body()).status, 200);
        assert_eq!(get(addr, "/live").status, 200);
        stopping.join().unwrap();
        assert!(t.elapsed() >= drain, "{:?}", t.elapsed());
    });
    assert!(client::request(addr, "GET", "/live", None, Duration::from_secs(2)).is_err());
}

#[test]
fn every_answer_echoes_the_request_id() {
    let server = super::start(config());
    let addr = server.addr();
    let body = serde_json::to_vec(&frame_body()).unwrap();
    for (path, body, status) in [
        ("/render", Some(&body[..]), 200),
        ("/render", Some(&b"{"[..]), 400),
        ("/nowhere", None, 404),
    ] {
        let method = if body.is_some() { "POST" } else { "GET" };
        let headers = [(REQUEST_ID_HEADER, "abc-42")];
        let r = client::request_with_headers(addr, method, path, &headers, body, WAIT).unwrap();
        assert_eq!(r.status, status, "{path}");
        assert_eq!(r.header(REQUEST_ID_HEADER), Some("abc-42"), "{path}");
    }
    let r = post(addr, "/render", &frame_body());
    assert_eq!(r.header(REQUEST_ID_HEADER), None);
}

#[test]
fn sigterm_drains_before_the_listener_closes() {
    let (mut child, addr) = spawn_cli_with(&fixture().run, &["--drain-delay", "1"]);
    assert_eq!(get(addr, "/health").status, 200);
    signal(&child, "TERM");
    let t = Instant::now();
    let health = loop {
        let h = get(addr, "/health");
        if h.status != 200 || t.elapsed() > WAIT {
            break h;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    assert_not_ready(&health, "draining");
    assert_eq!(post(addr, "/render", &frame_body()).status, 200);
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
    assert!(
        t.elapsed() >= Duration::from_millis(900),
        "{:?}",
        t.elapsed()
    );
}

#[test]
fn bench_serve_benches_a_server_by_its_url() {
    let server = super::start(config());
    let url = format!("http://{}", server.addr());
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["bench", "serve", "--target", &url])
        .args(["--clients", "1,2", "--requests", "4"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Each row: clients, requests, ok, 503, failed, lost, wrong, ...
    let rows: Vec<Vec<&str>> = stdout
        .lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .filter(|w| w.len() == 11 && w[0].parse::<usize>().is_ok())
        .collect();
    assert_eq!(rows.len(), 2, "{stdout}");
    for row in rows {
        assert_eq!(&row[1..7], ["4", "4", "0", "0", "0", "0"], "{stdout}");
    }
    // 2 x 4 timed requests, one untimed, and the bench's GET /subjects (not a render).
    assert_eq!(get(server.addr(), "/health").json()["pool"]["completed"], 9);

    for (target, says) in [
        ("127.0.0.1:1", "--target"),
        ("https://127.0.0.1:1", "plain HTTP"),
        ("http://127.0.0.1:1/render", "--target"),
        ("http://127.0.0.1:1", "GET /subjects"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(["bench", "serve", "--target", target])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{target}: {stderr}");
        assert!(stderr.contains(says), "{target}: {stderr}");
        assert!(!stderr.contains("panicked"), "{target}: {stderr}");
    }
}

#[test]
fn a_job_whose_client_has_gone_is_skipped() {
    use std::io::Write;
    let server = super::start(ServeConfig {
        workers: 1,
        ..config()
    });
    let addr = server.addr();
    let p = fixture().dataset.frames[0].params.to_json();
    let long = serde_json::json!({"subject": super::subject(), "frames": vec![p; 8], "width": 48, "height": 48});
    std::thread::scope(|s| {
        let busy = s.spawn(|| post(addr, "/render/sequence", &long));
        super::wait_until_busy(addr, &|| busy.is_finished());
        // A render that queues behind it, whose client gives up (as the page's
        // AbortController does): the connection closes with the request unanswered.
        let body = serde_json::to_vec(&frame_body()).unwrap();
        let mut gone = std::net::TcpStream::connect(addr).unwrap();
        write!(
            gone,
            "POST /render HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
             Content-Length: {}\r\n\r\n",
            body.len()
        )
        .unwrap();
        gone.write_all(&body).unwrap();
        let t = Instant::now();
        while get(addr, "/health").json()["pool"]["queued"] != 1 {
            assert!(t.elapsed() < WAIT, "the render never queued");
            std::thread::sleep(Duration::from_millis(5));
        }
        drop(gone);
        assert_eq!(busy.join().unwrap().status, 200);
    });
    let t = Instant::now();
    while get(addr, "/health").json()["skipped_jobs"] != 1 {
        assert!(t.elapsed() < WAIT, "{}", get(addr, "/health").json());
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(get(addr, "/health").json()["pool"]["queued"], 0);
}
