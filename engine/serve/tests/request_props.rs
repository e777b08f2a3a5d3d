//! Property tests of the request parser (`talkin_serve::request`): on arbitrary bytes, on
//! valid requests with one value swapped for a hostile one, and on valid request text with
//! bytes spliced in, it never panics, and whatever it accepts is finite and within the
//! documented bounds.
//!
//! 64 cases per property by default, from a fixed seed; `PROPTEST_CASES=N` runs more and
//! `PROPTEST_RNG_SEED=S` picks another seed (see docs/server-api.md).

#[path = "../../data/tests/support/proptest_config.rs"]
mod proptest_config;

use glam::DVec3;
use proptest::prelude::*;
use proptest_config::config;
use serde_json::{Value, json};
use talkin_data::params_json::ParamsJson;
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;
use talkin_serve::request::{
    self, CAMERA_DISTANCE_LIMIT, FOCAL_RANGE_PX, PARAM_LIMIT, RenderRequest, SequenceRequest,
};
use talkin_serve::{ServeConfig, ServedSubject};

fn subjects() -> Vec<ServedSubject> {
    let camera = Camera::look_at(
        144,
        192,
        200.0,
        DVec3::new(0.0, 1.0, 3.2),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::Y,
    )
    .unwrap();
    vec![ServedSubject {
        name: "ada".into(),
        index: 0,
        default_camera: camera,
        orbit_target: DVec3::new(0.0, 1.0, 0.0),
    }]
}

fn serve_config() -> ServeConfig {
    ServeConfig {
        max_pixels: 512 * 512,
        ..ServeConfig::default()
    }
}

fn camera_json(c: &Camera) -> Value {
    json!({
        "width": c.width,
        "height": c.height,
        "intrinsics": c.intrinsics_rows(),
        "extrinsics": c.extrinsics_rows(),
    })
}

/// A valid `/render` body using every member.
fn valid_render() -> Value {
    let mut params = FrameParams::default();
    params.jaw_pose.x = 0.3;
    params.expression[1] = -1.0;
    json!({
        "subject": "ada",
        "params": params.to_json(),
        "camera": camera_json(&subjects()[0].default_camera),
        "width": 72,
        "height": 96,
        "format": "raw",
    })
}

/// A valid `/render/sequence` body using every member.
fn valid_sequence() -> Value {
    let mut bent = FrameParams::default();
    bent.body_pose[17].z = 1.2;
    json!({
        "subject": "ada",
        "frames": [FrameParams::default().to_json(), bent.to_json()],
        "camera": camera_json(&subjects()[0].default_camera),
        "width": 72,
        "height": 96,
        "smooth": true,
    })
}

/// Paths to every value of `v` (object keys and array indices), containers included.
fn paths(v: &Value, here: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    out.push(here.clone());
    match v {
        Value::Object(m) => {
            for (k, child) in m {
                here.push(Step::Key(k.clone()));
                paths(child, here, out);
                here.pop();
            }
        }
        Value::Array(a) => {
            for (i, child) in a.iter().enumerate() {
                here.push(Step::Index(i));
                paths(child, here, out);
                here.pop();
            }
        }
        _ => {}
    }
}

#[derive(Clone, Debug)]
enum Step {
    Key(String),
    Index(usize),
}

fn at<'a>(v: &'a mut Value, path: &[Step]) -> &'a mut Value {
    path.iter().fold(v, |v, step| match step {
        Step::Key(k) => &mut v[k.as_str()],
        Step::Index(i) => &mut v[*i],
    })
}

/// Values a hostile client might put anywhere.
fn hostile() -> impl Strategy<Value = Value> {
    prop_oneof![
        prop::sample::select(vec![
            1e300,
            -1e300,
            1e308,
            -1e308,
            1.7e308,
            3.4e38,
            1e-300,
            5e-324,
            0.0,
            -0.0,
            1e3,
            1000.000001,
            -1e6,
            1e9,
            16384.0,
            16385.0,
            0.1,
            0.099,
            1e6,
            1.000001e6,
        ])
        .prop_map(|x| json!(x)),
        any::<f64>().prop_map(|x| json!(x)),
        (-3.0..3.0f64).prop_map(|x| json!(x)),
        any::<i64>().prop_map(|x| json!(x)),
        any::<u64>().prop_map(|x| json!(x)),
        prop::sample::select(vec![
            Value::Null,
            json!(true),
            json!("ada"),
            json!("png"),
            json!(""),
            json!([]),
            json!({}),
            json!([[1e300]]),
            json!([0.0, 0.0]),
            json!([0.0, 0.0, 0.0, 0.0]),
            json!({"subject": "ada"}),
        ]),
    ]
}

