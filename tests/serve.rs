//! The render server over real HTTP on 127.0.0.1: a tiny run trained here, frames equal to
//! the avatar's own renders, concurrent clients, every class of bad input answered with a
//! JSON error naming the field (and the server still serving), a full queue's 503, render
//! timeouts, graceful shutdown by call and by SIGTERM, the connection limits (`limits`),
//! posted BEAT2/AMASS motion files (`motion`), readiness for a load balancer and the load
//! benchmark against a URL (`readiness`), replicas behind HAProxy under faults (`deploy`,
//! ignored: needs haproxy),
//! and (ignored: needs chromium) the page in a headless browser.

mod common;
#[path = "serve/deploy.rs"]
mod deploy;
#[path = "serve/limits.rs"]
mod limits;
#[path = "serve/motion.rs"]
mod motion;
#[path = "serve/readiness.rs"]
mod readiness;

use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Barrier, OnceLock};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use talkin::avatar::Avatar;
use talkin::data::dataset::Dataset;
use talkin::data::params_json::ParamsJson;
use talkin::grids::SamplerKind;
use talkin::render::avatar::RenderFrame;
use talkin::serve::client::{self, HttpResponse};
use talkin::serve::{ServeConfig, Server};
use talkin::train::{TrainOptions, train};

const WAIT: Duration = Duration::from_secs(120);

struct Fixture {
    run: PathBuf,
    dataset: Dataset,
    avatar: Arc<Avatar>,
}

/// One tiny run for every test: 1 identity, 48 px, a few training steps.
fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dataset = common::synthetic_scene("serve_scene", 1, 48, 1);
        let run = common::temp_dir("serve_run");
        let opts = TrainOptions {
            batch_rays: 128,
            occ_every: 0,
            ..common::small_train_opts(SamplerKind::Accelerated, 3)
        };
        train(&dataset, &run, &opts, &mut |_| {}).unwrap();
        let avatar = Arc::new(Avatar::load(&run).unwrap());
        Fixture {
            run,
            dataset,
            avatar,
        }
    })
}

/// Small limits so the tests stay fast: default frames of 24 x 32.
fn config() -> ServeConfig {
    ServeConfig {
        workers: 2,
        queue: 16,
        max_body_bytes: 64 << 10,
        max_pixels: 64 * 64,
        max_sequence_frames: 12,
        default_width: 24,
        default_height: 32,
        ..ServeConfig::default()
    }
}

fn start(config: ServeConfig) -> Server {
    Server::start(fixture().avatar.clone(), "127.0.0.1:0", config).unwrap()
}

fn subject() -> String {
    fixture().dataset.subjects[0].name.clone()
}

fn get(addr: SocketAddr, path: &str) -> HttpResponse {
    client::request(addr, "GET", path, None, WAIT).unwrap()
}

fn post(addr: SocketAddr, path: &str, body: &Value) -> HttpResponse {
    let bytes = serde_json::to_vec(body).unwrap();
    client::request(addr, "POST", path, Some(&bytes), WAIT).unwrap()
}

/// Frame 0 of the dataset as a `/render` body.
fn frame_body() -> Value {
    let f = &fixture().dataset.frames[0];
    json!({
        "subject": subject(),
        "params": f.params.to_json(),
        "camera": {
            "width": f.camera.width,
            "height": f.camera.height,
            "intrinsics": f.camera.intrinsics_rows(),
            "extrinsics": f.camera.extrinsics_rows(),
        },
    })
}

fn decode_png(bytes: &[u8]) -> image::RgbImage {
    image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .expect("a PNG")
        .to_rgb8()
}

/// Asserts a JSON error with `status` whose `field` is `field`; says which case failed.
fn assert_error(case: &str, r: &HttpResponse, status: u16, field: Option<&str>) {
    let body = r.json();
    assert_eq!(
        r.status,
        status,
        "{case}: {}",
        String::from_utf8_lossy(&r.body)
    );
    assert_eq!(r.header("content-type"), Some("application/json"), "{case}");
    assert!(
        body["error"].as_str().is_some_and(|e| !e.is_empty()),
        "{case}: {body}"
    );
    assert_eq!(body["field"].as_str(), field, "{case}: {body}");
}

