//! One writer per run directory: an OS advisory lock (`flock` on Linux, through std's
//! `File::try_lock`) on a file inside it, held for as long as the writer lives. The kernel
//! drops it with the process, so a trainer killed by SIGKILL leaves nothing that blocks
//! the next one. Readers (render, eval, serve) take no lock: they read the newest
//! verified checkpoint, which a writer only ever renames into place.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// The lock file inside a run directory; it holds the holder's process id as text.
pub const LOCK_FILE: &str = "run.lock";

/// Why the lock could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum RunLockError {
    /// Another process holds it (`pid` when it had written its id).
    #[error(
        "{} is being written by another talkin process{}: one writer per run (wait for it \
         to end, or stop it; a killed process leaves no lock behind)",
        run.display(),
        pid.map(|p| format!(" (pid {p})")).unwrap_or_default()
    )]
    Held { run: PathBuf, pid: Option<u32> },
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// The lock on one run directory, released when dropped (or when the process dies).
#[derive(Debug)]
pub struct RunLock {
    /// Kept open: closing the file releases the lock.
    _file: File,
    /// The run directory, when taking the lock created it.
    created: Option<PathBuf>,
}

impl RunLock {
    /// Takes the lock on `run` (created if absent) without waiting, and writes this
    /// process's id into the lock file for the message another writer gets.
    pub fn take(run: &Path) -> Result<RunLock, RunLockError> {
        let path = run.join(LOCK_FILE);
        let io = |source| RunLockError::Io {
            file: path.clone(),
            source,
        };
        let created = (!run.exists()).then(|| run.to_path_buf());
        std::fs::create_dir_all(run).map_err(|source| RunLockError::Io {
            file: run.to_path_buf(),
            source,
        })?;
        // Never truncated on open: the holder's id must survive a refused opener.
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                return Err(RunLockError::Held {
                    run: run.to_path_buf(),
                    pid: holder_pid(&mut file),
                });
            }
            Err(TryLockError::Error(e)) => return Err(io(e)),
        }
        // The id is a courtesy for the message: a full disk must not stop the run here.
        let _ = file
            .set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| writeln!(file, "{}", std::process::id()))
            .and_then(|()| file.flush());
        Ok(RunLock {
            _file: file,
            created,
        })
    }
}

/// A command refused before it wrote anything (a bad dataset, say) leaves no directory it
/// created behind: while still locked, the lock file goes, then the directory if empty. A
/// writer that opened the file meanwhile is refused by the lock; one that opens after
/// creates a new file, and the directory stays.
impl Drop for RunLock {
    fn drop(&mut self) {
        let Some(run) = &self.created else {
            return;
        };
        let only_the_lock = std::fs::read_dir(run).is_ok_and(|entries| {
            entries
                .flatten()
                .all(|e| e.file_name() == std::ffi::OsStr::new(LOCK_FILE))
        });
        if only_the_lock {
            let _ = std::fs::remove_file(run.join(LOCK_FILE));
            let _ = std::fs::remove_dir(run);
        }
    }
}

/// The id the holder wrote, if it has written one yet.
fn holder_pid(file: &mut File) -> Option<u32> {
    let mut text = String::new();
    file.take(32).read_to_string(&mut text).ok()?;
    text.trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_taker_is_refused_until_the_first_is_dropped() {
        let dir = std::env::temp_dir().join(format!("talkin_run_lock_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let run = dir.join("run");
        let first = RunLock::take(&run).unwrap();
        // flock locks belong to the open file, so a second open in this process conflicts.
        match RunLock::take(&run) {
            Err(RunLockError::Held { run: r, pid }) => {
                assert_eq!(r, run);
                assert_eq!(pid, Some(std::process::id()));
            }
            other => panic!("expected Held, got {other:?}"),
        }
        let message = RunLock::take(&run).unwrap_err().to_string();
        assert!(
            message.contains(&run.display().to_string())
                && message.contains(&format!("pid {}", std::process::id())),
            "{message}"
        );
        drop(first);
        // The directory it created held nothing else: it is gone.
        assert!(!run.exists());
        let again = RunLock::take(&run).unwrap();
        std::fs::write(run.join("train_log.csv"), "step\n").unwrap();
        drop(again);
        // With a run in it, the directory and its lock file stay.
        assert!(run.join(LOCK_FILE).is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
