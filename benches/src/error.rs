//! The error of the training benchmarks (speed-vs-error, ablations): training,
//! evaluation, writing the report, or a bad option.

use std::path::PathBuf;

use talkin_train::TrainError;

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error("render: {0}")]
    Render(#[from] talkin_avatar::AvatarError),
    #[error("evaluation: {0}")]
    Eval(#[from] talkin_render::eval::EvalError),
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("option `{field}`: {problem}")]
    BadOption {
        field: &'static str,
        problem: String,
    },
}

impl BenchError {
    /// A bad option, naming it.
    pub fn bad(field: &'static str, problem: &str) -> BenchError {
        BenchError::BadOption {
            field,
            problem: problem.into(),
        }
    }
}
