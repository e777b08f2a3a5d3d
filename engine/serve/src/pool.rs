//! A fixed set of render threads behind a bounded queue. Rendering is CPU-bound and takes
//! tens of milliseconds to seconds, so it never runs on the async executor's threads; a
//! job that finds no idle worker and no free queue slot is refused at once (the caller
//! answers 503) instead of piling up.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Work for a render thread. It returns how to hand its result over; the pool counts the
/// job as completed before it delivers, so a client that holds a reply sees it counted in
/// `/health`.
pub type Job = Box<dyn FnOnce() -> Deliver + Send + 'static>;

/// Hands a finished job's result to whoever waits for it.
pub type Deliver = Box<dyn FnOnce() + Send + 'static>;

/// Why a job was not accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    #[error("every worker is busy and {queued} jobs wait")]
    Full { queued: usize },
    #[error("the pool is shutting down")]
    Closed,
}

/// What the pool is doing now, for `/health` and `Retry-After`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PoolStats {
    pub workers: usize,
    pub busy: usize,
    pub queued: usize,
    pub queue_capacity: usize,
    pub completed: u64,
    /// Mean seconds a job took, over the finished ones (0 before the first).
    pub mean_job_s: f64,
}

struct State {
    jobs: VecDeque<Job>,
    busy: usize,
    closed: bool,
    completed: u64,
    job_seconds: f64,
}

struct Shared {
    state: Mutex<State>,
    ready: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A job that panicked poisons nothing we rely on: the counters stay consistent
        // because they are only changed under this lock, outside the job.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// `workers` threads, at most `queue` jobs waiting beyond the ones being run.
pub struct Pool {
    shared: Arc<Shared>,
    threads: Mutex<Vec<JoinHandle<()>>>,
    workers: usize,
    queue: usize,
}

impl Pool {
    /// Starts `workers` threads named `talkin-render-{i}`.
    pub fn new(workers: usize, queue: usize) -> std::io::Result<Pool> {
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                jobs: VecDeque::new(),
                busy: 0,
                closed: false,
                completed: 0,
                job_seconds: 0.0,
            }),
            ready: Condvar::new(),
        });
        let mut threads = Vec::with_capacity(workers);
        for i in 0..workers {
            let shared = shared.clone();
            threads.push(
                std::thread::Builder::new()
                    .name(format!("talkin-render-{i}"))
                    .spawn(move || worker(&shared))?,
            );
        }
        Ok(Pool {
            shared,
            threads: Mutex::new(threads),
            workers,
            queue,
        })
    }

    /// Queues `job` if a worker is idle or a queue slot is free; never blocks.
    pub fn try_submit(&self, job: Job) -> Result<(), Refused> {
        let mut s = self.shared.lock();
        if s.closed {
            return Err(Refused::Closed);
        }
        // Jobs meant for free workers that have not picked them up yet still sit in `jobs`.
        if s.jobs.len() >= self.workers - s.busy + self.queue {
            return Err(Refused::Full {
                queued: s.jobs.len(),
            });
        }
        s.jobs.push_back(job);
        drop(s);
        self.shared.ready.notify_one();
        Ok(())
    }

    pub fn stats(&self) -> PoolStats {
        let s = self.shared.lock();
        PoolStats {
            workers: self.workers,
            busy: s.busy,
            queued: s.jobs.len(),
            queue_capacity: self.queue,
            completed: s.completed,
            mean_job_s: if s.completed == 0 {
                0.0
            } else {
                s.job_seconds / s.completed as f64
            },
        }
    }

    /// A guess at when a refused client should retry: the time the queue ahead of it
    /// takes to drain, at least a second.
    pub fn retry_after(&self) -> Duration {
        let st = self.stats();
        let waves = (st.queued + st.busy) as f64 / self.workers as f64;
        Duration::from_secs_f64((st.mean_job_s * waves).ceil().max(1.0))
    }

    /// Refuses new jobs, lets the workers finish every queued one, and joins them.
    pub fn shutdown(&self) {
        self.shared.lock().closed = true;
        self.shared.ready.notify_all();
        let threads = std::mem::take(&mut *self.threads.lock().unwrap_or_else(|p| p.into_inner()));
        for t in threads {
            // A panicking job already reported itself on stderr.
            let _ = t.join();
        }
    }
}

