//! The HumanNeRF baseline: stratified samples over the ray's stretch in the posed box.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use rayon::prelude::*;

use crate::ray::{clip_to_box, validate_rays};
use crate::rng::SplitMix64;
use crate::samples::{ALL_BONES, ALL_PARTS, PackedSamples, stratified_bins};
use crate::{GridError, Ray};

/// Options of [`sample_dense`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DenseOpts {
    /// Samples per ray that meets the box (HumanNeRF: 128).
    pub samples_per_ray: u32,
    /// Stratified jitter (training); off gives regular bins (evaluation).
    pub jitter: bool,
    /// Jitter seed, e.g. the training step; mixed with the ray index.
    pub seed: u64,
}

impl Default for DenseOpts {
    fn default() -> Self {
        DenseOpts {
            samples_per_ray: 128,
            jitter: true,
            seed: 0,
        }
    }
}

/// `samples_per_ray` stratified samples over each ray's stretch inside the posed box
/// `[bbox_min, bbox_max]` (world space: the joints +- a margin), none for rays that miss
/// it. Nothing is known about the samples, so every part and bone is a candidate.
pub fn sample_dense(
    rays: &[Ray],
    bbox_min: Vec3,
    bbox_max: Vec3,
    opts: &DenseOpts,
) -> Result<PackedSamples, GridError> {
    validate_rays(rays)?;
    check_box(bbox_min, bbox_max)?;
    if opts.samples_per_ray == 0 {
        return Err(GridError::BadOption {
            field: "samples_per_ray",
            value: 0.0,
            expected: ">= 1",
        });
    }
    // Every ray that meets the box gets exactly `n` samples, so the layout is known
    // up front and the arrays are filled in place, ray-parallel.
    let n = opts.samples_per_ray as usize;
    let spans: Vec<Option<(f32, f32)>> = rays
        .par_iter()
        .map(|r| clip_to_box(r, bbox_min, bbox_max))
        .collect();
    let mut ray_offsets = Vec::with_capacity(rays.len() + 1);
    ray_offsets.push(0u32);
    let mut total = 0usize;
    for span in &spans {
        total += if span.is_some() { n } else { 0 };
        ray_offsets.push(u32::try_from(total).expect("more than 2^32 dense samples"));
    }
    let hit: Vec<(usize, (f32, f32))> = spans
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.map(|s| (i, s)))
        .collect();
    let mut t_start = vec![0.0f32; total];
    let mut t_end = vec![0.0f32; total];
    t_start
        .par_chunks_mut(n)
        .zip(t_end.par_chunks_mut(n))
        .zip(hit.par_iter())
        .for_each(|((starts, ends), &(i, (t0, t1)))| {
            let mut rng = SplitMix64::for_stream(opts.seed, i as u64);
            let rng = opts.jitter.then_some(&mut rng);
            let mut k = 0;
            stratified_bins(t0, t1, opts.samples_per_ray, rng, |a, b| {
                starts[k] = a;
                ends[k] = b;
                k += 1;
            });
        });
    Ok(PackedSamples {
        ray_offsets,
        t_start,
        t_end,
        part_mask: vec![ALL_PARTS; total],
        bone_mask: vec![ALL_BONES; total],
    })
}

pub(crate) fn check_box(min: Vec3, max: Vec3) -> Result<(), GridError> {
    if min.is_finite() && max.is_finite() && min.cmplt(max).all() {
        Ok(())
    } else {
        Err(GridError::BadBox { min, max })
    }
}
