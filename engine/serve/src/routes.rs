//! The HTTP routes. Handlers only read, validate and hand work to the render pool; every
//! refusal is a [`RequestError`] with a JSON body.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, Uri, header};
use axum::middleware::Next;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::{Value, json};
use talkin_render::avatar::RenderFrame;
use tokio::sync::oneshot;

use super::encode::{self, Encoded};
use super::error::RequestError;
use super::motion;
use super::pool::{Job, Refused};
use super::request::{self, Format};
use super::{App, Readiness};
use crate::json::json_body;

/// The web page at `/`: sliders for a few parameters, the rendered frame (no external
/// scripts: a served machine may reach nothing outside).
const PAGE: &str = include_str!("page.html");

pub(super) fn router(app: Arc<App>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/health", get(health))
        .route("/live", get(live))
        .route("/subjects", get(subjects))
        .route("/render", post(render))
        .route("/render/sequence", post(sequence))
        .route("/motions", get(motions))
        .route("/motion/poses", get(served_poses).post(posted_poses))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(axum::middleware::from_fn(echo_request_id))
        .with_state(app)
}

/// The request header a client may set to tell its answers apart; every answer carries
/// it back unchanged (behind a load balancer that retries, the client can check that
/// the answer it got is the one to its own request).
pub const REQUEST_ID_HEADER: &str = "x-request-id";

async fn echo_request_id(request: axum::extract::Request, next: Next) -> Response {
    let id = request.headers().get(REQUEST_ID_HEADER).cloned();
    let mut response = next.run(request).await;
    if let Some(id) = id {
        response.headers_mut().insert(REQUEST_ID_HEADER, id);
    }
    response
}

async fn page() -> Html<&'static str> {
    Html(PAGE)
}

async fn not_found() -> RequestError {
    RequestError::NotFound {
        field: None,
        message: "no such route; try GET /, /health, /live, /subjects, /motions, \
                  /motion/poses or POST /render, /render/sequence, /motion/poses"
            .into(),
    }
}

