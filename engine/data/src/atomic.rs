//! Atomic file writes: a temp file beside the target, then a rename, so a reader (or a
//! kill mid-write) sees the old file or the new one, never a partial one.

use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` through `path` + `.tmp` and a rename; the temp file is removed
/// if the rename fails.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}
