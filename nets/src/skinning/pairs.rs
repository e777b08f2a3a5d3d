//! Inverse skinning's pairs for the CPU: each sample's (sample, candidate bone) pairs with
//! the candidate's canonical point, the posed-space prior's logit and the volume corners
//! where the bone's logit is read (a CubeCL device finds all of it in its kernel).
//!
//! The CPU builds them for every forward, so they are laid out in parallel: a first
//! pass counts each sample's candidates, which fixes where its pairs go, and chunks of
//! samples then fill their own stretch of the output on rayon's threads. Each pair's
//! arithmetic is the same on any number of threads, so the pairs are too.

use rayon::prelude::*;

use super::prior::{NO_CAPSULE_LOGIT, capsule_distance};
use super::{BlendWeightVolume, BoneCapsule, FINGER_MASK, FINGER_TAU_FRACTION, N_SMPLX_JOINTS};

/// Samples a rayon task lays out.
const SAMPLES_PER_TASK: usize = 2048;

/// Host-side (sample, bone) pairs with their canonical points and volume corners, in
/// sample order.
pub(crate) struct Pairs {
    pub sample: Vec<i32>,
    pub bone: Vec<usize>,
    /// `[m * 3]`
    pub x: Vec<f32>,
    /// `[m * 8]`
    pub rows: Vec<i32>,
    /// `[m * 8]`
    pub weights: Vec<f32>,
    /// `[m]` the posed-space prior's logit (0 when off).
    pub posed: Vec<f32>,
}

/// One task's stretch of every output column.
struct Stretch<'a> {
    samples: std::ops::Range<usize>,
    sample: &'a mut [i32],
    bone: &'a mut [usize],
    x: &'a mut [f32],
    rows: &'a mut [i32],
    weights: &'a mut [f32],
    posed: &'a mut [f32],
}

impl BlendWeightVolume {
    /// The eight volume rows and trilinear weights where bone `b`'s logit is read at
    /// canonical point `xc`.
    fn corners(&self, b: usize, xc: [f32; 3]) -> ([i32; 8], [f32; 8]) {
        let r = self.resolution;
        let mut cell = [0usize; 3];
        let mut frac = [0f32; 3];
        for a in 0..3 {
            let span = self.aabb[3 + a] - self.aabb[a];
            let u = ((xc[a] - self.aabb[a]) / span * (r - 1) as f32).clamp(0.0, (r - 1) as f32);
            let c = (u.floor() as usize).min(r - 2);
            cell[a] = c;
            frac[a] = u - c as f32;
        }
        let mut rows = [0i32; 8];
        let mut weights = [0f32; 8];
        for k in 0..8 {
            let d = [k & 1, (k >> 1) & 1, k >> 2];
            let mut w = 1.0;
            for a in 0..3 {
                w *= if d[a] == 1 { frac[a] } else { 1.0 - frac[a] };
            }
            let (x, y, z) = (cell[0] + d[0], cell[1] + d[1], cell[2] + d[2]);
            rows[k] = (((b * r + z) * r + y) * r + x) as i32;
            weights[k] = w;
        }
        (rows, weights)
    }

    /// Each sample's (sample, candidate bone) pairs with their volume corners.
    pub(crate) fn pairs(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        canonical_from_posed: &[[f32; 16]],
        bone_capsules: &[BoneCapsule],
    ) -> Pairs {
        let by_bone = self.capsules_by_bone(bone_capsules);
        let candidates: Vec<u64> = bone_masks
            .par_iter()
            .map(|&mask| self.candidates(mask))
            .collect();
        // Where each sample's pairs start (the last entry is `m`).
        let mut start = Vec::with_capacity(candidates.len() + 1);
        start.push(0);
        for c in &candidates {
            start.push(start.last().unwrap() + c.count_ones() as usize);
        }
        let m = *start.last().unwrap();
        let mut p = Pairs {
            sample: vec![0; m],
            bone: vec![0; m],
            x: vec![0.0; 3 * m],
            rows: vec![0; 8 * m],
            weights: vec![0.0; 8 * m],
            posed: vec![0.0; m],
        };

        // Cut every column at the tasks' first pairs.
        let mut stretches = Vec::with_capacity(points.len().div_ceil(SAMPLES_PER_TASK));
        let (mut sample, mut bone, mut x) = (&mut p.sample[..], &mut p.bone[..], &mut p.x[..]);
        let (mut rows, mut weights) = (&mut p.rows[..], &mut p.weights[..]);
        let mut posed = &mut p.posed[..];
        for first in (0..points.len()).step_by(SAMPLES_PER_TASK) {
            let end = (first + SAMPLES_PER_TASK).min(points.len());
            let k = start[end] - start[first];
            let s;
            (s, sample) = sample.split_at_mut(k);
            let b;
            (b, bone) = bone.split_at_mut(k);
            let xs;
            (xs, x) = x.split_at_mut(3 * k);
            let r;
            (r, rows) = rows.split_at_mut(8 * k);
            let w;
            (w, weights) = weights.split_at_mut(8 * k);
            let l;
            (l, posed) = posed.split_at_mut(k);
            stretches.push(Stretch {
                samples: first..end,
                sample: s,
                bone: b,
                x: xs,
                rows: r,
                weights: w,
                posed: l,
            });
        }

        stretches
            .into_par_iter()
            .for_each(|out| self.fill(out, points, &candidates, canonical_from_posed, &by_bone));
        p
    }

    /// Lays out the pairs of `out`'s samples into its stretch of the columns.
    fn fill(
        &self,
        out: Stretch,
        points: &[[f32; 3]],
        candidates: &[u64],
        canonical_from_posed: &[[f32; 16]],
        by_bone: &[Vec<&BoneCapsule>; N_SMPLX_JOINTS],
    ) {
        let mut j = 0;
        for s in out.samples {
            let x = points[s];
            let mut bones = candidates[s];
            let tau = match self.posed_tau {
                Some(tau) if bones & FINGER_MASK != 0 => Some(tau * FINGER_TAU_FRACTION),
                tau => tau,
            };
            while bones != 0 {
                let b = bones.trailing_zeros() as usize;
                bones &= bones - 1;
                let m = &canonical_from_posed[b];
                let xc: [f32; 3] = std::array::from_fn(|i| {
                    (m[4 * i] as f64 * x[0] as f64
                        + m[4 * i + 1] as f64 * x[1] as f64
                        + m[4 * i + 2] as f64 * x[2] as f64
                        + m[4 * i + 3] as f64) as f32
                });
                let (r, w) = self.corners(b, xc);
                out.rows[8 * j..8 * j + 8].copy_from_slice(&r);
                out.weights[8 * j..8 * j + 8].copy_from_slice(&w);
                out.sample[j] = s as i32;
                out.bone[j] = b;
                out.x[3 * j..3 * j + 3].copy_from_slice(&xc);
                out.posed[j] = match tau {
                    Some(tau) => by_bone[b].iter().fold(NO_CAPSULE_LOGIT, |l, c| {
                        l.max(-capsule_distance(x, c) / tau)
                    }),
                    None => 0.0,
                };
                j += 1;
            }
        }
    }
}
