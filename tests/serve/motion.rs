//! `POST /render/sequence` with a motion file as the body: BEAT2 and AMASS `.npz` files
//! written as the tools write them come back as the same zip the JSON form gives for the
//! same prepared poses (also resampled), with the motion's notes in `X-Talkin-Notes`; bad
//! files, bad query values and oversized bodies are refused with the field named. The
//! page's player gets a motion's prepared poses (`/motion/poses`) by name or by upload.

use std::io::Read;
use std::net::SocketAddr;
use std::path::Path;

use serde_json::{Value, json};
use talkin::data::array::NdArray;
use talkin::data::motion::{Prepare, read_motion};
use talkin::data::npz::NpzWriter;
use talkin::data::params_json::ParamsJson;
use talkin::serve::client::{self, HttpResponse};

use super::common::{npz_text, write_beat2};
use super::{WAIT, assert_error, config, fixture, get, post, start, subject};

/// Small pose values that differ per frame and column.
fn poses(n: usize, cols: usize) -> Vec<f32> {
    (0..n * cols)
        .map(|k| ((k * 7) % 23) as f32 * 0.01 - 0.1)
        .collect()
}

/// An AMASS SMPL-X file of `n` frames at 60 fps (z up).
fn write_amass(file: &Path, n: usize) {
    let p: Vec<f64> = poses(n, 165).iter().map(|&x| f64::from(x)).collect();
    let mut w = NpzWriter::create(file).unwrap();
    w.array("poses", &NdArray::f64(&[n, 165], p).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], vec![0.1; 3 * n]).unwrap())
        .unwrap()
        .array("betas", &NdArray::f64(&[16], vec![0.0; 16]).unwrap())
        .unwrap()
        .array("surface_model_type", &npz_text("smplx"))
        .unwrap()
        .array("mocap_frame_rate", &NdArray::f64(&[], vec![60.0]).unwrap())
        .unwrap();
    w.finish().unwrap();
}

/// `name` in a directory shared by this file's tests (each test names its own files).
fn file(name: &str) -> std::path::PathBuf {
    static DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| crate::common::temp_dir("serve_motion"))
        .join(name)
}

/// A BEAT2 file of `n` frames named after `tag`, and its bytes.
pub(super) fn beat2(tag: &str, n: usize) -> (std::path::PathBuf, Vec<u8>) {
    let f = file(&format!("{tag}_beat2_{n}.npz"));
    write_beat2(&f, n, poses(n, 165));
    let bytes = std::fs::read(&f).unwrap();
    (f, bytes)
}

/// Posts `body` as `content_type` to `/render/sequence?query`.
fn post_motion(addr: SocketAddr, query: &str, content_type: &str, body: &[u8]) -> HttpResponse {
    let head = format!(
        "POST /render/sequence?{query} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\
         Content-Type: {content_type}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    let mut wire = head.into_bytes();
    wire.extend_from_slice(body);
    client::send_raw(addr, &wire, WAIT).unwrap()
}

fn pngs(r: &HttpResponse) -> Vec<Vec<u8>> {
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(r.header("content-type"), Some("application/zip"));
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(r.body.clone())).unwrap();
    (0..zip.len())
        .map(|i| {
            let mut png = Vec::new();
            zip.by_name(&format!("frame_{i:05}.png"))
                .unwrap()
                .read_to_end(&mut png)
                .unwrap();
            png
        })
        .collect()
}

/// The JSON form's frames for `file` prepared as `talkin render --motion` prepares it.
fn json_form_pngs(addr: SocketAddr, file: &Path, fps: Option<f64>) -> Vec<Vec<u8>> {
    let (_, model) = fixture().avatar.subject(&subject()).unwrap();
    let prepared = read_motion(file, None)
        .unwrap()
        .prepare(&Prepare {
            subject: &model.skeleton,
            model: None,
            fps,
            keep_trans: false,
        })
        .unwrap();
    let frames: Vec<Value> = prepared.frames.iter().map(|p| p.to_json()).collect();
    pngs(&post(
        addr,
        "/render/sequence",
        &json!({"subject": subject(), "frames": frames}),
    ))
}

