//! The peers of a data-parallel run: who they are ([`launch`]: the flags and the
//! variables MPI launchers and schedulers set), how they exchange ([`Collective`]: MPI
//! between processes, threads within one for tests) and the deadline on every exchange
//! ([`deadline`]: a peer that died or hangs stops the others, naming it).
//!
//! It must not know what is exchanged: gradients, losses and fingerprints are flat
//! buffers here, and training (talkin-train) decides what they hold.

pub mod collective;
pub mod deadline;
pub mod launch;
#[cfg(feature = "mpi")]
pub mod mpi_world;
pub mod threads;

pub use collective::{Collective, PeerError};
pub use launch::{Launch, LaunchError, Launcher};
