//! The server's connection limits over raw TCP: a client that trickles its headers is cut
//! off, idle connections are closed, connections beyond the cap are answered 503 while
//! the ones within are served, and shutdown ends within its grace period whatever the
//! clients do; the CLI refuses options it cannot run with, naming the flag.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::json;
use talkin::data::params_json::ParamsJson;
use talkin::serve::ServeConfig;

use super::{WAIT, config, fixture, frame_body, get, post, signal, spawn_cli_with, start, subject};

fn connect(addr: SocketAddr) -> TcpStream {
    let stream = TcpStream::connect_timeout(&addr, WAIT).unwrap();
    stream.set_read_timeout(Some(WAIT)).unwrap();
    stream
}

/// Whether the server has closed `stream` (EOF or reset) by now, waiting at most `wait`.
fn closed_within(stream: &mut TcpStream, wait: Duration) -> bool {
    stream.set_read_timeout(Some(wait)).unwrap();
    let mut byte = [0u8; 1];
    match stream.read(&mut byte) {
        Ok(0) => true,
        Ok(_) => panic!("the server sent data to a client that asked for nothing"),
        Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => false,
        Err(_) => true,
    }
}

/// One keep-alive `GET path` on `stream`: (status, head, body).
fn keep_alive_get(stream: &mut TcpStream, path: &str) -> (u16, String, Vec<u8>) {
    write!(stream, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    read_answer(stream)
}

/// Reads one answer with a `content-length` off `stream`.
fn read_answer(stream: &mut TcpStream) -> (u16, String, Vec<u8>) {
    let mut bytes = Vec::new();
    let mut buf = [0u8; 4096];
    let head_end = loop {
        if let Some(i) = bytes.windows(4).position(|w| w == b"\r\n\r\n") {
            break i;
        }
        let n = stream.read(&mut buf).unwrap();
        assert!(
            n > 0,
            "closed mid-answer: {:?}",
            String::from_utf8_lossy(&bytes)
        );
        bytes.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8(bytes[..head_end].to_vec()).unwrap();
    let length: usize = head
        .lines()
        .find_map(|l| {
            l.to_ascii_lowercase()
                .strip_prefix("content-length:")
                .map(|v| v.trim().parse().unwrap())
        })
        .expect("a content-length");
    let mut body = bytes[head_end + 4..].to_vec();
    while body.len() < length {
        let n = stream.read(&mut buf).unwrap();
        assert!(n > 0, "closed mid-body");
        body.extend_from_slice(&buf[..n]);
    }
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    (status, head, body)
}

#[test]
fn a_client_that_trickles_its_headers_is_cut_off_after_the_header_timeout() {
    let header = Duration::from_millis(400);
    let server = start(ServeConfig {
        header_timeout: header,
        idle_timeout: Duration::from_secs(30),
        ..config()
    });
    let mut stream = connect(server.addr());
    let start = Instant::now();
    let wire =
        b"GET /health HTTP/1.1\r\nHost: x\r\nX-Slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa";
    let mut cut = None;
    for byte in wire.iter().cycle().take(200) {
        // One byte every 50 ms: never idle, never done.
        if stream.write_all(&[*byte]).is_err()
            || closed_within(&mut stream, Duration::from_millis(50))
        {
            cut = Some(start.elapsed());
            break;
        }
    }
    let cut = cut.expect("the trickling client was never cut off");
    eprintln!("trickling client cut off after {cut:?} (header timeout {header:?})");
    assert!(
        cut >= header && cut < header + Duration::from_secs(2),
        "cut off after {cut:?}"
    );
    // Everyone else is still served.
    assert_eq!(get(server.addr(), "/health").status, 200);
    server.shutdown().unwrap();
}

#[test]
fn idle_connections_are_closed_after_the_idle_timeout() {
    let idle = Duration::from_millis(200);
    let server = start(ServeConfig {
        idle_timeout: idle,
        header_timeout: Duration::from_secs(30),
        ..config()
    });
    let addr = server.addr();
    // Silent from the start.
    let mut silent = connect(addr);
    let t = Instant::now();
    assert!(closed_within(&mut silent, WAIT), "never closed");
    let waited = t.elapsed();
    eprintln!("silent connection closed after {waited:?} (idle timeout {idle:?})");
    assert!(
        waited >= idle && waited < idle + Duration::from_secs(2),
        "closed after {waited:?}"
    );

    // Silent after an answer on a kept-alive connection; a second request in time is
    // served on the same connection.
    let mut kept = connect(addr);
    assert_eq!(keep_alive_get(&mut kept, "/health").0, 200);
    std::thread::sleep(idle / 3);
    assert_eq!(keep_alive_get(&mut kept, "/health").0, 200);
    let t = Instant::now();
    assert!(closed_within(&mut kept, WAIT), "never closed");
    let waited = t.elapsed();
    eprintln!("kept-alive connection closed {waited:?} after its answer (idle timeout {idle:?})");
    assert!(
        waited >= idle / 2 && waited < idle + Duration::from_secs(2),
        "closed after {waited:?}"
    );

    // A request in flight for longer than the idle timeout is not idle.
    let p = fixture().dataset.frames[0].params.to_json();
    let body = json!({"subject": subject(), "frames": vec![p; 12], "width": 48, "height": 48});
    let t = Instant::now();
    let r = post(addr, "/render/sequence", &body);
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    eprintln!(
        "a 12-frame sequence took {:?} (idle timeout {idle:?})",
        t.elapsed()
    );
    server.shutdown().unwrap();
}

#[test]
fn connections_beyond_the_cap_are_refused_and_those_within_are_served() {
    let server = start(ServeConfig {
        max_connections: 3,
        ..config()
    });
    let addr = server.addr();
    let mut held: Vec<TcpStream> = (0..3).map(|_| connect(addr)).collect();
    // The server has accepted all three once one of them sees three open.
    let t = Instant::now();
    loop {
        let (status, _, body) = keep_alive_get(&mut held[0], "/health");
        assert_eq!(status, 200);
        let health: serde_json::Value = serde_json::from_slice(&body).unwrap();
        assert_eq!(health["connections"]["max"], 3);
        if health["connections"]["open"] == 3 {
            break;
        }
        assert!(t.elapsed() < WAIT, "{health}");
        std::thread::sleep(Duration::from_millis(10));
    }

    let mut extra = connect(addr);
    let (status, head, body) = read_answer(&mut extra);
    assert_eq!(status, 503);
    assert!(
        head.to_ascii_lowercase().contains("retry-after: 1"),
        "{head}"
    );
    let error: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert!(
        error["error"].as_str().unwrap().contains("limit of 3"),
        "{error}"
    );
    assert!(error["field"].is_null());
    assert!(closed_within(&mut extra, WAIT));

    // Within the cap, the server answers as usual.
    for stream in &mut held {
        assert_eq!(keep_alive_get(stream, "/health").0, 200);
    }
    // A closed connection frees its slot.
    held.pop();
    let t = Instant::now();
    while client_get(addr).is_none_or(|status| status != 200) {
        assert!(t.elapsed() < WAIT, "the freed slot never came back");
        std::thread::sleep(Duration::from_millis(10));
    }
    server.shutdown().unwrap();
}

/// `GET /health` on a new connection: its status, or None if the connection was refused
/// before an answer could be read.
fn client_get(addr: SocketAddr) -> Option<u16> {
    talkin::serve::client::request(addr, "GET", "/health", None, WAIT)
        .ok()
        .map(|r| r.status)
}

/// A request cut off in its headers, and one cut off in its body.
fn half_sent_requests(addr: SocketAddr) -> Vec<TcpStream> {
    let mut head = connect(addr);
    head.write_all(b"POST /render HTTP/1.1\r\nHost: x\r\nContent-Le")
        .unwrap();
    let mut body = connect(addr);
    body.write_all(b"POST /render HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n{\"subj")
        .unwrap();
    vec![head, body]
}

#[test]
fn shutdown_ends_within_its_grace_period_while_clients_hold_half_sent_requests() {
    let grace = Duration::from_millis(300);
    let server = start(ServeConfig {
        shutdown_grace: grace,
        header_timeout: Duration::from_secs(60),
        idle_timeout: Duration::from_secs(60),
        body_timeout: Duration::from_secs(60),
        ..config()
    });
    let addr = server.addr();
    let mut clients = half_sent_requests(addr);
    // Both requests have reached the server before it is told to stop.
    let t = Instant::now();
    while get(addr, "/health").json()["connections"]["open"] != 3 {
        assert!(t.elapsed() < WAIT);
        std::thread::sleep(Duration::from_millis(10));
    }
    let (done_tx, done) = mpsc::channel();
    let t = Instant::now();
    std::thread::spawn(move || done_tx.send(server.shutdown()));
    let report = done
        .recv_timeout(grace + Duration::from_secs(5))
        .expect("shutdown waited on the half-sent requests")
        .unwrap();
    let took = t.elapsed();
    eprintln!("shutdown with half-sent requests took {took:?} (grace {grace:?})");
    assert!(
        took < grace + Duration::from_secs(2),
        "shutdown took {took:?}"
    );
    assert!(report.dropped_connections >= 1, "{report:?}");
    for c in &mut clients {
        assert!(closed_within(c, WAIT));
    }
}

#[test]
fn sigterm_ends_the_cli_server_within_its_grace_period() {
    let (mut child, addr) = spawn_cli_with(
        &fixture().run,
        &[
            "--shutdown-grace",
            "0.3",
            "--header-timeout",
            "60",
            "--idle-timeout",
            "60",
        ],
    );
    let _clients = half_sent_requests(addr);
    assert_eq!(get(addr, "/health").status, 200);
    signal(&child, "TERM");
    let t = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if t.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            panic!("the server did not exit within 10 s of SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{status}");
    eprintln!("SIGTERM to exit: {:?} (grace 0.3 s)", t.elapsed());
    assert!(
        t.elapsed() < Duration::from_secs(3),
        "exit took {:?}",
        t.elapsed()
    );
}

#[test]
fn unknown_routes_and_wrong_methods_answer_json() {
    let server = start(config());
    let addr = server.addr();
    let request = |method: &str, path: &str| {
        talkin::serve::client::request(addr, method, path, None, WAIT).unwrap()
    };
    super::assert_error("unknown route", &request("GET", "/nope"), 404, None);
    super::assert_error(
        "unknown POST route",
        &request("POST", "/render/nope"),
        404,
        None,
    );
    for (method, path, allow) in [
        ("GET", "/render", "POST"),
        ("GET", "/render/sequence", "POST"),
        ("POST", "/health", "GET,HEAD"),
        ("DELETE", "/", "GET,HEAD"),
        ("PUT", "/subjects", "GET,HEAD"),
    ] {
        let r = request(method, path);
        super::assert_error(&format!("{method} {path}"), &r, 405, None);
        assert_eq!(r.header("allow"), Some(allow), "{method} {path}");
        let error = r.json()["error"].as_str().unwrap().to_string();
        assert!(error.contains(method) && error.contains(path), "{error}");
    }
    assert_eq!(post(addr, "/render", &frame_body()).status, 200);
    server.shutdown().unwrap();
}

/// Runs `talkin serve` with `args` on a run that does not exist: the options are checked
/// first, so it must fail on them. Returns the exit code and stderr.
fn serve_cli(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args([
            "serve",
            "--run",
            "/nonexistent/run",
            "--addr",
            "127.0.0.1:0",
        ])
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_cli_refuses_bad_options_naming_the_flag_without_panicking() {
    let cases: &[(&[&str], &str)] = &[
        (&["--timeout", "1e300"], "--timeout"),
        (&["--timeout", "NaN"], "--timeout"),
        (&["--timeout", "inf"], "--timeout"),
        (&["--timeout=-1"], "--timeout"),
        (&["--timeout", "0"], "--timeout"),
        (&["--header-timeout", "1e300"], "--header-timeout"),
        (&["--idle-timeout", "nan"], "--idle-timeout"),
        (&["--shutdown-grace=-0.5"], "--shutdown-grace"),
        (&["--shutdown-grace", "1e20"], "--shutdown-grace"),
        (&["--drain-delay=-1"], "--drain-delay"),
        (&["--drain-delay", "nan"], "--drain-delay"),
        (&["--motion", "/nonexistent/walk.npz"], "--motion"),
        (&["--max-connections", "0"], "--max-connections"),
        (&["--queue", "18446744073709551615"], "--queue"),
        (&["--workers", "0"], "--workers"),
        (&["--workers", "100000000"], "--workers"),
        (&["--max-pixels", "0"], "--max-pixels"),
        (&["--size", "0x0"], "--size"),
        (&["--size", "99999999999x1"], "--size"),
        (&["--max-body-bytes", "0"], "--max-body-bytes"),
        // The model file is read before the run, so a bad one is named first.
        (
            &["--body-model", "/nonexistent/SMPLX_NEUTRAL.npz"],
            "body model /nonexistent/SMPLX_NEUTRAL.npz",
        ),
    ];
    for (args, flag) in cases {
        let (code, stderr) = serve_cli(args);
        assert_eq!(code, Some(1), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert!(
            stderr.contains(flag),
            "{args:?} does not name {flag}: {stderr}"
        );
    }
    // Good options get as far as loading the run.
    let (code, stderr) = serve_cli(&["--timeout", "0.5", "--shutdown-grace", "0"]);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("/nonexistent/run"), "{stderr}");
}
