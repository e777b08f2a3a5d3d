//! Peers as threads of one process, for tests: the same [`Collective`] calls, summed in
//! rank order under a lock (every peer gets the same bits, as MPI's gives).

use std::sync::{Arc, Barrier, Mutex};

use crate::collective::{Collective, PeerError};

struct Shared {
    slots: Mutex<Vec<Vec<u8>>>,
    sums: Mutex<Vec<Vec<f32>>>,
    barrier: Barrier,
}

/// One of `size` peers in this process (see [`ThreadPeers::group`]).
pub struct ThreadPeers {
    rank: usize,
    size: usize,
    shared: Arc<Shared>,
    bytes: u64,
}

impl ThreadPeers {
    /// `size` peers, ranks `0..size`, to hand one to each thread.
    pub fn group(size: usize) -> Vec<ThreadPeers> {
        let shared = Arc::new(Shared {
            slots: Mutex::new(vec![Vec::new(); size]),
            sums: Mutex::new(vec![Vec::new(); size]),
            barrier: Barrier::new(size),
        });
        (0..size)
            .map(|rank| ThreadPeers {
                rank,
                size,
                shared: shared.clone(),
                bytes: 0,
            })
            .collect()
    }
}

impl Collective for ThreadPeers {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn all_reduce_sum(&mut self, buf: &mut [f32], _what: &str) -> Result<(), PeerError> {
        self.bytes += 4 * buf.len() as u64;
        self.shared.sums.lock().expect("a peer thread panicked")[self.rank] = buf.to_vec();
        self.shared.barrier.wait();
        {
            let sums = self.shared.sums.lock().expect("a peer thread panicked");
            buf.fill(0.0);
            for s in sums.iter() {
                buf.iter_mut().zip(s).for_each(|(a, b)| *a += b);
            }
        }
        self.shared.barrier.wait();
        Ok(())
    }

    fn all_gather(&mut self, mine: &[u8], _what: &str) -> Result<Vec<Vec<u8>>, PeerError> {
        self.bytes += mine.len() as u64;
        self.shared.slots.lock().expect("a peer thread panicked")[self.rank] = mine.to_vec();
        self.shared.barrier.wait();
        let all = self
            .shared
            .slots
            .lock()
            .expect("a peer thread panicked")
            .clone();
        self.shared.barrier.wait();
        Ok(all)
    }

    fn bytes_reduced(&self) -> u64 {
        self.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_threads_sum_and_gather_the_same_bits() {
        let results: Vec<(Vec<f32>, Vec<Vec<u8>>)> = std::thread::scope(|s| {
            let handles: Vec<_> = ThreadPeers::group(3)
                .into_iter()
                .map(|mut p| {
                    s.spawn(move || {
                        let r = p.rank() as f32;
                        let mut buf = vec![r, 0.1 * r, 1.0];
                        p.all_reduce_sum(&mut buf, "test").unwrap();
                        let all = p.all_gather(&[p.rank() as u8; 2], "test").unwrap();
                        (buf, all)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for (buf, all) in &results {
            assert_eq!(buf, &results[0].0);
            assert_eq!(buf[0], 3.0);
            assert_eq!(buf[2], 3.0);
            assert_eq!(all, &vec![vec![0u8, 0], vec![1, 1], vec![2, 2]]);
        }
    }
}
