//! Parsing and validating request bodies. The `params` and `camera` objects are the
//! dataset's (parsed by the same code as `dataset.json`), so an error names the field path
//! exactly as a dataset error would (`params.body_pose[3][1]`).

use serde_json::{Map, Value};

use super::config::ServeConfig;
use super::error::RequestError;
use super::subjects::ServedSubject;
use talkin_data::dataset::parse_camera;
use talkin_data::json_shape::{self, ShapeError};
use talkin_data::params_json::{ParamsJson, check_param_limits};
use talkin_human::body::FrameParams;
use talkin_human::camera::{Camera, MAX_SIDE};

pub use talkin_data::params_json::PARAM_LIMIT;

/// Farthest a request camera's centre may be from the world origin (metres). The figure
/// stands within a few metres of it: a camera beyond sees nothing and, far enough out,
/// overflows the renderer's f32 rays.
pub const CAMERA_DISTANCE_LIMIT: f64 = 1e3;
/// Focal lengths (`fx`, `fy`) a request camera may have, in pixels (also after `width` and
/// `height` rescale it). Below, the view is wider than a half-space; above, a pixel covers
/// less than a micro-radian.
pub const FOCAL_RANGE_PX: std::ops::RangeInclusive<f64> = 0.1..=1e6;
/// Largest magnitude of K's skew, in pixels.
pub const SKEW_LIMIT_PX: f64 = 1e6;
/// How far, in image sizes, the principal point may lie beyond the image's edges.
pub const PRINCIPAL_POINT_MARGIN: f64 = 1.0;

/// How a frame comes back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `image/png`.
    Png,
    /// Row-major 8-bit RGB, `application/octet-stream`, size in `x-image-width/height`.
    Raw,
}

/// A valid `POST /render` body.
#[derive(Clone, Debug)]
pub struct RenderRequest {
    pub subject: usize,
    pub params: FrameParams,
    pub camera: Camera,
    pub format: Format,
}

/// A valid `POST /render/sequence` body.
#[derive(Clone, Debug)]
pub struct SequenceRequest {
    pub subject: usize,
    pub frames: Vec<FrameParams>,
    pub camera: Camera,
    /// Temporal smoothing of the poses asked for (Gaussian window 5, sigma 1).
    pub smooth: bool,
}

impl From<ShapeError> for RequestError {
    fn from(e: ShapeError) -> Self {
        RequestError::invalid(e.field.clone(), e.to_string())
    }
}

/// Parses `POST /render`: `{subject, params, camera?, width?, height?, format?}`.
pub fn parse_render(
    body: &[u8],
    subjects: &[ServedSubject],
    config: &ServeConfig,
) -> Result<RenderRequest, RequestError> {
    let doc = parse_json(body)?;
    let obj = only_keys(
        &doc,
        &["subject", "params", "camera", "width", "height", "format"],
    )?;
    let subject = subject(obj, subjects)?;
    let format = match obj.get("format") {
        None | Some(Value::Null) => Format::Png,
        Some(v) => match json_shape::string(v, "format")? {
            "png" => Format::Png,
            "raw" => Format::Raw,
            other => {
                return Err(RequestError::invalid(
                    "format",
                    format!("field `format`: expected \"png\" or \"raw\", found {other:?}"),
                ));
            }
        },
    };
    let camera = camera(obj, subject, config)?;
    let params = params(json_shape::member(&doc, "", "params")?, "params")?;
    Ok(RenderRequest {
        subject: subject.index,
        params,
        camera,
        format,
    })
}

