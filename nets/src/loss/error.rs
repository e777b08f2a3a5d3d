use std::path::PathBuf;

/// Why LPIPS weights could not be loaded. Every variant names the file; tensor problems
/// name the tensor and the shape the architecture expects.
#[derive(Debug, thiserror::Error)]
pub enum LossError {
    /// The weights file could not be read.
    #[error("cannot read LPIPS weights {}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not a valid safetensors file.
    #[error("{} is not a valid safetensors file: {message}", path.display())]
    Format { path: PathBuf, message: String },
    /// A tensor the architecture needs is absent.
    #[error("{}: tensor `{name}` is missing (expected f32 of shape {expected:?}); \
             regenerate the file with `talkin lpips-weights`", path.display())]
    MissingTensor {
        path: PathBuf,
        name: String,
        expected: Vec<usize>,
    },
    /// A tensor has the wrong shape (e.g. the file of the other backbone).
    #[error("{}: tensor `{name}` has shape {found:?}, expected {expected:?}", path.display())]
    Shape {
        path: PathBuf,
        name: String,
        found: Vec<usize>,
        expected: Vec<usize>,
    },
    /// A tensor is not float32.
    #[error("{}: tensor `{name}` has dtype {found}, expected F32 of shape {expected:?}", path.display())]
    Dtype {
        path: PathBuf,
        name: String,
        found: String,
        expected: Vec<usize>,
    },
    /// A value is NaN/infinite, or a linear head has a negative weight (LPIPS v0.1 heads
    /// are non-negative by construction).
    #[error("{}: tensor `{name}` (shape {expected:?}) has an invalid value {value} at flat index {index}", path.display())]
    BadValue {
        path: PathBuf,
        name: String,
        expected: Vec<usize>,
        index: usize,
        value: f32,
    },
}
