//! What a data-parallel step needs of its peers: a sum over all of them and a gather.

/// A collective that failed or was refused.
#[derive(Debug, thiserror::Error)]
pub enum PeerError {
    /// The engine reported an error during `what`.
    #[error("peer {rank} of {size}: {what} failed: {problem}")]
    Failed {
        rank: usize,
        size: usize,
        what: String,
        problem: String,
    },
    /// The peers disagree on what they run (dataset, recipe, build, step): refused before
    /// the first step.
    #[error("{0}")]
    Mismatch(String),
}

/// The peers of one run, seen from one of them. Every peer calls the same collectives in
/// the same order with buffers of the same length; every peer ends with the same bits.
pub trait Collective {
    /// This peer's rank, `0..size()`; rank 0 writes the run.
    fn rank(&self) -> usize;
    /// How many peers the run has.
    fn size(&self) -> usize;
    /// Sums `buf` element-wise over every peer, in place. `what` names the exchange in a
    /// deadline's message (`"step 17's gradients"`).
    fn all_reduce_sum(&mut self, buf: &mut [f32], what: &str) -> Result<(), PeerError>;
    /// Every peer's `mine`, by rank (each peer's `mine` has the same length).
    fn all_gather(&mut self, mine: &[u8], what: &str) -> Result<Vec<Vec<u8>>, PeerError>;
    /// Bytes this peer handed to the engine since it started (the buffers, not the
    /// engine's own traffic, which depends on its algorithm).
    fn bytes_reduced(&self) -> u64;
}
