//! JSON response bodies: every answer but the page and the images is one.

use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde_json::Value;

/// A JSON response body.
pub(crate) fn json_body(v: &Value) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        serde_json::to_vec(v).expect("JSON values always serialise"),
    )
        .into_response()
}