#[test]
fn health_subjects_and_page() {
    let server = start(config());
    let addr = server.addr();
    let health = get(addr, "/health");
    assert_eq!(health.status, 200);
    assert_eq!(health.json()["status"], "ok");
    assert_eq!(health.json()["pool"]["workers"], 2);

    let subjects = get(addr, "/subjects").json();
    let s = &subjects["subjects"][0];
    assert_eq!(s["name"], subject().as_str());
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(24), Some(32))
    );
    assert_eq!(s["camera"]["intrinsics"].as_array().map(Vec::len), Some(3));
    assert_eq!(subjects["limits"]["max_pixels"], 64 * 64);

    let page = get(addr, "/");
    assert_eq!(page.status, 200);
    assert!(
        page.header("content-type")
            .unwrap()
            .starts_with("text/html")
    );
    let html = String::from_utf8(page.body).unwrap();
    assert!(html.contains("type=\"range\"") && html.contains("/render"));
    // Nothing outside the server is reachable where this runs.
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"));

    assert_error("unknown route", &get(addr, "/nope"), 404, None);
    server.shutdown().unwrap();
}

#[test]
fn frames_equal_the_avatars_own_renders() {
    let fx = fixture();
    let server = start(config());
    let addr = server.addr();
    let f = &fx.dataset.frames[0];
    let expected = fx
        .avatar
        .render(0, &f.params, &f.camera, None)
        .unwrap()
        .to_image();

    let png = post(addr, "/render", &frame_body());
    assert_eq!(png.status, 200, "{}", String::from_utf8_lossy(&png.body));
    assert_eq!(png.header("content-type"), Some("image/png"));
    assert!(
        png.header("x-render-samples")
            .unwrap()
            .parse::<u64>()
            .unwrap()
            > 0
    );
    assert_eq!(decode_png(&png.body), expected);

    let mut raw_body = frame_body();
    raw_body["format"] = json!("raw");
    let raw = post(addr, "/render", &raw_body);
    assert_eq!(raw.status, 200);
    let width = f.camera.width.to_string();
    assert_eq!(raw.header("x-image-width"), Some(width.as_str()));
    assert_eq!(raw.body, expected.into_raw());

    // Resized camera; the subject's default camera.
    let mut resized = frame_body();
    resized["width"] = json!(32);
    resized["height"] = json!(40);
    let img = decode_png(&post(addr, "/render", &resized).body);
    assert_eq!(img.dimensions(), (32, 40));
    let mut default_camera = frame_body();
    default_camera.as_object_mut().unwrap().remove("camera");
    let r = post(addr, "/render", &default_camera);
    assert_eq!(decode_png(&r.body).dimensions(), (24, 32));
    server.shutdown().unwrap();
}