/// Parses `POST /render/sequence`: `{subject, frames: [params...], camera?, width?,
/// height?, smooth?}`.
pub fn parse_sequence(
    body: &[u8],
    subjects: &[ServedSubject],
    config: &ServeConfig,
) -> Result<SequenceRequest, RequestError> {
    let doc = parse_json(body)?;
    let obj = only_keys(
        &doc,
        &["subject", "frames", "camera", "width", "height", "smooth"],
    )?;
    let subject = subject(obj, subjects)?;
    let camera = camera(obj, subject, config)?;
    let frames_json = json_shape::member(&doc, "", "frames")?;
    let Some(items) = frames_json.as_array().filter(|a| !a.is_empty()) else {
        return Err(RequestError::invalid(
            "frames",
            "field `frames`: expected a non-empty array of `params` objects",
        ));
    };
    if items.len() > config.max_sequence_frames {
        return Err(RequestError::too_large(
            "frames",
            format!(
                "field `frames`: {} frames, more than the {} a sequence may have",
                items.len(),
                config.max_sequence_frames
            ),
        ));
    }
    let frames = items
        .iter()
        .enumerate()
        .map(|(i, v)| params(v, &format!("frames[{i}]")))
        .collect::<Result<Vec<_>, _>>()?;
    let smooth = match obj.get("smooth") {
        None | Some(Value::Null) => false,
        Some(Value::Bool(b)) => *b,
        Some(_) => {
            return Err(RequestError::invalid(
                "smooth",
                "field `smooth`: expected true or false",
            ));
        }
    };
    Ok(SequenceRequest {
        subject: subject.index,
        frames,
        camera,
        smooth,
    })
}

fn parse_json(body: &[u8]) -> Result<Value, RequestError> {
    serde_json::from_slice(body).map_err(|e| RequestError::Invalid {
        field: None,
        message: format!(
            "malformed JSON at line {} column {}: {e}",
            e.line(),
            e.column()
        ),
    })
}

/// The top-level object, refusing keys it does not know (a typo such as `widht` would
/// otherwise be silently ignored).
fn only_keys<'a>(doc: &'a Value, known: &[&str]) -> Result<&'a Map<String, Value>, RequestError> {
    let Value::Object(obj) = doc else {
        return Err(RequestError::Invalid {
            field: None,
            message: "the body must be a JSON object".into(),
        });
    };
    if let Some(k) = obj.keys().find(|k| !known.contains(&k.as_str())) {
        return Err(RequestError::invalid(
            k.clone(),
            format!("unknown field `{k}`; expected some of {}", known.join(", ")),
        ));
    }
    Ok(obj)
}

