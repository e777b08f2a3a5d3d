//! Inverse skinning on a CubeCL device (`kernels::cube::skin`): the host uploads each
//! sample's point and candidate bones (a mask) and the frame's numbers; the kernel does
//! the rest, so no (sample, bone) pair is laid out or uploaded.

use burn::prelude::*;
use rayon::prelude::*;

use super::{BlendWeightVolume, BoneCapsule, FINGER_TAU_FRACTION, N_SMPLX_JOINTS};
use crate::kernels::cube::skin::{
    CAPSULE_PARAMS, CAPSULE_STARTS, FINGER_TAU, FIRST_FINGER, FRAME_HEAD, MASK_BITS, N_JOINTS, TAU,
    warp,
};
use crate::util::{floats, ints};

const _: () = assert!(N_JOINTS == N_SMPLX_JOINTS && FIRST_FINGER == super::FIRST_FINGER_JOINT);
// Two words hold every joint, neither uses an int's sign bit, and the fingers start in
// the first (the kernel's finger test reads the first word's top bits and all the second).
const _: () =
    assert!(2 * MASK_BITS >= N_SMPLX_JOINTS && MASK_BITS < 31 && FIRST_FINGER < MASK_BITS);

impl BlendWeightVolume {
    /// The warp on a CubeCL device (`kernels::cube::skin`): one unit per sample over its
    /// candidates, their canonical points from `transforms` `[55, 12]` (which may require
    /// gradients). Uploads the points, the candidates and the frame's numbers; returns the
    /// canonical points and how many (sample, bone) pairs the kernel weighs.
    pub(super) fn warp_on_device(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        bone_capsules: &[BoneCapsule],
        transforms: Tensor<2>,
        device: &Device,
    ) -> (Tensor<2>, usize) {
        let n = points.len();
        let (words, pairs) = self.candidate_words(bone_masks);
        let flat = points.as_flattened().to_vec();
        let frame = self.frame_numbers(bone_capsules);
        let len = frame.len();
        let x_canonical = warp(
            self.logits.val(),
            transforms,
            floats(flat, [n, 3], device),
            floats(frame, [len], device),
            ints(words, device).reshape([n, 2]),
        );
        (x_canonical, pairs)
    }

    /// Each sample's candidate bones as two words of [`MASK_BITS`] bits, and how many
    /// there are in all.
    fn candidate_words(&self, bone_masks: &[u64]) -> (Vec<i32>, usize) {
        let low = (1u64 << MASK_BITS) - 1;
        let words: Vec<i32> = bone_masks
            .par_iter()
            .flat_map_iter(|&mask| {
                let c = self.candidates(mask);
                [(c & low) as i32, (c >> MASK_BITS) as i32]
            })
            .collect();
        let pairs = words.par_iter().map(|w| w.count_ones() as usize).sum();
        (words, pairs)
    }

    /// The kernel's `frame`: the volume's grid, the posed prior's temperatures (0 when
    /// off) and each skinned joint's capsules (see `skin_kernels`).
    fn frame_numbers(&self, bone_capsules: &[BoneCapsule]) -> Vec<f32> {
        let by_bone = self.capsules_by_bone(bone_capsules);
        let mut frame = vec![0.0; FRAME_HEAD];
        let r = self.resolution;
        frame[..3].copy_from_slice(&self.aabb[..3]);
        for a in 0..3 {
            frame[3 + a] = (r - 1) as f32 / (self.aabb[3 + a] - self.aabb[a]);
        }
        frame[6] = r as f32;
        if let Some(tau) = self.posed_tau {
            frame[TAU] = tau;
            frame[FINGER_TAU] = tau * FINGER_TAU_FRACTION;
        }
        let mut count = 0;
        for (b, caps) in by_bone.iter().enumerate() {
            frame[CAPSULE_STARTS + b] = count as f32;
            for c in caps {
                frame.extend(c.a.iter().chain(&c.b).chain([&c.radius]));
            }
            count += caps.len();
        }
        frame[CAPSULE_STARTS + N_SMPLX_JOINTS] = count as f32;
        debug_assert_eq!(frame.len(), FRAME_HEAD + CAPSULE_PARAMS * count);
        frame
    }
}