/// axum adds the `Allow` header to this answer.
async fn method_not_allowed(method: Method, uri: Uri) -> RequestError {
    RequestError::MethodNotAllowed {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

/// Readiness: 200 when the server wants requests, 503 with the reason while it loads or
/// drains (what a load balancer's health check reads).
async fn health(State(app): State<Arc<App>>) -> Response {
    let max = app.config.max_connections;
    let open = max.saturating_sub(app.connections.available_permits());
    let readiness = app.readiness();
    let (code, status) = match readiness {
        Readiness::Ready => (StatusCode::OK, "ok"),
        Readiness::Loading => (StatusCode::SERVICE_UNAVAILABLE, "loading"),
        Readiness::Draining => (StatusCode::SERVICE_UNAVAILABLE, "draining"),
    };
    let mut response = json_body(&json!({
        "status": status,
        "reason": readiness.reason(),
        "pool": app.pool.stats(),
        "skipped_jobs": app.skipped.load(std::sync::atomic::Ordering::Relaxed),
        "connections": {"open": open, "max": max},
    }));
    *response.status_mut() = code;
    response
}

/// Liveness: 200 whenever the process answers HTTP at all, loading and draining included.
async fn live() -> Response {
    json_body(&json!({"status": "alive"}))
}

async fn subjects(State(app): State<Arc<App>>) -> Response {
    let loaded = match app.loaded() {
        Ok(l) => l,
        Err(e) => return e.into_response(),
    };
    let subjects: Vec<Value> = loaded
        .subjects
        .iter()
        .map(|s| {
            let c = &s.default_camera;
            json!({
                "name": s.name,
                "index": s.index,
                "orbit_target": s.orbit_target.to_array(),
                "width": c.width,
                "height": c.height,
                "camera": {
                    "width": c.width,
                    "height": c.height,
                    "intrinsics": c.intrinsics_rows(),
                    "extrinsics": c.extrinsics_rows(),
                },
            })
        })
        .collect();
    let c = &app.config;
    json_body(&json!({
        "subjects": subjects,
        "limits": {
            "max_pixels": c.max_pixels,
            "max_body_bytes": c.max_body_bytes,
            "max_sequence_frames": c.max_sequence_frames,
            "render_timeout_s": c.render_timeout.as_secs_f64(),
            "body_timeout_s": c.body_timeout.as_secs_f64(),
            "header_timeout_s": c.header_timeout.as_secs_f64(),
            "idle_timeout_s": c.idle_timeout.as_secs_f64(),
            "max_connections": c.max_connections,
        },
        "formats": ["png", "raw"],
    }))
}

async fn render(State(app): State<Arc<App>>, headers: HeaderMap, body: Body) -> Response {
    let result = async {
        let subjects = &app.loaded()?.subjects;
        let bytes = read_body(&app, &headers, body, None).await?;
        let req = request::parse_render(&bytes, subjects, &app.config)?;
        let avatar = app.loaded()?.avatar.clone();
        let encoded = on_pool(&app, app.config.render_timeout, move |_| {
            let frame = avatar.render(req.subject, &req.params, &req.camera, None)?;
            Ok(match req.format {
                Format::Png => encode::png(&frame)?,
                Format::Raw => encode::raw(&frame),
            })
        })
        .await?;
        Ok::<_, RequestError>(encoded)
    }
    .await;
    match result {
        Ok(e) => image_response(e),
        Err(e) => e.into_response(),
    }
}

async fn sequence(
    State(app): State<Arc<App>>,
    uri: Uri,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok());
    let result = if motion::is_motion(content_type) {
        motion_sequence(app, uri.query(), &headers, body).await
    } else {
        json_sequence(app, &headers, body).await
    };
    match result {
        Ok((zip, notes)) => {
            let mut response = (
                [
                    (header::CONTENT_TYPE, "application/zip"),
                    (
                        header::CONTENT_DISPOSITION,
                        "attachment; filename=\"frames.zip\"",
                    ),
                ],
                zip,
            )
                .into_response();
            if !notes.is_empty() {
                // Header values are visible ASCII; anything else reads `?`.
                let text: String = notes
                    .join("; ")
                    .chars()
                    .map(|c| {
                        if c.is_ascii_graphic() || c == ' ' {
                            c
                        } else {
                            '?'
                        }
                    })
                    .collect();
                if let Ok(v) = HeaderValue::from_str(&text) {
                    response.headers_mut().insert(NOTES_HEADER, v);
                }
            }
            response
        }
        Err(e) => e.into_response(),
    }
}

/// The response header carrying a motion's notes (what was assumed or left as given).
pub const NOTES_HEADER: &str = "x-talkin-notes";

/// The JSON form: `{subject, frames, ...}`.
async fn json_sequence(
    app: Arc<App>,
    headers: &HeaderMap,
    body: Body,
) -> Result<(Vec<u8>, Vec<String>), RequestError> {
    let bytes = read_body(&app, headers, body, None).await?;
    let mut req = request::parse_sequence(&bytes, &app.loaded()?.subjects, &app.config)?;
    if req.smooth {
        req.frames = smooth(&req.frames, "frames")?;
    }
    let zip = render_frames(app, req.subject, req.frames, req.camera, "frames").await?;
    Ok((zip, Vec::new()))
}

/// The motion-file form: the body is a BEAT2 or AMASS `.npz`, the options are the query's.
async fn motion_sequence(
    app: Arc<App>,
    query: Option<&str>,
    headers: &HeaderMap,
    body: Body,
) -> Result<(Vec<u8>, Vec<String>), RequestError> {
    let q = motion::parse_query(query, &app.loaded()?.subjects, &app.config)?;
    let bytes = read_body(&app, headers, body, Some("motion")).await?;
    let reader = app.clone();
    let q2 = q.clone();
    // Reading and preparing touch the disk and the CPU: off the async threads.
    let (mut frames, notes) = tokio::task::spawn_blocking(move || {
        let motion = motion::read_bytes(&bytes, q2.layout)?;
        let loaded = reader.loaded()?;
        let subject = loaded.avatar.subjects[q2.subject]
            .model
            .as_ref()
            .ok_or_else(|| RequestError::Render("a served subject has no model".into()))?;
        motion::prepare(
            &motion,
            &q2,
            &subject.skeleton,
            loaded.body_model.as_deref(),
            &reader.config,
        )
    })
    .await
    .map_err(|e| RequestError::Render(format!("reading the motion: {e}")))??;
    if q.smooth {
        frames = smooth(&frames, "motion")?;
    }
    let zip = render_frames(app, q.subject, frames, q.camera, "motion").await?;
    Ok((zip, notes))
}

/// `GET /motions`: the motion files the server was started with.
async fn motions(State(app): State<Arc<App>>) -> Response {
    let offered = app.motions.read().unwrap_or_else(|p| p.into_inner());
    let list: Vec<Value> = offered
        .iter()
        .map(|m| {
            json!({
                "name": m.name,
                "frames": m.motion.frames.len(),
                "fps": m.motion.fps,
                "layout": format!("{:?}", m.motion.layout).to_ascii_lowercase(),
            })
        })
        .collect();
    json_body(&json!({ "motions": list }))
}

/// `GET /motion/poses?name=NAME&subject=...`: a served motion's poses, prepared for the
/// subject as `/render/sequence` prepares a posted file.
async fn served_poses(State(app): State<Arc<App>>, uri: Uri) -> Response {
    let result = async {
        let (name, rest) = motion::split_name(uri.query())?;
        let name = name.ok_or_else(|| {
            RequestError::invalid("name", "query parameter `name`: missing (see GET /motions)")
        })?;
        let found = app
            .motions
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .find(|m| m.name == name)
            .cloned()
            .ok_or_else(|| RequestError::NotFound {
                field: Some("name".into()),
                message: format!("no motion named `{name}`; GET /motions lists them"),
            })?;
        let q = motion::parse_query(Some(&rest), &app.loaded()?.subjects, &app.config)?;
        poses(app, q, name, move |_| Ok(found.motion.clone())).await
    }
    .await;
    result.unwrap_or_else(IntoResponse::into_response)
}

/// `POST /motion/poses?subject=...` with a BEAT2/AMASS `.npz` body: its poses, prepared.
async fn posted_poses(
    State(app): State<Arc<App>>,
    uri: Uri,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let result = async {
        let (name, rest) = motion::split_name(uri.query())?;
        if name.is_some() {
            return Err(RequestError::invalid(
                "name",
                "query parameter `name` names a served motion (GET); a posted file has none",
            ));
        }
        let content_type = headers
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok());
        if !motion::is_motion(content_type) {
            return Err(RequestError::invalid(
                "motion",
                format!(
                    "the body must be a motion file (.npz) sent as one of {}, not {}",
                    motion::MOTION_CONTENT_TYPES.join(", "),
                    content_type.unwrap_or("no Content-Type")
                ),
            ));
        }
        let q = motion::parse_query(Some(&rest), &app.loaded()?.subjects, &app.config)?;
        let bytes = read_body(&app, &headers, body, Some("motion")).await?;
        poses(app, q.clone(), "upload".into(), move |q| {
            motion::read_bytes(&bytes, q.layout)
        })
        .await
    }
    .await;
    result.unwrap_or_else(IntoResponse::into_response)
}

