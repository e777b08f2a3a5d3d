//! Typed errors of the nets crate: malformed packed batches and condition vectors.

/// What was wrong with an input handed to the field or the renderer.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NetsError {
    /// A per-sample or per-ray slice has the wrong length.
    #[error("{what}: expected length {expected}, got {got}")]
    Length {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// Ray offsets must start at 0, never decrease and end at the sample count.
    #[error("ray offsets are malformed: {0}")]
    Offsets(String),
    /// An index (identity, bone) is out of range.
    #[error("{what} index {index} out of range (< {limit})")]
    Index {
        what: &'static str,
        index: usize,
        limit: usize,
    },
    /// A configuration value is out of its range.
    #[error("config field {field} is {value}; expected {expected}")]
    Config {
        field: &'static str,
        value: String,
        expected: &'static str,
    },
    /// A value that must be finite is not.
    #[error("{what} contains a non-finite value")]
    NonFinite { what: &'static str },
}

/// Checks a slice length, naming the field in the error.
pub(crate) fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), NetsError> {
    if got == expected {
        Ok(())
    } else {
        Err(NetsError::Length {
            what,
            expected,
            got,
        })
    }
}
