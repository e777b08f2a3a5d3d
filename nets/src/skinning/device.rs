//! Inverse skinning's blend on a CubeCL device (`kernels::cube::skin`): the pairs laid
//! out for the kernel, one row of slots per sample.

use burn::prelude::*;

use super::{BlendWeightVolume, Pairs};
use crate::kernels::cube::skin::{GRID_PARAMS, PAIR_PARAMS, blend};
use crate::util::{floats, ints};

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
        let m = p.sample.len();
        let r = self.resolution;
        let mut numbers = Vec::with_capacity(m * PAIR_PARAMS + GRID_PARAMS);
        for (i, x) in p.x.chunks_exact(3).enumerate() {
            numbers.extend_from_slice(x);
            numbers.extend([p.bone[i] as f32, p.posed[i]]);
        }
        numbers.extend_from_slice(&self.aabb[..3]);
        numbers.extend((0..3).map(|a| (r - 1) as f32 / (self.aabb[3 + a] - self.aabb[a])));
        numbers.push(r as f32);
        let (slots, k) = padded_slots(&p.sample, n);
        let len = numbers.len();
        blend(
            self.logits.val(),
            xb,
            floats(numbers, [len], device),
            ints(slots, device).reshape([n, k]),
        )
    }
}

/// Each sample's pairs in a row of `K` slots (`K` the most any sample has): slot
/// `(s, j)` holds the index of sample `s`'s `j`-th pair (pairs are sorted by sample), the
/// rest `m`, past the last pair.
fn padded_slots(sample: &[i32], n: usize) -> (Vec<i32>, usize) {
    let m = sample.len();
    let mut count = vec![0usize; n];
    for &s in sample {
        count[s as usize] += 1;
    }
    let k = count.iter().copied().max().unwrap_or(1).max(1);
    let mut slot = vec![m as i32; n * k];
    let mut start = 0;
    for (s, &c) in count.iter().enumerate() {
        for j in 0..c {
            slot[s * k + j] = (start + j) as i32;
        }
        start += c;
    }
    (slot, k)
}
