//! The bound on every exchange. A collective waits for every peer, so one that died or
//! hangs would hold the others forever; a watcher thread ends this process with exit 1
//! and a message naming the peers it waited for once an exchange outlasts its bound.
//!
//! A process that exits so writes nothing more: the run's files are only ever renamed
//! into place, so the last checkpoint stands and `--resume` continues from it.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How often the watcher looks at the clock.
const POLL: Duration = Duration::from_millis(200);

struct Armed {
    until: Instant,
    message: String,
}

/// A watcher over the exchanges of this process (one thread for its lifetime).
pub struct Deadline {
    armed: Arc<Mutex<Option<Armed>>>,
}

impl Deadline {
    /// Starts the watcher; `on_expiry` runs (on its thread) with the message of an exchange
    /// that outlasted its bound. [`Deadline::exiting`] prints it and exits 1.
    pub fn start(on_expiry: fn(&str)) -> Deadline {
        let armed: Arc<Mutex<Option<Armed>>> = Arc::new(Mutex::new(None));
        let watched = armed.clone();
        std::thread::Builder::new()
            .name("peer-deadline".into())
            .spawn(move || {
                loop {
                    std::thread::sleep(POLL);
                    let expired = match watched.lock() {
                        Ok(a) => a
                            .as_ref()
                            .filter(|a| Instant::now() >= a.until)
                            .map(|a| a.message.clone()),
                        Err(_) => return,
                    };
                    if let Some(message) = expired {
                        on_expiry(&message);
                        // A test's handler returns: disarm so it fires once.
                        if let Ok(mut a) = watched.lock() {
                            *a = None;
                        }
                    }
                }
            })
            .expect("spawning the peer-deadline thread");
        Deadline { armed }
    }

    /// The process's handler: the message on stderr, then exit 1.
    pub fn exiting() -> Deadline {
        Deadline::start(|message| {
            eprintln!("error: {message}");
            // An MPI launcher forwards the line through a pipe it may stop reading once
            // it sees the exit: give it time to pass the line on.
            std::thread::sleep(Duration::from_millis(2000));
            std::process::exit(1);
        })
    }

    /// Arms the bound for one exchange: `message` if it is not over `within` from now.
    /// Disarmed when the guard drops.
    pub fn arm(&self, within: Duration, message: String) -> Guard<'_> {
        if let Ok(mut a) = self.armed.lock() {
            *a = Some(Armed {
                until: Instant::now() + within,
                message,
            });
        }
        Guard { deadline: self }
    }
}

/// Disarms its [`Deadline`] when dropped (the exchange returned).
pub struct Guard<'a> {
    deadline: &'a Deadline,
}

impl Drop for Guard<'_> {
    fn drop(&mut self) {
        if let Ok(mut a) = self.deadline.armed.lock() {
            *a = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    static FIRED: AtomicUsize = AtomicUsize::new(0);

    #[test]
    fn fires_once_after_the_bound_and_never_when_disarmed_in_time() {
        let d = Deadline::start(|m| {
            assert!(m.contains("peer 1"));
            FIRED.fetch_add(1, Ordering::SeqCst);
        });
        {
            let _g = d.arm(Duration::from_millis(300), "peer 1 lost".into());
            std::thread::sleep(Duration::from_millis(50));
        }
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(FIRED.load(Ordering::SeqCst), 0, "disarmed in time");
        let _g = d.arm(Duration::from_millis(100), "peer 1 lost".into());
        std::thread::sleep(Duration::from_millis(900));
        assert_eq!(FIRED.load(Ordering::SeqCst), 1);
    }
}