/// Reads a motion with `read` and prepares it per `q` off the async threads; the answer
/// is `{name, fps, frames: [params], notes}`.
async fn poses(
    app: Arc<App>,
    q: motion::MotionQuery,
    name: String,
    read: impl FnOnce(&motion::MotionQuery) -> Result<talkin_data::motion::Motion, RequestError>
    + Send
    + 'static,
) -> Result<Response, RequestError> {
    let q2 = q.clone();
    let (frames, notes, fps) = tokio::task::spawn_blocking(move || {
        let motion = read(&q2)?;
        let loaded = app.loaded()?;
        let subject = loaded.avatar.subjects[q2.subject]
            .model
            .as_ref()
            .ok_or_else(|| RequestError::Render("a served subject has no model".into()))?;
        let (mut frames, notes) = motion::prepare(
            &motion,
            &q2,
            &subject.skeleton,
            loaded.body_model.as_deref(),
            &app.config,
        )?;
        if q2.smooth {
            frames = smooth(&frames, "motion")?;
        }
        Ok::<_, RequestError>((frames, notes, q2.fps.or(motion.fps)))
    })
    .await
    .map_err(|e| RequestError::Render(format!("reading the motion: {e}")))??;
    use talkin_data::params_json::ParamsJson;
    let frames: Vec<Value> = frames.iter().map(ParamsJson::to_json).collect();
    Ok(json_body(&json!({
        "name": name,
        "fps": fps,
        "frames": frames,
        "notes": notes,
    })))
}

/// The paper's test-time filter over a sequence (one camera).
fn smooth(
    frames: &[talkin_human::body::FrameParams],
    field: &str,
) -> Result<Vec<talkin_human::body::FrameParams>, RequestError> {
    talkin_human::smooth::smooth_params(frames, &talkin_human::smooth::Smoothing::PAPER)
        .map_err(|e| RequestError::invalid(field, e.to_string()))
}

