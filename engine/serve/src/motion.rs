//! `POST /render/sequence` with a motion file as the body (BEAT2 or AMASS SMPL-X `.npz`),
//! its options in the query string. The file is read by `talkin-data`'s own motion reader
//! and prepared for the subject exactly as `talkin render --motion` prepares it; every
//! problem is a [`RequestError`] naming `motion`, `motion.<array>` or the query field.

use std::io::Write;
use std::path::PathBuf;

use serde_json::{Map, Value};

use super::config::ServeConfig;
use super::error::RequestError;
use super::request;
use super::subjects::ServedSubject;
use talkin_data::motion::{Motion, MotionError, MotionLayout, Prepare, read_motion};
use talkin_data::npz::NpzError;
use talkin_data::smplx_model::SmplxModel;
use talkin_human::body::{FrameParams, Skeleton};
use talkin_human::camera::Camera;

/// Highest output frame rate a request may ask for (frames per second).
pub const MAX_FPS: f64 = 1000.0;

/// The `Content-Type`s that mean "the body is a motion file".
pub const MOTION_CONTENT_TYPES: [&str; 3] = [
    "application/octet-stream",
    "application/x-npz",
    "application/zip",
];

/// The query keys a motion request may carry.
const QUERY_KEYS: [&str; 7] = [
    "subject",
    "fps",
    "layout",
    "keep_trans",
    "width",
    "height",
    "smooth",
];

/// A motion file the server was started with (`talkin serve --motion`), offered by name.
#[derive(Clone, Debug)]
pub struct NamedMotion {
    /// The file's stem.
    pub name: String,
    pub motion: Motion,
}

/// Reads motion `files`, each named by its file stem. A file that does not read, or a
/// stem given twice, is refused naming the file.
pub fn read_named(files: &[PathBuf]) -> Result<Vec<NamedMotion>, super::ServeError> {
    use super::ServeError;
    let mut named: Vec<NamedMotion> = Vec::with_capacity(files.len());
    for file in files {
        let name = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.is_empty() || named.iter().any(|m| m.name == name) {
            return Err(ServeError::MotionName {
                file: file.clone(),
                name,
            });
        }
        let motion = read_motion(file, None).map_err(|source| ServeError::Motion {
            file: file.clone(),
            source: Box::new(source),
        })?;
        named.push(NamedMotion { name, motion });
    }
    Ok(named)
}

/// Splits `name=...` (a served motion's name, `GET /motion/poses`) off a query string;
/// returns it and the other parameters, re-encoded.
pub fn split_name(query: Option<&str>) -> Result<(Option<String>, String), RequestError> {
    let mut name = None;
    let mut rest = form_urlencoded::Serializer::new(String::new());
    for (key, value) in form_urlencoded::parse(query.unwrap_or_default().as_bytes()) {
        if key == "name" {
            if name.is_some() {
                return Err(RequestError::invalid(
                    "name",
                    "query parameter `name` is given twice",
                ));
            }
            name = Some(value.into_owned());
        } else {
            rest.append_pair(&key, &value);
        }
    }
    Ok((name, rest.finish()))
}

/// True when `content_type` (parameters such as `; charset` ignored) names a motion file.
pub fn is_motion(content_type: Option<&str>) -> bool {
    content_type
        .and_then(|t| t.split(';').next())
        .map(|t| t.trim().to_ascii_lowercase())
        .is_some_and(|t| MOTION_CONTENT_TYPES.contains(&t.as_str()))
}

/// The options of a motion request, from its query string.
#[derive(Clone, Debug)]
pub struct MotionQuery {
    /// Identity index in the avatar.
    pub subject: usize,
    pub camera: Camera,
    /// Output frame rate (`None`: the file's).
    pub fps: Option<f64>,
    pub layout: Option<MotionLayout>,
    pub keep_trans: bool,
    pub smooth: bool,
}

/// Parses the query string: `subject` (required), `fps`, `layout`, `keep_trans`, `width`
/// and `height` (together), `smooth`. Unknown and repeated keys are refused.
pub fn parse_query(
    query: Option<&str>,
    subjects: &[ServedSubject],
    config: &ServeConfig,
) -> Result<MotionQuery, RequestError> {
    let mut obj = Map::new();
    for (key, value) in form_urlencoded::parse(query.unwrap_or_default().as_bytes()) {
        let key = key.into_owned();
        if !QUERY_KEYS.contains(&key.as_str()) {
            return Err(RequestError::invalid(
                key.clone(),
                format!(
                    "unknown query parameter `{key}`; expected some of {}",
                    QUERY_KEYS.join(", ")
                ),
            ));
        }
        if obj.contains_key(&key) {
            return Err(RequestError::invalid(
                key.clone(),
                format!("query parameter `{key}` is given twice"),
            ));
        }
        obj.insert(key, Value::String(value.into_owned()));
    }
    let text = |k: &str| obj.get(k).and_then(Value::as_str).map(str::to_string);
    // width and height go through the JSON form's own checks, as numbers.
    let mut sized = Map::new();
    for k in ["width", "height"] {
        if let Some(v) = text(k) {
            let n: u64 = v.trim().parse().map_err(|_| {
                RequestError::invalid(k, format!("query parameter `{k}`: {v:?} is not a size"))
            })?;
            sized.insert(k.into(), Value::from(n));
        }
    }
    sized.insert(
        "subject".into(),
        obj.get("subject").cloned().ok_or_else(|| {
            RequestError::invalid("subject", "query parameter `subject`: missing")
        })?,
    );
    let subject = request::subject(&sized, subjects)?;
    let camera = request::camera(&sized, subject, config)?;
    let fps = match text("fps") {
        None => None,
        Some(v) => Some(
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|f| f.is_finite() && *f > 0.0 && *f <= MAX_FPS)
                .ok_or_else(|| {
                    RequestError::invalid(
                        "fps",
                        format!(
                            "query parameter `fps`: expected frames per second in (0, {MAX_FPS}], \
                             found {v:?}"
                        ),
                    )
                })?,
        ),
    };
    let layout = match text("layout") {
        None => None,
        Some(v) => match v.to_ascii_lowercase().as_str() {
            "beat2" => Some(MotionLayout::Beat2),
            "amass" => Some(MotionLayout::Amass),
            _ => {
                return Err(RequestError::invalid(
                    "layout",
                    format!("query parameter `layout`: expected beat2 or amass, found {v:?}"),
                ));
            }
        },
    };
    let flag = |k: &str| -> Result<bool, RequestError> {
        match text(k).as_deref() {
            None | Some("false") | Some("0") => Ok(false),
            Some("true") | Some("1") | Some("") => Ok(true),
            Some(v) => Err(RequestError::invalid(
                k,
                format!("query parameter `{k}`: expected true or false, found {v:?}"),
            )),
        }
    };
    Ok(MotionQuery {
        subject: subject.index,
        camera,
        fps,
        layout,
        keep_trans: flag("keep_trans")?,
        smooth: flag("smooth")?,
    })
}