impl Pool {
    /// Like [`Pool::shutdown`], but waits for the workers only until `deadline`: a worker
    /// still rendering then is left to finish on its own (unjoined). Returns how many were.
    pub fn shutdown_until(&self, deadline: Instant) -> usize {
        self.shared.lock().closed = true;
        self.shared.ready.notify_all();
        let mut threads =
            std::mem::take(&mut *self.threads.lock().unwrap_or_else(|p| p.into_inner()));
        loop {
            let (done, running): (Vec<_>, Vec<_>) =
                threads.into_iter().partition(|t| t.is_finished());
            for t in done {
                let _ = t.join();
            }
            let now = Instant::now();
            if running.is_empty() || now >= deadline {
                return running.len();
            }
            threads = running;
            std::thread::sleep((deadline - now).min(Duration::from_millis(5)));
        }
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn worker(shared: &Shared) {
    loop {
        let job = {
            let mut s = shared.lock();
            loop {
                if let Some(job) = s.jobs.pop_front() {
                    s.busy += 1;
                    break job;
                }
                if s.closed {
                    return;
                }
                s = shared.ready.wait(s).unwrap_or_else(|p| p.into_inner());
            }
        };
        let start = Instant::now();
        // A panic in one render must not take a worker away for good.
        let deliver = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job));
        {
            let mut s = shared.lock();
            s.busy -= 1;
            s.completed += 1;
            s.job_seconds += start.elapsed().as_secs_f64();
        }
        if let Ok(deliver) = deliver {
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(deliver));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// A job that blocks until its gate is opened, and says when it started.
    fn gated(started: mpsc::Sender<()>) -> (Job, mpsc::Sender<()>) {
        let (open, gate) = mpsc::channel::<()>();
        let job: Job = Box::new(move || {
            started.send(()).unwrap();
            let _ = gate.recv();
            Box::new(|| {})
        });
        (job, open)
    }

    #[test]
    fn refuses_beyond_workers_plus_queue_and_recovers() {
        let pool = Pool::new(2, 1).unwrap();
        let (started_tx, started) = mpsc::channel();
        let mut gates = Vec::new();
        for _ in 0..2 {
            let (job, gate) = gated(started_tx.clone());
            pool.try_submit(job).unwrap();
            gates.push(gate);
        }
        // Both workers hold a job before the queue is tested.
        started.recv().unwrap();
        started.recv().unwrap();
        let (job, gate) = gated(started_tx.clone());
        pool.try_submit(job).unwrap();
        gates.push(gate);
        let (job, _never) = gated(started_tx.clone());
        assert_eq!(pool.try_submit(job), Err(Refused::Full { queued: 1 }));
        let st = pool.stats();
        assert_eq!((st.busy, st.queued), (2, 1));
        assert!(pool.retry_after() >= Duration::from_secs(1));

        // Freeing a worker frees a slot.
        gates.remove(0).send(()).unwrap();
        started.recv().unwrap();
        let (job, gate) = gated(started_tx.clone());
        pool.try_submit(job).unwrap();
        gates.push(gate);
        for g in gates {
            g.send(()).unwrap();
        }
        pool.shutdown();
        assert_eq!(pool.stats().completed, 4);
        let (job, _) = gated(started_tx);
        assert_eq!(pool.try_submit(job), Err(Refused::Closed));
    }

    #[test]
    fn shutdown_finishes_queued_jobs_and_survives_panics() {
        let pool = Pool::new(1, 4).unwrap();
        let done = Arc::new(Mutex::new(0));
        pool.try_submit(Box::new(|| panic!("a broken render")))
            .unwrap();
        for _ in 0..3 {
            let done = done.clone();
            pool.try_submit(Box::new(move || {
                *done.lock().unwrap() += 1;
                Box::new(|| {})
            }))
            .unwrap();
        }
        pool.shutdown();
        assert_eq!(*done.lock().unwrap(), 3);
        assert_eq!(pool.stats().completed, 4);
    }

    #[test]
    fn shutdown_until_leaves_a_busy_worker_behind_at_the_deadline() {
        let pool = Pool::new(2, 0).unwrap();
        let (started_tx, started) = mpsc::channel();
        let (job, gate) = gated(started_tx);
        pool.try_submit(job).unwrap();
        started.recv().unwrap();
        let t = Instant::now();
        assert_eq!(pool.shutdown_until(t + Duration::from_millis(50)), 1);
        assert!(t.elapsed() < Duration::from_secs(5));
        assert_eq!(
            pool.try_submit(Box::new(|| Box::new(|| {}))),
            Err(Refused::Closed)
        );
        // The left worker still finishes its job; dropping the pool does not wait for it.
        gate.send(()).unwrap();
        drop(pool);
    }

    #[test]
    fn a_delivered_result_is_already_counted() {
        let pool = Pool::new(1, 0).unwrap();
        for n in 1..=20 {
            let (tx, rx) = mpsc::channel();
            pool.try_submit(Box::new(move || {
                Box::new(move || {
                    let _ = tx.send(());
                })
            }))
            .unwrap();
            rx.recv().unwrap();
            assert_eq!(pool.stats().completed, n);
        }
    }
}
