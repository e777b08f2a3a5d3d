//! What the exchanges cost a peer: the seconds they and the work every peer repeats
//! take, and the gradient blocks no peer touched (what a sparse all-reduce would skip).

/// A peer's exchange costs, summed over the steps it exchanged.
#[derive(Clone, Debug, Default)]
pub struct ExchangeCosts {
    /// The whole exchange: waiting, packing, the all-reduce and unpacking.
    pub exchange_s: f64,
    /// Waiting for the slowest peer (a one-value all-reduce before the gradients').
    pub wait_s: f64,
    /// The gradients' all-reduce alone.
    pub reduce_s: f64,
    /// What every peer repeats whatever its share: Adam, pose refinement and the grid
    /// updates (`update_s`), and drawing the whole batch's samples (`sampling_s`).
    pub update_s: f64,
    pub sampling_s: f64,
    /// Over every tenth step: the gradient's 64-value blocks, and those zero on every
    /// peer.
    pub blocks: u64,
    pub zero_blocks: u64,
    /// Steps exchanged.
    pub steps: usize,
}

impl ExchangeCosts {
    /// Counts the summed gradient's 64-value blocks, and those that are zero.
    pub(crate) fn count_blocks(&mut self, grads: &[f32]) {
        for block in grads.chunks(64) {
            self.blocks += 1;
            self.zero_blocks += u64::from(block.iter().all(|v| *v == 0.0));
        }
    }

    /// The costs in a line: per step, and as shares of `train_s` seconds of training, for
    /// peer `rank` of `size` that all-reduced `bytes` in all.
    pub fn summary(&self, rank: usize, size: usize, bytes: u64, train_s: f64) -> String {
        let steps = self.steps.max(1) as f64;
        let ms = |s: f64| 1e3 * s / steps;
        let share = |s: f64| 100.0 * s / train_s.max(1e-9);
        let zero = self.zero_blocks as f64 / self.blocks.max(1) as f64;
        format!(
            "peer {rank} of {size}: {} steps exchanged, {:.2} MB all-reduced a step; the \
             all-reduce {:.1} ms a step ({:.1}% of this peer's training time), waiting for \
             the slowest peer {:.1} ms ({:.1}%), the whole exchange (waiting, packing and \
             unpacking included) {:.1} ms ({:.1}%); repeated on every peer: Adam and the grid \
             updates {:.1} ms ({:.1}%), sampling the whole batch {:.1} ms ({:.1}%); {:.0}% of \
             the gradient's 64-value blocks were zero on every peer",
            self.steps,
            bytes as f64 / steps / 1e6,
            ms(self.reduce_s),
            share(self.reduce_s),
            ms(self.wait_s),
            share(self.wait_s),
            ms(self.exchange_s),
            share(self.exchange_s),
            ms(self.update_s),
            share(self.update_s),
            ms(self.sampling_s),
            share(self.sampling_s),
            100.0 * zero,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_untouched_by_every_peer_are_counted() {
        let mut c = ExchangeCosts::default();
        let mut grads = vec![0.0f32; 64 * 4];
        grads[70] = 1.0; // block 1
        grads[255] = -2.0; // block 3
        c.count_blocks(&grads);
        assert_eq!((c.blocks, c.zero_blocks), (4, 2));
        c.steps = 2;
        c.reduce_s = 0.02;
        let line = c.summary(0, 2, 48_000_000, 1.0);
        assert!(line.contains("24.00 MB all-reduced a step"), "{line}");
        assert!(
            line.contains("the all-reduce 10.0 ms a step (2.0%"),
            "{line}"
        );
        assert!(
            line.contains("50% of the gradient's 64-value blocks"),
            "{line}"
        );
    }
}
