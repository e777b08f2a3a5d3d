//! Dataset errors: every one names the file, and where it applies the frame and field.

use std::path::PathBuf;

use crate::json_shape::ShapeError;
use talkin_human::camera::CameraError;

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: malformed JSON at line {line}, column {column}: {message}", file.display())]
    Json {
        file: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    #[error("{}: {source}", file.display())]
    Shape {
        file: PathBuf,
        #[source]
        source: ShapeError,
    },
    #[error("{}: field `{field}`: {problem}", file.display())]
    Invalid {
        file: PathBuf,
        field: String,
        problem: String,
    },
    #[error("{}: field `{field}`: {source}", file.display())]
    Camera {
        file: PathBuf,
        field: String,
        #[source]
        source: CameraError,
    },
    #[error("{}: {problem}", file.display())]
    Image { file: PathBuf, problem: String },
}

impl DatasetError {
    /// The file the error is about.
    pub fn file(&self) -> &std::path::Path {
        match self {
            DatasetError::Io { file, .. }
            | DatasetError::Json { file, .. }
            | DatasetError::Shape { file, .. }
            | DatasetError::Invalid { file, .. }
            | DatasetError::Camera { file, .. }
            | DatasetError::Image { file, .. } => file,
        }
    }
}