/// Reads a motion file from its bytes: written to a temporary `.npz` (removed on return)
/// and read by [`read_motion`], so a posted file is read exactly as a file on disk.
/// Blocking: call it off the async threads.
pub fn read_bytes(bytes: &[u8], layout: Option<MotionLayout>) -> Result<Motion, RequestError> {
    let io = |e: std::io::Error| {
        RequestError::Render(format!("writing the motion to a temporary file: {e}"))
    };
    let mut file = tempfile::Builder::new()
        .prefix("talkin-motion-")
        .suffix(".npz")
        .tempfile()
        .map_err(io)?;
    file.write_all(bytes).map_err(io)?;
    file.flush().map_err(io)?;
    let path = file.path().display().to_string();
    read_motion(file.path(), layout).map_err(|e| motion_error(&e, &path))
}

/// The frames of `motion` ready to render on `skeleton` (as `talkin render --motion`
/// prepares them) and the notes about what was assumed. The frame count after resampling
/// is checked before any frame is made.
pub fn prepare(
    motion: &Motion,
    query: &MotionQuery,
    skeleton: &Skeleton,
    model: Option<&SmplxModel>,
    config: &ServeConfig,
) -> Result<(Vec<FrameParams>, Vec<String>), RequestError> {
    let n = motion.frames.len();
    let (count, field) = match (query.fps, motion.fps) {
        (Some(_), None) => {
            return Err(RequestError::invalid(
                "fps",
                "query parameter `fps`: the motion has no frame rate to resample from (no \
                 `mocap_frame_rate`); leave out fps",
            ));
        }
        (Some(out), Some(file)) => ((n - 1) as f64 * out / file + 1.0, "fps"),
        (None, _) => (n as f64, "motion"),
    };
    let max = config.max_sequence_frames;
    if count.floor() > max as f64 {
        return Err(RequestError::too_large(
            field,
            format!(
                "the motion is {} frames{}, more than the {max} a sequence may have",
                count.floor(),
                query.fps.map_or(String::new(), |f| format!(" at {f} fps"))
            ),
        ));
    }
    let prepared = motion
        .prepare(&Prepare {
            subject: skeleton,
            model,
            fps: query.fps,
            keep_trans: query.keep_trans,
        })
        .map_err(|e| motion_error(&e, &motion.file.display().to_string()))?;
    for (i, frame) in prepared.frames.iter().enumerate() {
        request::check_params(frame, &format!("motion[{i}]"))?;
    }
    Ok((prepared.frames, prepared.notes))
}

/// A motion error as a refusal: the field is the array at fault (`motion.poses`) or the
/// file (`motion`); the temporary file's path in the message reads `motion`.
fn motion_error(e: &MotionError, path: &str) -> RequestError {
    let message = e.to_string().replace(path, "motion");
    let array = match e {
        MotionError::Array { array, .. } => Some(array.as_str()),
        MotionError::Npz(n) => match n {
            NpzError::Missing { array, .. }
            | NpzError::Corrupt { array, .. }
            | NpzError::Pickled { array, .. }
            | NpzError::Shape { array, .. }
            | NpzError::DType { array, .. }
            | NpzError::NonFinite { array, .. } => Some(array.as_str()),
            NpzError::Io { .. } | NpzError::Archive { .. } => None,
        },
        _ => None,
    };
    let field = array.map_or_else(|| "motion".to_string(), |a| format!("motion.{a}"));
    RequestError::invalid(field, message)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_content_types() {
        assert!(is_motion(Some("application/octet-stream")));
        assert!(is_motion(Some("Application/X-NPZ; charset=binary")));
        assert!(is_motion(Some("application/zip")));
        assert!(!is_motion(Some("application/json")));
        assert!(!is_motion(None));
    }

    #[test]
    fn bytes_that_are_no_npz_name_the_motion() {
        let e = read_bytes(b"PK\x03\x04 truncated", None).unwrap_err();
        assert_eq!(e.field(), Some("motion"), "{e}");
        assert!(!e.to_string().contains("talkin-motion-"), "{e}");
    }
}
