//! Import errors: each names the file, and where it applies the field and the shape that
//! was expected.

use std::path::{Path, PathBuf};

use crate::pickle::{PickleError, Value};
use talkin_data::array::{Dim, NdArray, shape_text};
use talkin_data::dataset::DatasetError;
use talkin_data::npz::NpzError;
use talkin_data::smplx_model::ModelError;

/// Why an import failed. Nothing is left under `--out` when it does.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Npz(#[from] NpzError),
    #[error(transparent)]
    Pickle(#[from] PickleError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{}: field `{field}`: {problem}", file.display())]
    Field {
        file: PathBuf,
        field: String,
        problem: String,
    },
    #[error("{}: {problem}", file.display())]
    File { file: PathBuf, problem: String },
    #[error("{0}")]
    Usage(String),
}

impl ImportError {
    pub(crate) fn field(file: &Path, field: impl Into<String>, problem: impl Into<String>) -> Self {
        ImportError::Field {
            file: file.to_path_buf(),
            field: field.into(),
            problem: problem.into(),
        }
    }

    pub(crate) fn file(file: &Path, problem: impl Into<String>) -> Self {
        ImportError::File {
            file: file.to_path_buf(),
            problem: problem.into(),
        }
    }

    pub(crate) fn io(file: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| ImportError::Io {
            file: file.to_path_buf(),
            source,
        }
    }
}

/// The finite numbers of array `a` (field `field` of `file`), which must have shape `dims`.
pub(crate) fn checked_f64(
    a: &NdArray,
    file: &Path,
    field: &str,
    dims: &[Dim],
) -> Result<Vec<f64>, ImportError> {
    talkin_data::npz::check_array(a, file, field, dims).map_err(|e| match e {
        NpzError::Shape { found, .. } => ImportError::field(
            file,
            field,
            format!("expected shape {}, found {found:?}", shape_text(dims)),
        ),
        NpzError::NonFinite { index, value, .. } => ImportError::field(
            file,
            field,
            format!(
                "expected shape {} of finite numbers, found {value} at {index:?}",
                shape_text(dims)
            ),
        ),
        other => ImportError::field(file, field, other.to_string()),
    })?;
    a.to_f64()
        .ok_or_else(|| ImportError::field(file, field, "expected numbers"))
}

/// Member `key` of pickle dict `v` (at `path` in `file`), which must be an array of shape
/// `dims` of finite numbers.
pub(crate) fn pickle_array(
    v: &Value,
    file: &Path,
    path: &str,
    key: &str,
    dims: &[Dim],
) -> Result<Vec<f64>, ImportError> {
    let field = format!("{path}['{key}']");
    let member = v.get(key).ok_or_else(|| {
        ImportError::field(
            file,
            &field,
            format!("missing (expected an array of shape {})", shape_text(dims)),
        )
    })?;
    let a = member.as_array().ok_or_else(|| {
        ImportError::field(
            file,
            &field,
            format!(
                "expected an array of shape {}, found a {}",
                shape_text(dims),
                member.kind()
            ),
        )
    })?;
    checked_f64(a, file, &field, dims)
}

/// Number `key` of JSON object `v`: an array of finite numbers of `n` elements (nested rows
/// are flattened).
pub(crate) fn json_numbers(
    v: &serde_json::Value,
    file: &Path,
    path: &str,
    key: &str,
    shape: &[usize],
) -> Result<Vec<f64>, ImportError> {
    let field = format!("{path}.{key}");
    let dims: Vec<Dim> = shape.iter().map(|&n| Dim::Is(n)).collect();
    let expected = format!("expected {} finite numbers", shape_text(&dims));
    let member = v
        .get(key)
        .ok_or_else(|| ImportError::field(file, &field, format!("missing ({expected})")))?;
    let mut out = Vec::new();
    fn flatten(v: &serde_json::Value, out: &mut Vec<Option<f64>>) {
        match v {
            serde_json::Value::Array(items) => items.iter().for_each(|i| flatten(i, out)),
            other => out.push(other.as_f64().filter(|x| x.is_finite())),
        }
    }
    let mut raw = Vec::new();
    flatten(member, &mut raw);
    let n: usize = shape.iter().product();
    if raw.len() != n {
        return Err(ImportError::field(
            file,
            &field,
            format!("{expected}, found {} values", raw.len()),
        ));
    }
    for (i, x) in raw.into_iter().enumerate() {
        out.push(x.ok_or_else(|| {
            ImportError::field(file, &field, format!("{expected}; value {i} is not one"))
        })?);
    }
    Ok(out)
}

/// Array `key` of an open archive: present, of shape `dims`, finite.
pub(crate) fn npz_f64(
    npz: &mut talkin_data::npz::Npz,
    key: &str,
    dims: &[Dim],
) -> Result<(Vec<f64>, Vec<usize>), ImportError> {
    let file = npz.file().to_path_buf();
    let a = npz.get(key)?.ok_or_else(|| {
        ImportError::field(
            &file,
            key,
            format!("missing (expected an array of shape {})", shape_text(dims)),
        )
    })?;
    let v = checked_f64(&a, &file, key, dims)?;
    Ok((v, a.shape().to_vec()))
}