pub(crate) fn subject<'a>(
    obj: &Map<String, Value>,
    subjects: &'a [ServedSubject],
) -> Result<&'a ServedSubject, RequestError> {
    let v = obj
        .get("subject")
        .ok_or_else(|| RequestError::invalid("subject", "field `subject`: missing"))?;
    let name = json_shape::string(v, "subject")?;
    subjects
        .iter()
        .find(|s| s.name == name)
        .ok_or_else(|| RequestError::NotFound {
            field: Some("subject".into()),
            message: format!(
                "unknown subject `{name}`; served: {}",
                subjects
                    .iter()
                    .map(|s| format!("`{}`", s.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
}

/// The request's camera (or the subject's default), resized to `width` x `height` if
/// given, within the server's pixel limit.
pub(crate) fn camera(
    obj: &Map<String, Value>,
    subject: &ServedSubject,
    config: &ServeConfig,
) -> Result<Camera, RequestError> {
    let side = |k: &str| -> Result<Option<u32>, RequestError> {
        let Some(v) = obj.get(k).filter(|v| !v.is_null()) else {
            return Ok(None);
        };
        let n = json_shape::index(v, k)?;
        if n == 0 || n > MAX_SIDE as usize {
            let message = format!("field `{k}`: {n} is not in 1..={MAX_SIDE}");
            return Err(if n == 0 {
                RequestError::invalid(k, message)
            } else {
                RequestError::too_large(k, message)
            });
        }
        Ok(Some(n as u32))
    };
    let size = match (side("width")?, side("height")?) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        (Some(_), None) => {
            return Err(RequestError::invalid(
                "height",
                "field `height`: missing (give width and height together)",
            ));
        }
        (None, Some(_)) => {
            return Err(RequestError::invalid(
                "width",
                "field `width`: missing (give width and height together)",
            ));
        }
    };
    let (base, path) = match obj.get("camera").filter(|v| !v.is_null()) {
        Some(v) => {
            let camera = parse_camera(v, "camera").map_err(|e| match e {
                Ok(degenerate) => RequestError::invalid(
                    format!("camera.{}", degenerate.field),
                    format!(
                        "field `camera.{}`: {}",
                        degenerate.field, degenerate.problem
                    ),
                ),
                Err(shape) => shape.into(),
            })?;
            sensible_view(&camera, "camera.extrinsics")?;
            sensible_intrinsics(&camera, "camera.intrinsics")?;
            (camera, "camera.width")
        }
        None => (subject.default_camera, "width"),
    };
    let (field, camera) = match size {
        Some((w, h)) => {
            let camera = resized(&base, w, h)?;
            sensible_intrinsics(&camera, "width")?;
            ("width", camera)
        }
        None => (path, base),
    };
    let pixels = u64::from(camera.width) * u64::from(camera.height);
    if pixels > config.max_pixels {
        return Err(RequestError::too_large(
            field,
            format!(
                "{}x{} is {pixels} pixels, more than the {} this server renders",
                camera.width, camera.height, config.max_pixels
            ),
        ));
    }
    Ok(camera)
}

/// Refuses a camera centre beyond [`CAMERA_DISTANCE_LIMIT`] (`field` is the extrinsics').
fn sensible_view(camera: &Camera, field: &str) -> Result<(), RequestError> {
    let distance = camera.center_in_world().length();
    if distance.is_nan() || distance > CAMERA_DISTANCE_LIMIT {
        return Err(RequestError::invalid(
            field,
            format!(
                "field `{field}`: the camera centre is {distance:.3e} m from the origin, beyond \
                 the {CAMERA_DISTANCE_LIMIT} m a camera may be"
            ),
        ));
    }
    Ok(())
}

/// Refuses focal lengths outside [`FOCAL_RANGE_PX`], a skew beyond [`SKEW_LIMIT_PX`] and a
/// principal point more than [`PRINCIPAL_POINT_MARGIN`] image sizes outside the image.
fn sensible_intrinsics(camera: &Camera, field: &str) -> Result<(), RequestError> {
    let [[fx, skew, cx], [_, fy, cy], _] = camera.intrinsics_rows();
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let m = PRINCIPAL_POINT_MARGIN;
    let problem = if !(FOCAL_RANGE_PX.contains(&fx) && FOCAL_RANGE_PX.contains(&fy)) {
        format!(
            "focal lengths fx={fx}, fy={fy} px are outside {}..={} px",
            FOCAL_RANGE_PX.start(),
            FOCAL_RANGE_PX.end()
        )
    } else if skew.is_nan() || skew.abs() > SKEW_LIMIT_PX {
        format!("skew {skew} px is beyond {SKEW_LIMIT_PX} px")
    } else if !((-m * w..=(1.0 + m) * w).contains(&cx) && (-m * h..=(1.0 + m) * h).contains(&cy)) {
        format!(
            "principal point ({cx}, {cy}) is more than {m} image size outside the {}x{} image",
            camera.width, camera.height
        )
    } else {
        return Ok(());
    };
    Err(RequestError::invalid(
        field,
        format!("field `{field}`: {problem}"),
    ))
}

/// The same view at another resolution: K scaled per axis.
fn resized(camera: &Camera, width: u32, height: u32) -> Result<Camera, RequestError> {
    let sx = f64::from(width) / f64::from(camera.width);
    let sy = f64::from(height) / f64::from(camera.height);
    let mut k = camera.intrinsics_rows();
    for c in 0..3 {
        k[0][c] *= sx;
        k[1][c] *= sy;
    }
    Camera::new(width, height, k, camera.extrinsics_rows()).map_err(|e| {
        RequestError::invalid(
            "width",
            format!("resizing the camera to {width}x{height}: {e}"),
        )
    })
}

/// One dataset `params` object at `path`, every value within [`PARAM_LIMIT`].
fn params(v: &Value, path: &str) -> Result<FrameParams, RequestError> {
    Ok(FrameParams::from_json(v, path)?)
}

/// Refuses a frame with a value beyond [`PARAM_LIMIT`] (or NaN), naming `path.<field>[i]`.
pub(crate) fn check_params(p: &FrameParams, path: &str) -> Result<(), RequestError> {
    Ok(check_param_limits(p, path)?)
}