#[test]
fn motion_files_render_as_the_json_form_of_their_prepared_poses() {
    let server = start(config());
    let addr = server.addr();
    let q = format!("subject={}", subject());

    // BEAT2, 5 frames at the file's 30 fps: the notes say the hands are kept as given.
    let (f, bytes) = beat2("good", 5);
    let r = post_motion(addr, &q, "application/octet-stream", &bytes);
    let got = pngs(&r);
    assert_eq!(got.len(), 5);
    assert_eq!(got, json_form_pngs(addr, &f, None));
    let notes = r.header("x-talkin-notes").unwrap_or_default();
    assert!(notes.contains("mean hand"), "{notes:?}");

    // Resampled to 15 fps: frames at 0, 2 and 4.
    let r = post_motion(addr, &format!("{q}&fps=15"), "application/x-npz", &bytes);
    let got = pngs(&r);
    assert_eq!(got.len(), 3);
    assert_eq!(got, json_form_pngs(addr, &f, Some(15.0)));

    // AMASS, z up, absolute hands: no notes.
    let a = file("amass.npz");
    write_amass(&a, 4);
    let r = post_motion(addr, &q, "application/zip", &std::fs::read(&a).unwrap());
    let got = pngs(&r);
    assert_eq!(got.len(), 4);
    assert_eq!(got, json_form_pngs(addr, &a, None));
    assert_eq!(r.header("x-talkin-notes"), None);

    // The JSON form is unchanged beside it.
    let f0 = fixture().dataset.frames[0].params.to_json();
    let r = post(
        addr,
        "/render/sequence",
        &json!({"subject": subject(), "frames": [f0.clone(), f0]}),
    );
    assert_eq!(pngs(&r).len(), 2);
    server.shutdown().unwrap();
}

#[test]
fn bad_motion_requests_are_refused_naming_the_field() {
    let server = start(config());
    let addr = server.addr();
    let q = format!("subject={}", subject());
    let (_, bytes) = beat2("bad", 5);
    let octet = "application/octet-stream";
    let refused = |case: &str, query: &str, body: &[u8], status: u16, field: &str| {
        let r = post_motion(addr, query, octet, body);
        assert_error(case, &r, status, Some(field));
    };

    refused("truncated", &q, &bytes[..bytes.len() / 2], 400, "motion");
    refused("not a zip", &q, b"hello", 400, "motion");
    let mut nan = poses(3, 165);
    nan[165 + 4] = f32::NAN;
    let f = file("nan.npz");
    write_beat2(&f, 3, nan);
    refused(
        "NaN pose",
        &q,
        &std::fs::read(&f).unwrap(),
        400,
        "motion.poses",
    );
    let mut huge = poses(3, 165);
    huge[3] = 1e9;
    write_beat2(&f, 3, huge);
    refused(
        "huge pose",
        &q,
        &std::fs::read(&f).unwrap(),
        400,
        "motion[0].body_pose[0][0]",
    );
    refused("unknown subject", "subject=nobody", &bytes, 404, "subject");
    refused("no subject", "fps=15", &bytes, 400, "subject");
    for fps in ["0", "-3", "NaN", "inf", "1e12", "fast"] {
        refused(
            &format!("fps={fps}"),
            &format!("{q}&fps={fps}"),
            &bytes,
            400,
            "fps",
        );
    }
    refused("layout", &format!("{q}&layout=bvh"), &bytes, 400, "layout");
    refused(
        "keep_trans",
        &format!("{q}&keep_trans=maybe"),
        &bytes,
        400,
        "keep_trans",
    );
    refused("typo", &format!("{q}&widht=10"), &bytes, 400, "widht");
    refused(
        "width alone",
        &format!("{q}&width=10"),
        &bytes,
        400,
        "height",
    );
    refused(
        "too wide",
        &format!("{q}&width=64&height=128"),
        &bytes,
        413,
        "width",
    );
    // Frames over max_sequence_frames (12): in the file, or after resampling.
    let (_, long) = beat2("bad", 13);
    refused("13 frames", &q, &long, 413, "motion");
    refused("resampled", &format!("{q}&fps=90"), &bytes, 413, "fps");
    // A body over max_body_bytes (64 KiB).
    refused("oversized", &q, &vec![0u8; 80 << 10], 413, "motion");

    // Still serving.
    assert_eq!(pngs(&post_motion(addr, &q, octet, &bytes)).len(), 5);
    server.shutdown().unwrap();
}

