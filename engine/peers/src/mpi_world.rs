//! The peers of an MPI job (rsmpi over the system's MPI): `MPI_Allreduce` and
//! `MPI_Allgather` on `MPI_COMM_WORLD`, each under the [`Deadline`].
//!
//! A peer that dies is seen by the launcher, which ends the job naming it (Open MPI's
//! `mpirun`: "process rank 1 ... exited on signal 9"); one that hangs never arrives, and
//! the others' deadline ends them, naming the peers they waited for.

use std::time::Duration;

use mpi::collective::SystemOperation;
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

use crate::collective::{Collective, PeerError};
use crate::deadline::Deadline;
use crate::launch::{Launch, LaunchError, Launcher, check_flags};

/// How many times an exchange's bound the registration may wait for the slowest peer's
/// start (a peer that dies meanwhile is seen by the launcher at once).
pub const REGISTRATION_FACTOR: u32 = 4;

/// This process as one peer of an MPI job.
pub struct MpiPeers {
    world: SimpleCommunicator,
    rank: usize,
    size: usize,
    /// The bound on each exchange.
    within: Duration,
    deadline: Deadline,
    scratch: Vec<f32>,
    bytes: u64,
    /// Finalizes MPI when dropped (after `world`).
    _universe: Universe,
}

impl MpiPeers {
    /// Joins the MPI job `launch` describes (initialising MPI, one thread calling it) and
    /// checks that its world is the one the flags and variables said. `within` bounds
    /// every all-reduce; the gather, which registers the peers before the first step and
    /// so also waits for the slowest peer's start (its dataset load, its census), gets
    /// [`REGISTRATION_FACTOR`] times it.
    pub fn join(launch: &Launch, within: Duration) -> Result<MpiPeers, LaunchError> {
        let Launcher::Mpi { via } = launch.launcher else {
            return Err(LaunchError::NoLauncher {
                what: "no MPI launcher's variables are set".into(),
                size: launch.size,
                alone: "without peers, leave --nodes out",
            });
        };
        let (universe, _) =
            mpi::initialize_with_threading(mpi::Threading::Funneled).ok_or(LaunchError::Value {
                name: "MPI".into(),
                expected: "not yet initialised in this process",
                value: "initialised".into(),
            })?;
        let world = universe.world();
        let (rank, size) = (world.rank() as usize, world.size() as usize);
        check_flags(Some(launch.size), Some(launch.rank), size, rank, via)?;
        Ok(MpiPeers {
            world,
            rank,
            size,
            within,
            deadline: Deadline::exiting(),
            scratch: Vec::new(),
            bytes: 0,
            _universe: universe,
        })
    }

    /// The deadline's message for `what`: who this is and whom it waited for.
    fn lost(&self, what: &str, within: Duration) -> String {
        let others: Vec<String> = (0..self.size)
            .filter(|&r| r != self.rank)
            .map(|r| r.to_string())
            .collect();
        let whom = if others.len() == 1 {
            format!("peer {} died or hangs", others[0])
        } else {
            format!("one of peers {} died or hangs", others.join(", "))
        };
        format!(
            "lost a peer: peer {} of {} waited {:.0} s for {what}: {whom}. This peer stops \
             (exit 1); the run's last checkpoint stands: start all peers again with \
             --resume",
            self.rank,
            self.size,
            within.as_secs_f64()
        )
    }
}

impl Collective for MpiPeers {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn all_reduce_sum(&mut self, buf: &mut [f32], what: &str) -> Result<(), PeerError> {
        self.bytes += 4 * buf.len() as u64;
        self.scratch.resize(buf.len(), 0.0);
        let message = self.lost(what, self.within);
        let _armed = self.deadline.arm(self.within, message);
        self.world
            .all_reduce_into(&buf[..], &mut self.scratch[..], SystemOperation::sum());
        buf.copy_from_slice(&self.scratch);
        Ok(())
    }

    fn all_gather(&mut self, mine: &[u8], what: &str) -> Result<Vec<Vec<u8>>, PeerError> {
        self.bytes += mine.len() as u64;
        let mut all = vec![0u8; mine.len() * self.size];
        let within = self.within * REGISTRATION_FACTOR;
        let message = self.lost(what, within);
        let _armed = self.deadline.arm(within, message);
        self.world.all_gather_into(mine, &mut all[..]);
        Ok(all.chunks(mine.len().max(1)).map(<[u8]>::to_vec).collect())
    }

    fn bytes_reduced(&self) -> u64 {
        self.bytes
    }
}
