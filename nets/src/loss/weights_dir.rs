//! Where the converted LPIPS weights live: one per-user place that every command finds,
//! whatever the working directory.

use std::path::PathBuf;
use std::sync::LazyLock;

/// The environment variable that overrides the weights' directory.
pub const LPIPS_DIR_ENV: &str = "TALKIN_LPIPS_DIR";

/// `$TALKIN_LPIPS_DIR` when set, else the user's cache: `$XDG_CACHE_HOME/talkin/lpips`
/// (by default `~/.cache/talkin/lpips`; `~/Library/Caches/talkin/lpips` on macOS), else,
/// where no home is known, `talkin-cache/lpips` in the working directory.
/// `talkin lpips-weights` (and `scripts/lpips_weights.py`) write to the same place.
pub fn lpips_weights_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os(LPIPS_DIR_ENV).filter(|d| !d.is_empty()) {
        return PathBuf::from(dir);
    }
    match dirs::cache_dir() {
        Some(cache) => cache.join("talkin").join("lpips"),
        None => PathBuf::from("talkin-cache").join("lpips"),
    }
}

/// [`lpips_weights_dir`], resolved once: a `'static` path for command-line defaults.
pub static DEFAULT_LPIPS_DIR: LazyLock<PathBuf> = LazyLock::new(lpips_weights_dir);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_ends_in_talkin_lpips_and_never_depends_on_the_working_directory() {
        // The variable is read, not set here (tests run in parallel); when CI sets it the
        // directory is whatever it names.
        let dir = lpips_weights_dir();
        if std::env::var_os(LPIPS_DIR_ENV).is_none_or(|d| d.is_empty()) {
            assert!(dir.ends_with("talkin/lpips"), "{}", dir.display());
            assert!(dir.is_absolute() || dirs::cache_dir().is_none());
        }
    }
}
