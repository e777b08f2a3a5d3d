//! Inverse skinning's blend on a CubeCL device (`kernels::cube::skin`): the pairs laid
//! out for the kernel, one row of slots per sample.

use burn::prelude::*;
use rayon::prelude::*;

use super::BlendWeightVolume;
use super::pairs::Pairs;
use crate::kernels::cube::skin::{GRID_PARAMS, PAIR_PARAMS, blend};
use crate::util::{floats, ints};

/// Pairs a rayon task lays out for the kernel.
const PAIRS_PER_TASK: usize = 4096;

impl BlendWeightVolume {
    /// The softmax blend on a CubeCL device (`kernels::cube::skin`): one unit per sample
    /// over its candidates, the volume's corners found in the kernel from the pairs' host
    /// points. Uploads the pairs' numbers with the grid's, and the slots.
    pub(super) fn blend_on_device(
        &self,
        p: &Pairs,
        n: usize,
        xb: Tensor<2>,
        device: &Device,
    ) -> Tensor<2> {
        let numbers = self.pair_numbers(p);
        let (slots, k) = padded_slots(&p.start);
        let len = numbers.len();
        blend(
            self.logits.val(),
            xb,
            floats(numbers, [len], device),
            ints(slots, device).reshape([n, k]),
        )
    }

    /// The kernel's `pairs` tensor: each pair's canonical point, bone and posed logit
    /// ([`PAIR_PARAMS`] numbers), then the grid's ([`GRID_PARAMS`]).
    fn pair_numbers(&self, p: &Pairs) -> Vec<f32> {
        let m = p.sample.len();
        let r = self.resolution;
        let mut numbers = vec![0.0; m * PAIR_PARAMS + GRID_PARAMS];
        let (pairs, grid) = numbers.split_at_mut(m * PAIR_PARAMS);
        pairs
            .par_chunks_mut(PAIR_PARAMS * PAIRS_PER_TASK)
            .enumerate()
            .for_each(|(c, out)| {
                for (k, row) in out.chunks_exact_mut(PAIR_PARAMS).enumerate() {
                    let i = c * PAIRS_PER_TASK + k;
                    row[..3].copy_from_slice(&p.x[3 * i..3 * i + 3]);
                    row[3] = p.bone[i] as f32;
                    row[4] = p.posed[i];
                }
            });
        grid[..3].copy_from_slice(&self.aabb[..3]);
        for a in 0..3 {
            grid[3 + a] = (r - 1) as f32 / (self.aabb[3 + a] - self.aabb[a]);
        }
        grid[6] = r as f32;
        numbers
    }
}

/// Each sample's pairs in a row of `K` slots (`K` the most any sample has), from where
/// each sample's pairs `start` (`[n + 1]`; pairs are sorted by sample): slot `(s, j)`
/// holds the index of sample `s`'s `j`-th pair, the rest `m`, past the last pair.
fn padded_slots(start: &[usize]) -> (Vec<i32>, usize) {
    let m = *start.last().unwrap_or(&0);
    let k = start
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(1)
        .max(1);
    let mut slot = vec![m as i32; (start.len() - 1) * k];
    slot.par_chunks_mut(k)
        .zip(start.par_windows(2))
        .for_each(|(row, w)| {
            for (j, pair) in (w[0]..w[1]).enumerate() {
                row[j] = pair as i32;
            }
        });
    (slot, k)
}
