//! Packed samples: flat per-sample arrays plus per-ray offsets, no padding.

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;

use crate::rng::SplitMix64;
use crate::{GridError, Ray};

/// Candidate-part mask with every part set: nothing is known about the sample.
pub const ALL_PARTS: u8 = 0b1111;
/// Candidate-bone mask with all 55 SMPL-X joints set.
pub const ALL_BONES: u64 = (1 << 55) - 1;

/// Samples of a batch of rays, packed like nerfacc's: sample `s` of ray `i`
/// (`ray_offsets[i] <= s < ray_offsets[i + 1]`) covers `[t_start[s], t_end[s]]` along the
/// ray and is evaluated at its midpoint. A ray's samples are sorted and do not overlap.
/// `part_mask` / `bone_mask` are the candidate parts ([`crate::Part::bit`]) and bones
/// (bit = SMPL-X joint index) the sample may belong to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PackedSamples {
    /// `rays + 1` entries, from 0 to the sample count.
    pub ray_offsets: Vec<u32>,
    pub t_start: Vec<f32>,
    pub t_end: Vec<f32>,
    pub part_mask: Vec<u8>,
    pub bone_mask: Vec<u64>,
}

/// One sample while it is being produced, handed to the packer
/// ([`crate::packing::SampleColumns::push`]) that stores it as columns.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    pub t_start: f32,
    pub t_end: f32,
    pub part_mask: u8,
    pub bone_mask: u64,
}

/// Slack (metres) of [`PackedSamples::holds`] for a surface point read from a depth map:
/// 0.2 mm for the maps' 0.1 mm quantisation.
pub const SURFACE_SLACK_M: f32 = 2e-4;

impl PackedSamples {
    pub fn num_rays(&self) -> usize {
        self.ray_offsets.len().saturating_sub(1)
    }

    pub fn num_samples(&self) -> usize {
        self.t_start.len()
    }

    /// Index range of ray `i`'s samples.
    pub fn range(&self, i: usize) -> Range<usize> {
        self.ray_offsets[i] as usize..self.ray_offsets[i + 1] as usize
    }

    /// Whether a sample of ray `i` holds the point at `t` along it, give or take `slack`
    /// (the benches' and tests' check that a true surface point was sampled, with
    /// [`SURFACE_SLACK_M`]).
    pub fn holds(&self, i: usize, t: f32, slack: f32) -> bool {
        self.range(i)
            .any(|s| self.t_start[s] - slack <= t && t <= self.t_end[s] + slack)
    }

    /// The ray of every sample (nerfacc's `ray_indices`).
    pub fn ray_indices(&self) -> Vec<u32> {
        let mut out = Vec::with_capacity(self.num_samples());
        for i in 0..self.num_rays() {
            out.extend(std::iter::repeat_n(i as u32, self.range(i).len()));
        }
        out
    }

    /// Midpoint `t` of sample `s`.
    #[inline]
    pub fn t_mid(&self, s: usize) -> f32 {
        0.5 * (self.t_start[s] + self.t_end[s])
    }

    /// Length `t_end - t_start` of every sample (the renderer's deltas).
    pub fn deltas(&self) -> Vec<f32> {
        self.t_start
            .iter()
            .zip(&self.t_end)
            .map(|(a, b)| b - a)
            .collect()
    }

    /// World (posed) position of every sample's midpoint; `rays` are the rays sampled.
    ///
    /// # Panics
    /// If `rays.len()` differs from [`PackedSamples::num_rays`].
    pub fn midpoints_in_world(&self, rays: &[Ray]) -> Vec<Vec3> {
        assert_eq!(rays.len(), self.num_rays(), "rays do not match the samples");
        let mut out = vec![Vec3::ZERO; self.num_samples()];
        let mut rest = out.as_mut_slice();
        let mut chunks = Vec::with_capacity(rays.len());
        for i in 0..rays.len() {
            let (head, tail) = rest.split_at_mut(self.range(i).len());
            chunks.push((i, head));
            rest = tail;
        }
        chunks.into_par_iter().for_each(|(i, dst)| {
            for (k, p) in self.range(i).zip(dst.iter_mut()) {
                *p = rays[i].at(self.t_mid(k));
            }
        });
        out
    }

    /// Rays `0..k` and rays `k..` as two packings (e.g. one half-batch per thread).
    ///
    /// # Panics
    /// If `k` exceeds [`PackedSamples::num_rays`].
    pub fn split_at_ray(&self, k: usize) -> (PackedSamples, PackedSamples) {
        assert!(k <= self.num_rays(), "split past the last ray");
        let cut = self.ray_offsets[k] as usize;
        let head = PackedSamples {
            ray_offsets: self.ray_offsets[..=k].to_vec(),
            t_start: self.t_start[..cut].to_vec(),
            t_end: self.t_end[..cut].to_vec(),
            part_mask: self.part_mask[..cut].to_vec(),
            bone_mask: self.bone_mask[..cut].to_vec(),
        };
        let tail = PackedSamples {
            ray_offsets: self.ray_offsets[k..]
                .iter()
                .map(|o| o - cut as u32)
                .collect(),
            t_start: self.t_start[cut..].to_vec(),
            t_end: self.t_end[cut..].to_vec(),
            part_mask: self.part_mask[cut..].to_vec(),
            bone_mask: self.bone_mask[cut..].to_vec(),
        };
        (head, tail)
    }