#[test]
fn concurrent_clients_get_identical_frames() {
    let server = start(config());
    let addr = server.addr();
    let body = serde_json::to_vec(&frame_body()).unwrap();
    let clients = 6;
    let barrier = Barrier::new(clients);
    let bodies: Vec<Vec<u8>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..clients)
            .map(|_| {
                s.spawn(|| {
                    barrier.wait();
                    (0..2)
                        .map(|_| {
                            let r = client::request(addr, "POST", "/render", Some(&body), WAIT)
                                .unwrap();
                            assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
                            r.body
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    assert_eq!(bodies.len(), 2 * clients);
    assert!(bodies.iter().all(|b| *b == bodies[0]));
    let health = get(addr, "/health").json();
    assert_eq!(health["pool"]["completed"], 2 * clients);
    server.shutdown().unwrap();
}

#[test]
fn bad_input_is_refused_with_the_field_and_the_server_keeps_serving() {
    let server = start(config());
    let addr = server.addr();
    let raw = |bytes: &[u8]| client::request(addr, "POST", "/render", Some(bytes), WAIT).unwrap();
    let with = |edit: &dyn Fn(&mut Value)| {
        let mut b = frame_body();
        edit(&mut b);
        b
    };

    assert_error("malformed JSON", &raw(b"{\"subject\": "), 400, None);
    assert_error("NaN literal", &raw(b"{\"subject\": NaN}"), 400, None);
    assert_error("not an object", &raw(b"[1, 2]"), 400, None);
    assert_error("empty body", &raw(b""), 400, None);
    let overflow = serde_json::to_string(&frame_body()).unwrap().replacen(
        "\"transl\":[",
        "\"transl\":[1e999,",
        1,
    );
    assert_error("number overflow", &raw(overflow.as_bytes()), 400, None);

    let cases: Vec<(&str, Value, u16, &str)> = vec![
        (
            "missing subject",
            with(&|b| {
                b.as_object_mut().unwrap().remove("subject");
            }),
            400,
            "subject",
        ),
        (
            "subject not a string",
            with(&|b| b["subject"] = json!(0)),
            400,
            "subject",
        ),
        (
            "unknown subject",
            with(&|b| b["subject"] = json!("nobody")),
            404,
            "subject",
        ),
        (
            "unknown field",
            with(&|b| b["widht"] = json!(10)),
            400,
            "widht",
        ),
        (
            "missing params",
            with(&|b| {
                b.as_object_mut().unwrap().remove("params");
            }),
            400,
            "params",
        ),
        (
            "missing params field",
            with(&|b| {
                b["params"].as_object_mut().unwrap().remove("jaw_pose");
            }),
            400,
            "params.jaw_pose",
        ),
        (
            "body_pose of 20 rows",
            with(&|b| {
                b["params"]["body_pose"].as_array_mut().unwrap().pop();
            }),
            400,
            "params.body_pose",
        ),
        (
            "a string in expression",
            with(&|b| b["params"]["expression"][2] = json!("x")),
            400,
            "params.expression[2]",
        ),
        (
            "a null in a pose",
            with(&|b| b["params"]["left_hand_pose"][4][1] = Value::Null),
            400,
            "params.left_hand_pose[4][1]",
        ),
        (
            "absurd translation",
            with(&|b| b["params"]["transl"][0] = json!(1e7)),
            400,
            "params.transl[0]",
        ),
        (
            "absurd finger",
            with(&|b| b["params"]["right_hand_pose"][3][2] = json!(-5e3)),
            400,
            "params.right_hand_pose[3][2]",
        ),
        (
            "bad format",
            with(&|b| b["format"] = json!("gif")),
            400,
            "format",
        ),
        (
            "zero width",
            with(&|b| {
                b["width"] = json!(0);
                b["height"] = json!(10);
            }),
            400,
            "width",
        ),
        (
            "negative width",
            with(&|b| {
                b["width"] = json!(-3);
                b["height"] = json!(10);
            }),
            400,
            "width",
        ),
        (
            "width without height",
            with(&|b| b["width"] = json!(10)),
            400,
            "height",
        ),
        (
            "absurd width",
            with(&|b| {
                b["width"] = json!(1_000_000);
                b["height"] = json!(10);
            }),
            413,
            "width",
        ),
        (
            "over the pixel limit",
            with(&|b| {
                b["width"] = json!(4000);
                b["height"] = json!(4000);
            }),
            413,
            "width",
        ),
        (
            "camera over the pixel limit",
            with(&|b| {
                b["camera"]["width"] = json!(1000);
            }),
            413,
            "camera.width",
        ),
        (
            "singular intrinsics",
            with(&|b| b["camera"]["intrinsics"][0][0] = json!(0.0)),
            400,
            "camera.intrinsics",
        ),
        (
            "camera without extrinsics",
            with(&|b| {
                b["camera"].as_object_mut().unwrap().remove("extrinsics");
            }),
            400,
            "camera.extrinsics",
        ),
        (
            "non-rotation extrinsics",
            with(&|b| b["camera"]["extrinsics"][0][0] = json!(3.0)),
            400,
            "camera.extrinsics",
        ),
        (
            "camera translation 1e300",
            with(&|b| b["camera"]["extrinsics"][0][3] = json!(1e300)),
            400,
            "camera.extrinsics",
        ),
        (
            "camera 2 km away",
            with(&|b| b["camera"]["extrinsics"][2][3] = json!(2000.0)),
            400,
            "camera.extrinsics",
        ),
        (
            "focal 1e300",
            with(&|b| b["camera"]["intrinsics"][0][0] = json!(1e300)),
            400,
            "camera.intrinsics",
        ),
        (
            "negative focal",
            with(&|b| b["camera"]["intrinsics"][1][1] = json!(-50.0)),
            400,
            "camera.intrinsics",
        ),
        (
            "focal of a hundredth of a pixel",
            with(&|b| b["camera"]["intrinsics"][0][0] = json!(0.01)),
            400,
            "camera.intrinsics",
        ),
        (
            "skew 1e12",
            with(&|b| b["camera"]["intrinsics"][0][1] = json!(1e12)),
            400,
            "camera.intrinsics",
        ),
        (
            "principal point far outside the image",
            with(&|b| b["camera"]["intrinsics"][0][2] = json!(1e9)),
            400,
            "camera.intrinsics",
        ),
        (
            "a resize that leaves the focal below a tenth of a pixel",
            with(&|b| {
                b["camera"]["intrinsics"][0][0] = json!(0.5);
                b["width"] = json!(1);
                b["height"] = json!(1);
            }),
            400,
            "width",
        ),
    ];
    for (case, body, status, field) in &cases {
        assert_error(case, &post(addr, "/render", body), *status, Some(field));
    }

    // Bodies over the limit, declared or not.
    let big = vec![b' '; 65 << 10];
    assert_error("body over the limit", &raw(&big), 413, None);
    let mut chunked = b"POST /render HTTP/1.1\r\nHost: x\r\nConnection: close\r\nTransfer-Encoding: chunked\r\n\r\n".to_vec();
    for _ in 0..70 {
        chunked.extend_from_slice(format!("{:x}\r\n", 1024).as_bytes());
        chunked.extend_from_slice(&[b' '; 1024]);
        chunked.extend_from_slice(b"\r\n");
    }
    chunked.extend_from_slice(b"0\r\n\r\n");
    let r = client::send_raw(addr, &chunked, WAIT).unwrap();
    assert_error("chunked body over the limit", &r, 413, None);
    // Not HTTP at all: hyper answers 400 and closes.
    let r = client::send_raw(addr, b"HELLO\r\n\r\n", WAIT);
    assert!(r.map_or(true, |r| r.status == 400));

    // Sequences.
    let f = &fixture().dataset.frames;
    let seq = |frames: Vec<Value>, extra: &dyn Fn(&mut Value)| {
        let mut b = json!({"subject": subject(), "frames": frames, "width": 16, "height": 16});
        extra(&mut b);
        b
    };
    let p = |i: usize| f[i].params.to_json();
    let mut bad_frame = p(1);
    bad_frame.as_object_mut().unwrap().remove("jaw_pose");
    let seq_cases: Vec<(&str, Value, u16, &str)> = vec![
        ("no frames", seq(vec![], &|_| {}), 400, "frames"),
        (
            "too many frames",
            seq(vec![p(0); 13], &|_| {}),
            413,
            "frames",
        ),
        (
            "a bad frame",
            seq(vec![p(0), bad_frame], &|_| {}),
            400,
            "frames[1].jaw_pose",
        ),
        (
            "smooth not a bool",
            seq(vec![p(0)], &|b| b["smooth"] = json!("yes")),
            400,
            "smooth",
        ),
    ];
    for (case, body, status, field) in &seq_cases {
        assert_error(
            case,
            &post(addr, "/render/sequence", body),
            *status,
            Some(field),
        );
    }

    // Still serving, and nothing was rendered for any of it.
    assert_eq!(get(addr, "/health").json()["pool"]["completed"], 0);
    assert_eq!(post(addr, "/render", &frame_body()).status, 200);
    server.shutdown().unwrap();
}

/// Cameras at the edges of what a request may ask render (background at worst), never 500.
#[test]
fn cameras_at_the_bounds_render() {
    let server = start(config());
    let addr = server.addr();
    let f = &fixture().dataset.frames[0];
    let (w, h) = (f64::from(f.camera.width), f64::from(f.camera.height));
    let rotation_and = |t: [f64; 3]| {
        let mut e = f.camera.extrinsics_rows();
        for (r, t) in t.iter().enumerate() {
            e[r][3] = *t;
        }
        e
    };
    let k = |fx: f64, skew: f64, cx: f64, cy: f64| [[fx, skew, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]];
    let cases: Vec<(&str, serde_json::Value, serde_json::Value)> = vec![
        (
            "999 m away",
            json!(rotation_and([0.0, 0.0, 999.0])),
            json!(f.camera.intrinsics_rows()),
        ),
        (
            "at the origin",
            json!(rotation_and([0.0; 3])),
            json!(f.camera.intrinsics_rows()),
        ),
        (
            "focal 0.1 px",
            json!(f.camera.extrinsics_rows()),
            json!(k(0.1, 0.0, w / 2.0, h / 2.0)),
        ),
        (
            "focal 1e6 px",
            json!(f.camera.extrinsics_rows()),
            json!(k(1e6, 1e6, w / 2.0, h / 2.0)),
        ),
        (
            "principal point one image outside",
            json!(f.camera.extrinsics_rows()),
            json!(k(50.0, 0.0, -w, 2.0 * h)),
        ),
    ];
    for (case, extrinsics, intrinsics) in cases {
        let mut body = frame_body();
        body["camera"]["extrinsics"] = extrinsics;
        body["camera"]["intrinsics"] = intrinsics;
        let r = post(addr, "/render", &body);
        assert_eq!(
            r.status,
            200,
            "{case}: {}",
            String::from_utf8_lossy(&r.body)
        );
    }
    server.shutdown().unwrap();
}

#[test]
fn sequences_come_back_as_a_zip_of_the_single_frames() {
    let server = start(config());
    let addr = server.addr();
    let f = &fixture().dataset.frames;
    let body = json!({
        "subject": subject(),
        "frames": [f[0].params.to_json(), f[1].params.to_json(), f[2].params.to_json()],
        "smooth": false,
    });
    let r = post(addr, "/render/sequence", &body);
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(r.header("content-type"), Some("application/zip"));
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(r.body)).unwrap();
    assert_eq!(zip.len(), 3);
    for i in 0..3 {
        let mut png = Vec::new();
        zip.by_name(&format!("frame_{i:05}.png"))
            .unwrap()
            .read_to_end(&mut png)
            .unwrap();
        let single = post(
            addr,
            "/render",
            &json!({"subject": subject(), "params": f[i].params.to_json()}),
        );
        assert_eq!(decode_png(&png), decode_png(&single.body), "frame {i}");
    }
    // Smoothed: the frames are the single renders of the library-smoothed poses.
    let raw: Vec<_> = (0..3).map(|i| f[i].params.clone()).collect();
    let smoothed =
        talkin::human::smooth::smooth_params(&raw, &talkin::human::smooth::Smoothing::PAPER)
            .unwrap();
    let r = post(
        addr,
        "/render/sequence",
        &json!({"subject": subject(), "frames": [f[0].params.to_json(), f[1].params.to_json(), f[2].params.to_json()], "smooth": true}),
    );
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(r.body)).unwrap();
    for (i, params) in smoothed.iter().enumerate() {
        let mut png = Vec::new();
        zip.by_name(&format!("frame_{i:05}.png"))
            .unwrap()
            .read_to_end(&mut png)
            .unwrap();
        let single = post(
            addr,
            "/render",
            &json!({"subject": subject(), "params": params.to_json()}),
        );
        assert_eq!(
            decode_png(&png),
            decode_png(&single.body),
            "smoothed frame {i}"
        );
    }
    server.shutdown().unwrap();
}

#[test]
fn a_full_queue_answers_503_with_retry_after() {
    let server = start(ServeConfig {
        workers: 1,
        queue: 1,
        ..config()
    });
    let addr = server.addr();
    // 8 frames per request keep the single worker busy far longer than it takes the other
    // clients to arrive.
    let p = fixture().dataset.frames[0].params.to_json();
    let body = serde_json::to_vec(&json!({
        "subject": subject(), "frames": vec![p; 8], "width": 48, "height": 48,
    }))
    .unwrap();
    let clients = 6;
    let barrier = Barrier::new(clients);
    let responses: Vec<HttpResponse> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..clients)
            .map(|_| {
                s.spawn(|| {
                    barrier.wait();
                    client::request(addr, "POST", "/render/sequence", Some(&body), WAIT).unwrap()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let ok = responses.iter().filter(|r| r.status == 200).count();
    let full: Vec<_> = responses.iter().filter(|r| r.status == 503).collect();
    assert_eq!(ok + full.len(), clients, "only 200 or 503");
    assert!(
        (1..=2).contains(&ok),
        "one running, one queued: {ok} succeeded"
    );
    for r in &full {
        assert_error("queue full", r, 503, None);
        let retry: u64 = r.header("retry-after").unwrap().parse().unwrap();
        assert!(retry >= 1);
    }
    // Once the queue drains, requests succeed again.
    assert_eq!(post(addr, "/render", &frame_body()).status, 200);
    server.shutdown().unwrap();
}

#[test]
fn a_slow_render_answers_504_and_the_server_keeps_serving() {
    let server = start(ServeConfig {
        render_timeout: Duration::from_millis(1),
        ..config()
    });
    let addr = server.addr();
    let r = post(addr, "/render", &frame_body());
    assert_error("timeout", &r, 504, None);
    assert_eq!(get(addr, "/health").status, 200);
    server.shutdown().unwrap();
}

/// A `talkin serve` child process, killed if a test ends without stopping it.
struct CliServer(std::process::Child);

impl Drop for CliServer {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

impl std::ops::Deref for CliServer {
    type Target = std::process::Child;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl std::ops::DerefMut for CliServer {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

/// Starts `talkin serve` on a free port and returns it with its address.
fn spawn_cli(run: &Path) -> (CliServer, SocketAddr) {
    spawn_cli_with(run, &[])
}

/// [`spawn_cli`] with more options.
fn spawn_cli_with(run: &Path, extra: &[&str]) -> (CliServer, SocketAddr) {
    let mut child = CliServer(
        Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(["serve", "--run"])
            .arg(run)
            .args(["--addr", "127.0.0.1:0", "--workers", "1", "--size", "24x32"])
            .args(extra)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    stderr.read_line(&mut line).unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no address in {line:?}"));
    // Keep draining stderr so the child never blocks on a full pipe.
    std::thread::spawn(move || std::io::copy(&mut stderr, &mut std::io::sink()));
    wait_until_ready(addr);
    (child, addr)
}

/// Waits until `/health` answers 200: the listener is up before the checkpoint loads.
fn wait_until_ready(addr: SocketAddr) {
    let start = Instant::now();
    loop {
        let r = client::request(addr, "GET", "/health", None, WAIT);
        match r {
            Ok(r) if r.status == 200 => return,
            Ok(r) => assert_eq!(r.json()["status"], "loading", "{r:?}"),
            Err(_) => {}
        }
        assert!(start.elapsed() < WAIT, "{addr} never became ready");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits until the server has a job on a worker (or the request already finished).
fn wait_until_busy(addr: SocketAddr, done: &dyn Fn() -> bool) {
    let start = Instant::now();
    while !done() && start.elapsed() < WAIT {
        if get(addr, "/health").json()["pool"]["busy"] == 1 {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn shutdown_finishes_requests_in_flight() {
    let server = start(config());
    let addr = server.addr();
    let p = fixture().dataset.frames[0].params.to_json();
    let body = json!({"subject": subject(), "frames": vec![p; 6], "width": 48, "height": 48});
    std::thread::scope(|s| {
        let request = s.spawn(|| post(addr, "/render/sequence", &body));
        wait_until_busy(addr, &|| request.is_finished());
        server.shutdown().unwrap();
        let r = request.join().unwrap();
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    });
    assert!(client::request(addr, "GET", "/health", None, Duration::from_secs(2)).is_err());
}

#[test]
fn sigterm_stops_the_cli_server_after_its_requests() {
    let (mut child, addr) = spawn_cli(&fixture().run);
    assert_eq!(get(addr, "/health").status, 200);
    let p = fixture().dataset.frames[0].params.to_json();
    let body = json!({"subject": subject(), "frames": vec![p; 6], "width": 48, "height": 48});
    std::thread::scope(|s| {
        let request = s.spawn(|| post(addr, "/render/sequence", &body));
        wait_until_busy(addr, &|| request.is_finished());
        signal(&child, "TERM");
        let r = request.join().unwrap();
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    });
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
}

/// `cargo test --test serve -- --ignored page_in_headless_chromium`: loads the page in
/// headless Chromium (`chromium` on PATH, or `$CHROMIUM`) with `?selftest`, which does
/// what a user does and checks the pixels: moves the jaw slider, drags the view (the
/// full-size frame after it must differ), then plays the motion the server offers and
/// counts the distinct frames that arrive, in order. Writes screenshots of the orbited
/// view (`?selftest=orbit`) and of a played motion's frame to the target tmp dir.
#[test]
#[ignore = "needs chromium"]
fn page_in_headless_chromium() {
    let server = start(ServeConfig {
        max_pixels: 256 * 256,
        default_width: 72,
        default_height: 96,
        ..config()
    });
    // 60 frames at 30 fps: 8 frames at the 4 fps the self-test plays.
    let (motion, _) = motion::beat2("page", 60);
    let named = talkin::serve::motion::read_named(&[motion]).unwrap();
    server.add_motions(named).unwrap();
    let profile = common::temp_dir("serve_chromium_profile");
    let headless = |test: &str, extra: &[&str]| {
        let url = format!("http://{}/?selftest={test}", server.addr());
        let flags = [
            "--disable-gpu",
            // Virtual time only advances while nothing loads, so the render requests
            // finish before the budget runs out.
            "--virtual-time-budget=120000",
            "--window-size=900,760",
        ];
        common::browser::headless_chromium(&url, &profile, &[&flags[..], extra].concat())
    };
    let verdict = |dom: &str| {
        dom.split("data-selftest=\"")
            .nth(1)
            .and_then(|s| s.split('"').next())
            .unwrap_or_else(|| panic!("the self-test did not finish: {dom}"))
            .replace("&quot;", "\"")
    };
    let full = verdict(&headless("all", &["--dump-dom"]));
    assert!(full.starts_with("pass"), "{full}");
    let orbit = verdict(&headless("orbit", &["--dump-dom"]));
    assert!(orbit.starts_with("pass"), "{orbit}");
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let mut shots = Vec::new();
    for (test, name) in [
        ("orbit", "serve_page_orbit.png"),
        ("all", "serve_page_motion.png"),
    ] {
        let shot = tmp.join(name);
        let _ = std::fs::remove_file(&shot);
        headless(test, &[&format!("--screenshot={}", shot.display())]);
        assert!(std::fs::metadata(&shot).unwrap().len() > 0);
        shots.push(shot.display().to_string());
    }
    eprintln!("page self-test: {full}\norbit: {orbit}\nscreenshots: {shots:?}");
    server.shutdown().unwrap();
}

/// Sends signal `name` (`TERM`, `KILL`, `STOP`, `CONT`) to `child` with `kill`.
fn signal(child: &std::process::Child, name: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{name}"), &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill -{name} {}", child.id());
}