/// A valid body with the value at one path (under the top-level member `under`, if given)
/// replaced by a hostile one.
fn mutated(valid: Value, under: Option<&str>) -> impl Strategy<Value = Vec<u8>> {
    let mut all = Vec::new();
    paths(&valid, &mut Vec::new(), &mut all);
    all.retain(|p| match (under, p.first()) {
        (None, _) => true,
        (Some(member), Some(Step::Key(k))) => k == member,
        _ => false,
    });
    (prop::sample::select(all), hostile()).prop_map(move |(path, value)| {
        let mut body = valid.clone();
        *at(&mut body, &path) = value;
        serde_json::to_vec(&body).unwrap()
    })
}

/// A valid body's text with some bytes replaced by number-ish or arbitrary ones.
fn spliced(valid: Value) -> impl Strategy<Value = Vec<u8>> {
    let text = serde_json::to_vec(&valid).unwrap();
    let len = text.len();
    let insert = prop_oneof![
        prop::sample::select(vec![
            b"1e999".to_vec(),
            b"-1e400".to_vec(),
            b"NaN".to_vec(),
            b"Infinity".to_vec(),
            b"1e300".to_vec(),
            b"-0".to_vec(),
            b"18446744073709551616".to_vec(),
            b"\"".to_vec(),
            b"]".to_vec(),
            b"\\u0000".to_vec(),
        ]),
        prop::collection::vec(any::<u8>(), 0..8),
    ];
    (0..len, 0..4usize, insert).prop_map(move |(at, cut, insert)| {
        let mut out = text[..at].to_vec();
        out.extend_from_slice(&insert);
        out.extend_from_slice(&text[(at + cut).min(len)..]);
        out
    })
}

fn within(x: f64, limit: f64) -> bool {
    x.is_finite() && x.abs() <= limit
}

fn params_ok(p: &FrameParams) -> bool {
    let values = [
        p.global_orient,
        p.jaw_pose,
        p.leye_pose,
        p.reye_pose,
        p.transl,
    ]
    .into_iter()
    .chain(p.body_pose)
    .chain(p.left_hand_pose)
    .chain(p.right_hand_pose)
    .flat_map(|v| v.to_array())
    .chain(p.expression);
    p.is_finite() && values.into_iter().all(|x| within(x, PARAM_LIMIT))
}

fn camera_ok(c: &Camera) -> bool {
    let k = c.intrinsics_rows();
    c.intrinsics.is_finite()
        && c.camera_from_world.is_finite()
        && within(c.center_in_world().length(), CAMERA_DISTANCE_LIMIT)
        && FOCAL_RANGE_PX.contains(&k[0][0])
        && FOCAL_RANGE_PX.contains(&k[1][1])
        && u64::from(c.width) * u64::from(c.height) <= serve_config().max_pixels
}

/// The property: no panic (proptest reports one as a failure), and an accepted request is
/// finite and within bounds.
fn check(body: &[u8]) -> Result<(), TestCaseError> {
    let (subjects, config) = (subjects(), serve_config());
    if let Ok(RenderRequest { params, camera, .. }) =
        request::parse_render(body, &subjects, &config)
    {
        prop_assert!(params_ok(&params), "accepted params {params:?}");
        prop_assert!(camera_ok(&camera), "accepted camera {camera:?}");
    }
    if let Ok(SequenceRequest { frames, camera, .. }) =
        request::parse_sequence(body, &subjects, &config)
    {
        prop_assert!(frames.iter().all(params_ok), "accepted frames {frames:?}");
        prop_assert!(camera_ok(&camera), "accepted camera {camera:?}");
    }
    Ok(())
}

#[test]
fn the_valid_bodies_are_accepted() {
    let (subjects, config) = (subjects(), serve_config());
    let render = serde_json::to_vec(&valid_render()).unwrap();
    request::parse_render(&render, &subjects, &config).unwrap();
    let sequence = serde_json::to_vec(&valid_sequence()).unwrap();
    request::parse_sequence(&sequence, &subjects, &config).unwrap();
}

proptest! {
    #![proptest_config(config(0x7a1c_5e12))]

    #[test]
    fn arbitrary_bytes(body in prop::collection::vec(any::<u8>(), 0..512)) {
        check(&body)?;
    }

    #[test]
    fn render_bodies_with_a_hostile_value(body in mutated(valid_render(), None)) {
        check(&body)?;
    }

    #[test]
    fn render_cameras_with_a_hostile_value(body in mutated(valid_render(), Some("camera"))) {
        check(&body)?;
    }

    #[test]
    fn sequence_bodies_with_a_hostile_value(body in mutated(valid_sequence(), None)) {
        check(&body)?;
    }

    #[test]
    fn render_text_with_bytes_spliced_in(body in spliced(valid_render())) {
        check(&body)?;
    }

    #[test]
    fn sequence_text_with_bytes_spliced_in(body in spliced(valid_sequence())) {
        check(&body)?;
    }
}
