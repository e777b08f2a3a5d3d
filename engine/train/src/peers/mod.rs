//! Training as one of N data-parallel peers (`talkin-peers` says who they are and carries
//! the exchanges). Every peer draws the step's whole batch from the same seeded state,
//! computes the loss of its share of the rays ([`share_of`]), weighted by that share of
//! the batch, and the peers sum their gradients, pose gradients and losses
//! (`PeerLink::exchange`): each then holds the gradient of the whole batch and applies
//! the same Adam step, so the run is the single process's with the same `--batch`,
//! split (to the order of the float sums). Peer 0's clock is the run's, so a `--minutes`
//! budget ends every peer at the same step. Peer 0 alone writes the run.

mod costs;
pub(crate) mod fingerprint;
pub(crate) mod pack;

use std::ops::Range;
use std::time::Instant;

use burn::optim::GradientsParams;
use talkin_nets::{PoseGrads, TalkinField};
use talkin_peers::Collective;

use crate::error::TrainError;
pub use costs::ExchangeCosts;
use pack::Layout;

/// The rays of a batch of `n` rays that peer `rank` of `size` computes: contiguous ranges
/// in rank order whose union is the batch. The batch's first `patch_rays` rays (its LPIPS
/// patches, each scored whole) stay with peer 0, which may then hold more than its even
/// share; a peer may hold none.
pub fn share_of(rank: usize, size: usize, n: usize, patch_rays: usize) -> Range<usize> {
    let bound = |k: usize| match k {
        0 => 0,
        k if k >= size => n,
        k => (k * n / size).max(patch_rays).min(n),
    };
    bound(rank)..bound(rank + 1)
}

/// A step's values after the exchange: the whole batch's.
pub(crate) struct Exchanged {
    pub loss: f32,
    pub mse: f32,
    pub grads: GradientsParams,
    pub pose: Option<PoseGrads>,
    /// Peer 0's training clock at the exchange.
    pub clock: f64,
}

/// What one step hands to the exchange besides its gradients.
pub(crate) struct StepShare {
    pub step: usize,
    pub loss: f32,
    pub mse: f32,
    /// This peer's training clock (only peer 0's is kept).
    pub clock: f64,
    /// The frame drawn and the occupancy grids' occupied share: every peer must hold the
    /// same.
    pub agree: [f32; pack::N_AGREE],
}

/// A trainer's link to its peers.
pub struct PeerLink {
    collective: Box<dyn Collective>,
    layout: Option<Layout>,
    buf: Vec<f32>,
    /// This peer's own training seconds (peer 0's is the run's clock).
    pub(crate) local_elapsed: f64,
    /// `local_elapsed` when it joined (a resumed run's earlier seconds).
    pub(crate) joined_at: f64,
    /// What the exchanges cost this peer so far.
    pub costs: ExchangeCosts,
    /// This peer was asked to stop (a signal), and whether any peer was, at the last
    /// exchange: then every peer stops after the same step.
    pub(crate) stop_asked: bool,
    pub(crate) stop_agreed: bool,
}

impl PeerLink {
    pub fn new(collective: Box<dyn Collective>) -> PeerLink {
        PeerLink {
            collective,
            layout: None,
            buf: Vec::new(),
            local_elapsed: 0.0,
            joined_at: 0.0,
            costs: ExchangeCosts::default(),
            stop_asked: false,
            stop_agreed: false,
        }
    }

    pub fn rank(&self) -> usize {
        self.collective.rank()
    }

    pub fn size(&self) -> usize {
        self.collective.size()
    }

    /// What the exchanges cost this peer, in a line (`train` prints it at the end).
    pub fn summary(&self) -> String {
        self.costs.summary(
            self.rank(),
            self.size(),
            self.bytes_reduced(),
            self.local_elapsed - self.joined_at,
        )
    }