/// Renders `frames` on the pool, one after the other, into a zip of PNGs; a frame's bad
/// input is refused as `field[i]`.
async fn render_frames(
    app: Arc<App>,
    subject: usize,
    frames: Vec<talkin_human::body::FrameParams>,
    camera: talkin_human::camera::Camera,
    field: &'static str,
) -> Result<Vec<u8>, RequestError> {
    let n = frames.len();
    let timeout = app.config.render_timeout * n as u32;
    let avatar = app.loaded()?.avatar.clone();
    on_pool(&app, timeout, move |job| {
        let mut pngs = Vec::with_capacity(n);
        for (i, params) in frames.iter().enumerate() {
            // A client that is gone (or was dropped at shutdown) gets no more frames.
            if Instant::now() > job.deadline || (job.client_gone)() {
                return Err(RequestError::Timeout {
                    seconds: timeout.as_secs_f64(),
                });
            }
            let frame =
                avatar.render(subject, params, &camera, None).map_err(
                    |e| match RequestError::from(e) {
                        RequestError::Invalid { message, .. } => {
                            RequestError::invalid(format!("{field}[{i}]"), message)
                        }
                        other => other,
                    },
                )?;
            pngs.push(encode::png(&frame)?.bytes);
        }
        encode::zip_frames(&pngs)
    })
    .await
}

fn image_response(e: Encoded) -> Response {
    let mut response = (StatusCode::OK, e.bytes).into_response();
    let h = response.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(e.content_type),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert("x-image-width", HeaderValue::from(e.width));
    h.insert("x-image-height", HeaderValue::from(e.height));
    h.insert("x-render-samples", HeaderValue::from(e.samples as u64));
    if let Ok(v) = HeaderValue::from_str(&format!("{:.4}", e.seconds)) {
        h.insert("x-render-seconds", v);
    }
    response
}

/// The whole body, refusing more than the limit (by `Content-Length` up front, or while
/// reading a body sent without one) and clients that send too slowly.
/// `field` names the body in refusals (`motion` for a motion file; none for JSON).
async fn read_body(
    app: &App,
    headers: &HeaderMap,
    body: Body,
    field: Option<&str>,
) -> Result<Bytes, RequestError> {
    let limit = app.config.max_body_bytes;
    let too_large = || RequestError::TooLarge {
        field: field.map(str::to_string),
        message: format!("the request body is over the {limit} bytes this server reads"),
    };
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit as u64) {
        return Err(too_large());
    }
    let seconds = app.config.body_timeout.as_secs();
    match tokio::time::timeout(app.config.body_timeout, axum::body::to_bytes(body, limit)).await {
        Err(_) => Err(RequestError::BodyTimeout { seconds }),
        // http-body-util's limit error; anything else is a client that went away, to whom
        // no answer matters.
        Ok(Err(e)) if e.to_string().contains("length limit") => Err(too_large()),
        Ok(Err(e)) => Err(RequestError::Invalid {
            field: field.map(str::to_string),
            message: format!("reading the request body: {e}"),
        }),
        Ok(Ok(bytes)) => Ok(bytes),
    }
}

/// What a job on the pool may ask while it runs.
struct JobClock<'a> {
    deadline: Instant,
    /// True once nobody waits for the result (the client disconnected, was answered 504,
    /// or was dropped at shutdown).
    client_gone: &'a dyn Fn() -> bool,
}

/// Runs `work` on a render thread, refusing at once if the pool is full and answering 504
/// after `timeout`. A job whose client has given up by the time a worker reaches it is
/// skipped; a longer job can ask its [`JobClock`].
async fn on_pool<T: Send + 'static>(
    app: &App,
    timeout: Duration,
    work: impl FnOnce(&JobClock) -> Result<T, RequestError> + Send + 'static,
) -> Result<T, RequestError> {
    let (tx, rx) = oneshot::channel();
    let deadline = Instant::now() + timeout;
    let skipped = app.skipped.clone();
    let job: Job = Box::new(move || {
        if tx.is_closed() {
            skipped.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            return Box::new(|| {});
        }
        let result = work(&JobClock {
            deadline,
            client_gone: &|| tx.is_closed(),
        });
        Box::new(move || {
            let _ = tx.send(result);
        })
    });
    app.pool.try_submit(job).map_err(|r| match r {
        Refused::Full { queued } => RequestError::QueueFull {
            queued,
            retry_after_s: app.pool.retry_after().as_secs(),
        },
        Refused::Closed => RequestError::ShuttingDown,
    })?;
    match tokio::time::timeout(timeout, rx).await {
        Ok(Ok(result)) => result,
        Ok(Err(_)) => Err(RequestError::Render(
            "the render thread dropped the job (it panicked; see the server's log)".into(),
        )),
        Err(_) => Err(RequestError::Timeout {
            seconds: timeout.as_secs_f64(),
        }),
    }
}
