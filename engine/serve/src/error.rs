//! Errors of the server: why it could not start, and why a request was refused (each
//! with its HTTP status and the request field at fault).

use std::path::PathBuf;

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::config::ConfigError;
use talkin_avatar::AvatarError;

/// Why the server could not start or stopped abnormally.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Device(#[from] talkin_nets::DeviceError),
    #[error("loading the avatar from {}: {source}", run.display())]
    Avatar {
        run: PathBuf,
        #[source]
        source: AvatarError,
    },
    #[error("loading the body model {}: {source}", file.display())]
    BodyModel {
        file: PathBuf,
        #[source]
        source: talkin_data::smplx_model::ModelError,
    },
    /// A motion file that does not read (its error names the file).
    #[error("{source}")]
    Motion {
        file: PathBuf,
        #[source]
        source: Box<talkin_data::motion::MotionError>,
    },
    #[error(
        "the motion file {} is named `{name}` (its file stem), which is empty or another \
         motion's name",
        file.display()
    )]
    MotionName { file: PathBuf, name: String },
    #[error("the avatar has no trained subject to serve")]
    NoSubjects,
    #[error("binding {addr}: {source}")]
    Bind {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("starting the async runtime or a worker thread: {0}")]
    Runtime(#[source] std::io::Error),
    #[error("serving: {0}")]
    Serve(#[source] std::io::Error),
}

/// Why one request was refused. The response is `{"error": message, "field": path}` with
/// `field` the JSON path of the offending value (`params.body_pose[3]`), or null.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// Malformed JSON, a missing or wrongly shaped field, a bad value: 400.
    #[error("{message}")]
    Invalid {
        field: Option<String>,
        message: String,
    },
    /// Unknown subject or route: 404.
    #[error("{message}")]
    NotFound {
        field: Option<String>,
        message: String,
    },
    /// A route that exists, asked with a method it does not answer: 405 with `Allow`.
    #[error("{method} is not allowed on {path}; the `Allow` header lists what is")]
    MethodNotAllowed { method: String, path: String },
    /// Body, image or sequence over the server's limits: 413.
    #[error("{message}")]
    TooLarge {
        field: Option<String>,
        message: String,
    },
    /// The client did not send its body in time: 408.
    #[error("the request body did not arrive within {seconds} s")]
    BodyTimeout { seconds: u64 },
    /// Every worker busy and the queue full: 503 with `Retry-After`.
    #[error("the render queue is full ({queued} waiting); retry in {retry_after_s} s")]
    QueueFull { queued: usize, retry_after_s: u64 },
    /// The server already holds `--max-connections` connections: 503 with `Retry-After`,
    /// written on a new connection before it is closed unread.
    #[error("the server holds its limit of {limit} open connections; retry later")]
    TooManyConnections { limit: usize },
    /// The server is shutting down: 503.
    #[error("the server is shutting down")]
    ShuttingDown,
    /// The server is not ready yet (its checkpoint is loading): 503 with `Retry-After`.
    #[error("{reason}; retry later")]
    NotReady { reason: &'static str },
    /// The render did not finish in time: 504.
    #[error("the render did not finish within {seconds} s")]
    Timeout { seconds: f64 },
    /// The renderer failed on valid input (a broken checkpoint): 500.
    #[error("render failed: {0}")]
    Render(String),
}

impl RequestError {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            field: Some(field.into()),
            message: message.into(),
        }
    }

    pub fn too_large(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::TooLarge {
            field: Some(field.into()),
            message: message.into(),
        }
    }

    pub fn status(&self) -> StatusCode {
        match self {
            Self::Invalid { .. } => StatusCode::BAD_REQUEST,
            Self::NotFound { .. } => StatusCode::NOT_FOUND,
            Self::MethodNotAllowed { .. } => StatusCode::METHOD_NOT_ALLOWED,
            Self::TooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            Self::BodyTimeout { .. } => StatusCode::REQUEST_TIMEOUT,
            Self::QueueFull { .. }
            | Self::TooManyConnections { .. }
            | Self::ShuttingDown
            | Self::NotReady { .. } => StatusCode::SERVICE_UNAVAILABLE,
            Self::Timeout { .. } => StatusCode::GATEWAY_TIMEOUT,
            Self::Render(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// The JSON path of the offending request value, if one is at fault.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::Invalid { field, .. }
            | Self::NotFound { field, .. }
            | Self::TooLarge { field, .. } => field.as_deref(),
            _ => None,
        }
    }

    /// The response body: `{"error": message, "field": path or null}`.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({ "error": self.to_string(), "field": self.field() })
    }
}

impl IntoResponse for RequestError {
    fn into_response(self) -> Response {
        let mut response = (self.status(), crate::json::json_body(&self.json())).into_response();
        let retry_after_s = match self {
            Self::QueueFull { retry_after_s, .. } => Some(retry_after_s),
            Self::NotReady { .. } => Some(1),
            _ => None,
        };
        if let Some(s) = retry_after_s {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(s));
        }
        response
    }
}

impl From<AvatarError> for RequestError {
    /// Input problems the avatar finds itself are the client's; anything else is ours.
    fn from(e: AvatarError) -> Self {
        match e {
            AvatarError::Subject(message) => Self::NotFound {
                field: Some("subject".into()),
                message,
            },
            AvatarError::BadInput { what, problem } if what != "render" => Self::Invalid {
                field: Some(what.clone()),
                message: format!("{what}: {problem}"),
            },
            other => Self::Render(other.to_string()),
        }
    }
}