    /// Bytes this peer handed to the all-reduce so far.
    pub fn bytes_reduced(&self) -> u64 {
        self.collective.bytes_reduced()
    }

    /// Sums this peer's gradients, pose gradients and losses with the other peers'.
    pub(crate) fn exchange(
        &mut self,
        field: &TalkinField,
        grads: GradientsParams,
        pose: Option<PoseGrads>,
        share: StepShare,
    ) -> Result<Exchanged, TrainError> {
        let start = Instant::now();
        let with_pose = pose.is_some();
        let layout = match &self.layout {
            Some(l) if (l.pose > 0) == with_pose => l.clone(),
            _ => Layout::new(field, with_pose),
        };
        self.buf.resize(layout.len(), 0.0);
        layout.pack(field, &grads, pose.as_ref(), &mut self.buf);
        drop(grads);
        let rank = self.rank();
        let tail = layout.tail().start;
        self.buf[tail + pack::LOSS] = share.loss;
        self.buf[tail + pack::MSE] = share.mse;
        self.buf[tail + pack::CLOCK] = if rank == 0 { share.clock as f32 } else { 0.0 };
        for (i, a) in share.agree.iter().enumerate() {
            self.buf[tail + pack::AGREE + i] = *a;
        }
        self.buf[tail + pack::STOP] = if self.stop_asked { 1.0 } else { 0.0 };
        // A one-value all-reduce first: the wait for the slowest peer, apart from the
        // transfer (a few microseconds on loopback).
        let wait_start = Instant::now();
        self.collective
            .all_reduce_sum(&mut [0.0], &format!("step {}'s start", share.step))?;
        let reduce_start = Instant::now();
        self.costs.wait_s += (reduce_start - wait_start).as_secs_f64();
        self.collective
            .all_reduce_sum(&mut self.buf, &format!("step {}'s gradients", share.step))?;
        self.costs.reduce_s += reduce_start.elapsed().as_secs_f64();
        if share.step.is_multiple_of(10) {
            self.costs.count_blocks(&self.buf[..layout.grads]);
        }
        let size = self.size() as f32;
        const WHAT: [&str; pack::N_AGREE] = ["the frame drawn", "the occupancy grids"];
        for (i, (mine, what)) in share.agree.iter().zip(WHAT).enumerate() {
            let sum = self.buf[tail + pack::AGREE + i];
            if sum != mine * size {
                return Err(TrainError::PeersDiverged {
                    step: share.step,
                    what,
                    rank,
                    mine: *mine,
                    mean: sum / size,
                });
            }
        }
        self.stop_agreed = self.buf[tail + pack::STOP] > 0.0;
        let (grads, pose) = layout.unpack(field, &self.buf);
        let out = Exchanged {
            loss: self.buf[tail + pack::LOSS],
            mse: self.buf[tail + pack::MSE],
            grads,
            pose,
            clock: f64::from(self.buf[tail + pack::CLOCK]),
        };
        self.layout = Some(layout);
        self.costs.exchange_s += start.elapsed().as_secs_f64();
        self.costs.steps += 1;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_cover_the_batch_in_order_and_keep_the_patches_with_peer_0() {
        for (size, n, patches) in [
            (1, 100, 0),
            (2, 100, 0),
            (3, 100, 0),
            (2, 100, 64),
            (4, 100, 90),
            (8, 5, 0),
        ] {
            let shares: Vec<_> = (0..size).map(|r| share_of(r, size, n, patches)).collect();
            assert_eq!(shares[0].start, 0);
            assert_eq!(shares[size - 1].end, n);
            for w in shares.windows(2) {
                assert_eq!(w[0].end, w[1].start, "{shares:?}");
            }
            assert!(shares[0].end >= patches.min(n));
        }
        assert_eq!(share_of(0, 2, 100, 0), 0..50);
        assert_eq!(share_of(1, 2, 100, 64), 64..100);
        assert_eq!(share_of(1, 4, 100, 90), 90..90);
    }
}