    /// Appends `next`'s rays after these (the inverse of [`PackedSamples::split_at_ray`]).
    pub fn append(&mut self, next: PackedSamples) {
        let base = self.num_samples() as u32;
        if self.ray_offsets.is_empty() {
            self.ray_offsets.push(0);
        }
        self.ray_offsets
            .extend(next.ray_offsets.iter().skip(1).map(|o| o + base));
        self.t_start.extend(next.t_start);
        self.t_end.extend(next.t_end);
        self.part_mask.extend(next.part_mask);
        self.bone_mask.extend(next.bone_mask);
    }

    /// Checks the packed layout: offsets start at 0, never decrease and end at the
    /// sample count; every array has that length; every sample has
    /// `t_start <= t_end`, and a ray's samples are sorted and do not overlap.
    pub fn check_layout(&self) -> Result<(), GridError> {
        let bad = |msg: String| Err(GridError::BadPacking(msg));
        let n = self.num_samples();
        if self.ray_offsets.first() != Some(&0) {
            return bad("ray_offsets must start at 0".into());
        }
        if let Some(w) = self.ray_offsets.windows(2).position(|w| w[0] > w[1]) {
            return bad(format!("ray_offsets decrease at ray {w}"));
        }
        if *self.ray_offsets.last().unwrap() as usize != n {
            return bad(format!(
                "ray_offsets end at {:?}, not {n}",
                self.ray_offsets.last()
            ));
        }
        let lens = [self.t_end.len(), self.part_mask.len(), self.bone_mask.len()];
        if lens.iter().any(|&l| l != n) {
            return bad(format!("array lengths {lens:?} differ from t_start's {n}"));
        }
        for i in 0..self.num_rays() {
            let r = self.range(i);
            for s in r.clone() {
                if !(self.t_start[s] <= self.t_end[s]) {
                    return bad(format!("sample {s} has t_start > t_end (or NaN)"));
                }
                if s + 1 < r.end && self.t_end[s] > self.t_start[s + 1] {
                    return bad(format!("samples {s} and {} overlap", s + 1));
                }
            }
        }
        Ok(())
    }

    /// Keeps the samples with `keep[s]`, preserving order and per-ray grouping.
    ///
    /// # Panics
    /// If `keep.len()` differs from [`PackedSamples::num_samples`].
    pub fn retain(&mut self, keep: &[bool]) {
        assert_eq!(keep.len(), self.num_samples(), "keep mask length");
        let mut w = 0usize;
        let mut offsets = Vec::with_capacity(self.ray_offsets.len());
        offsets.push(0u32);
        for i in 0..self.num_rays() {
            for s in self.range(i) {
                if keep[s] {
                    self.t_start[w] = self.t_start[s];
                    self.t_end[w] = self.t_end[s];
                    self.part_mask[w] = self.part_mask[s];
                    self.bone_mask[w] = self.bone_mask[s];
                    w += 1;
                }
            }
            offsets.push(w as u32);
        }
        self.ray_offsets = offsets;
        self.t_start.truncate(w);
        self.t_end.truncate(w);
        self.part_mask.truncate(w);
        self.bone_mask.truncate(w);
    }
}

/// Splits `[t0, t1]` into `n` contiguous bins. With `rng`, each inner boundary moves
/// uniformly within +-0.45 of a bin width around its regular place (stratified jitter:
/// bins stay contiguous, tile `[t0, t1]` exactly and keep at least 0.1 of a width);
/// without, the bins are regular.
pub(crate) fn stratified_bins(
    t0: f32,
    t1: f32,
    n: u32,
    mut rng: Option<&mut SplitMix64>,
    mut emit: impl FnMut(f32, f32),
) {
    let width = (t1 - t0) / n as f32;
    let mut prev = t0;
    for i in 1..n {
        let shift = rng.as_mut().map_or(0.0, |r| 0.9 * (r.next_f32() - 0.5));
        let b = (t0 + (i as f32 + shift) * width).clamp(prev, t1);
        emit(prev, b);
        prev = b;
    }
    emit(prev, t1);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn append_undoes_a_split_at_every_ray() {
        let all = PackedSamples {
            ray_offsets: vec![0, 2, 2, 5],
            t_start: vec![0.0, 1.0, 0.0, 1.0, 2.0],
            t_end: vec![0.5, 1.5, 0.5, 1.5, 2.5],
            part_mask: vec![1, 2, 3, 4, 5],
            bone_mask: vec![1, 2, 3, 4, 5],
        };
        for k in 0..=all.num_rays() {
            let (mut head, tail) = all.split_at_ray(k);
            head.append(tail);
            assert_eq!(head, all, "split at ray {k}");
        }
        let mut empty = PackedSamples::default();
        empty.append(all.clone());
        assert_eq!(empty, all);
    }

    #[test]
    fn split_at_ray_gives_both_halves_with_their_own_offsets() {
        // Rays with 2, 0 and 3 samples.
        let all = PackedSamples {
            ray_offsets: vec![0, 2, 2, 5],
            t_start: vec![0.0, 1.0, 0.0, 1.0, 2.0],
            t_end: vec![0.5, 1.5, 0.5, 1.5, 2.5],
            part_mask: vec![1; 5],
            bone_mask: vec![1, 2, 3, 4, 5],
        };
        for k in 0..=3 {
            let (a, b) = all.split_at_ray(k);
            a.check_layout().unwrap();
            b.check_layout().unwrap();
            assert_eq!((a.num_rays(), b.num_rays()), (k, 3 - k));
            assert_eq!(a.num_samples() + b.num_samples(), 5);
            for i in 0..3 {
                let (half, j) = if i < k { (&a, i) } else { (&b, i - k) };
                let got: Vec<u64> = half.range(j).map(|s| half.bone_mask[s]).collect();
                let want: Vec<u64> = all.range(i).map(|s| all.bone_mask[s]).collect();
                assert_eq!(got, want, "k {k}, ray {i}");
            }
        }
    }
}
