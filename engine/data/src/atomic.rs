//! Durable, atomic file writes: a uniquely named temp file beside the target, written and
//! fsynced, renamed over the target, and the directory fsynced, so that a reader, a kill
//! mid-write or a power cut sees the old file or the new one, never a partial one.

use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` through a temp file in the same directory (`.NAME.XXXXXX.tmp`),
/// fsyncs it, renames it over `path` and fsyncs the directory. The temp file is removed if
/// anything fails. New files get the usual `0666 & !umask` mode, not the temp file's 0600.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let prefix = format!(".{name}.");
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    sync_dir(dir)
}

/// Writes `bytes` to a new file `path` and fsyncs it (for files inside a directory that
/// is itself renamed into place afterwards, such as a checkpoint's).
pub fn write_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = std::fs::File::create(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

/// Fsyncs a directory, making the creations, renames and removals in it durable. A no-op
/// where directories cannot be opened as files (Windows).
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::fs::File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

/// A directory of files that appears complete or not at all: they are written into a
/// hidden staging directory beside the target (`.NAME.partial-PID`), which
/// [`StagedDir::publish`] moves into place and which is removed if it is dropped
/// unpublished (an error half-way, a full disk).
#[derive(Debug)]
pub struct StagedDir {
    staging: std::path::PathBuf,
    target: std::path::PathBuf,
    published: bool,
}

impl StagedDir {
    /// A fresh staging directory for `target` (not created: the writer creates it).
    pub fn new(target: &Path) -> std::io::Result<StagedDir> {
        let name = target.file_name().ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "not a directory name (it ends in `..` or is a root)",
            )
        })?;
        let staging = target.with_file_name(format!(
            ".{}.partial-{}",
            name.to_string_lossy(),
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&staging);
        Ok(StagedDir {
            staging,
            target: target.to_path_buf(),
            published: false,
        })
    }

    /// Where the files go until [`StagedDir::publish`].
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// Moves the files into the target: one rename when it is absent or empty, else file
    /// by file (replacing same-named files; a folder already there takes the staged
    /// folder's files the same way). Renames need no space, so a full disk fails before
    /// this, while writing.
    pub fn publish(mut self) -> std::io::Result<()> {
        let empty = match std::fs::read_dir(&self.target) {
            Ok(mut entries) => entries.next().is_none(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => true,
            Err(e) => return Err(e),
        };
        if empty {
            if self.target.exists() {
                std::fs::remove_dir(&self.target)?;
            }
            std::fs::rename(&self.staging, &self.target)?;
        } else {
            move_into(&self.staging, &self.target)?;
        }
        self.published = true;
        sync_dir(parent_dir(&self.target))
    }
}

/// Moves the entries of folder `from` into folder `to`, replacing same-named files and
/// merging same-named folders, then removes `from`.
fn move_into(from: &Path, to: &Path) -> std::io::Result<()> {
    for entry in std::fs::read_dir(from)? {
        let entry = entry?;
        let there = to.join(entry.file_name());
        if entry.file_type()?.is_dir() && there.is_dir() {
            move_into(&entry.path(), &there)?;
        } else {
            std::fs::rename(entry.path(), there)?;
        }
    }
    std::fs::remove_dir(from)
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.published {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// The directory holding `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_the_file_keeps_a_normal_mode_and_leaves_no_temp() {
        let dir = std::env::temp_dir().join(format!("talkin_atomic_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("x.json");
        write_atomic(&file, b"first").unwrap();
        write_atomic(&file, b"second").unwrap();
        assert_eq!(std::fs::read(&file).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["x.json"]);
        #[cfg(unix)]
        {
            // The mode a plain `std::fs::write` gives under this umask, not the temp's 0600.
            use std::os::unix::fs::PermissionsExt;
            let plain = dir.join("plain");
            std::fs::write(&plain, b"").unwrap();
            let mode = |f: &Path| std::fs::metadata(f).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode(&file), mode(&plain));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_staged_dir_appears_whole_or_not_at_all() {
        let dir = std::env::temp_dir().join(format!("talkin_staged_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let target = dir.join("renders");
        let listing = || -> Vec<String> {
            let mut names: Vec<String> = std::fs::read_dir(&dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            names
        };
        // Dropped half-way: nothing is left, under either name.
        let staged = StagedDir::new(&target).unwrap();
        std::fs::create_dir_all(staged.path()).unwrap();
        std::fs::write(staged.path().join("a.png"), b"a").unwrap();
        drop(staged);
        assert!(listing().is_empty(), "{:?}", listing());
        // Published: the files appear; into a non-empty target, beside what is there.
        let staged = StagedDir::new(&target).unwrap();
        std::fs::create_dir_all(staged.path()).unwrap();
        std::fs::write(staged.path().join("a.png"), b"a").unwrap();
        staged.publish().unwrap();
        let staged = StagedDir::new(&target).unwrap();
        std::fs::create_dir_all(staged.path()).unwrap();
        std::fs::write(staged.path().join("b.png"), b"b").unwrap();
        staged.publish().unwrap();
        assert_eq!(listing(), ["renders"]);
        assert_eq!(std::fs::read(target.join("a.png")).unwrap(), b"a");
        assert_eq!(std::fs::read(target.join("b.png")).unwrap(), b"b");
        // A folder published twice takes the second's files beside the first's.
        for name in ["c.png", "d.png"] {
            let staged = StagedDir::new(&target).unwrap();
            std::fs::create_dir_all(staged.path().join("sub")).unwrap();
            std::fs::write(staged.path().join("sub").join(name), name).unwrap();
            staged.publish().unwrap();
        }
        for name in ["c.png", "d.png"] {
            assert_eq!(
                std::fs::read(target.join("sub").join(name)).unwrap(),
                name.as_bytes()
            );
        }
        assert_eq!(listing(), ["renders"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