#[test]
fn motion_poses_come_by_name_or_from_an_upload_and_bad_uploads_name_the_field() {
    use talkin::serve::motion::read_named;
    let server = start(config());
    let addr = server.addr();
    let (f, bytes) = beat2("poses", 31);
    server.add_motions(read_named(&[f]).unwrap()).unwrap();
    let listed = get(addr, "/motions").json();
    assert_eq!(listed["motions"][0]["name"], "poses_beat2_31", "{listed}");
    assert_eq!(listed["motions"][0]["frames"], 31);
    assert_eq!(listed["motions"][0]["fps"], 30.0);

    let q = format!("subject={}&fps=10", subject());
    let served = get(addr, &format!("/motion/poses?name=poses_beat2_31&{q}"));
    assert_eq!(
        served.status,
        200,
        "{}",
        String::from_utf8_lossy(&served.body)
    );
    let served = served.json();
    // 31 frames at 30 fps are 1 s: 11 frames at 10 fps.
    assert_eq!(served["frames"].as_array().unwrap().len(), 11, "{served}");
    assert_eq!(served["fps"], 10.0);
    let r = client::request_with_headers(
        addr,
        "POST",
        &format!("/motion/poses?{q}"),
        &[("Content-Type", "application/octet-stream")],
        Some(&bytes),
        WAIT,
    )
    .unwrap();
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(r.json()["frames"], served["frames"]);
    // Each pose renders as a frame.
    let params = served["frames"][5].clone();
    let frame = post(
        addr,
        "/render",
        &json!({"subject": subject(), "params": params}),
    );
    assert_eq!(frame.status, 200);

    let post_as = |query: &str, content_type: &str, body: &[u8]| {
        client::request_with_headers(
            addr,
            "POST",
            &format!("/motion/poses?{query}"),
            &[("Content-Type", content_type)],
            Some(body),
            WAIT,
        )
        .unwrap()
    };
    let cases = [
        (
            "no npz",
            post_as(&q, "application/octet-stream", b"not a zip"),
            400,
            "motion",
        ),
        (
            "json",
            post_as(&q, "application/json", b"{}"),
            400,
            "motion",
        ),
        (
            "empty",
            post_as(&q, "application/octet-stream", b""),
            400,
            "motion",
        ),
        (
            "fps",
            post_as(
                &format!("subject={}&fps=0", subject()),
                "application/octet-stream",
                &bytes,
            ),
            400,
            "fps",
        ),
        (
            "subject",
            post_as("fps=10", "application/octet-stream", &bytes),
            400,
            "subject",
        ),
        (
            "name",
            post_as(&format!("{q}&name=x"), "application/octet-stream", &bytes),
            400,
            "name",
        ),
        (
            "no name",
            get(addr, &format!("/motion/poses?{q}")),
            400,
            "name",
        ),
        (
            "unknown name",
            get(addr, &format!("/motion/poses?name=nope&{q}")),
            404,
            "name",
        ),
    ];
    for (case, r, status, field) in cases {
        assert_error(case, &r, status, Some(field));
    }
    let (_, large_bytes) = beat2("long", 60);
    let too_many = post_as(
        &format!("subject={}", subject()),
        "application/octet-stream",
        &large_bytes,
    );
    assert_error("too many frames", &too_many, 413, Some("motion"));
    server.shutdown().unwrap();
}
