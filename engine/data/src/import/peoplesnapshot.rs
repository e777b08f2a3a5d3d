//! Placeholder.

use super::{ImportError, ImportOptions, Source};

pub fn read(opts: &ImportOptions) -> Result<Source, ImportError> {
    Err(ImportError::file(&opts.src, "format not implemented yet"))
}
