//! The HumanNeRF baseline: stratified samples over the ray's stretch in the posed box.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::packing::par_pack;
use crate::ray::{clip_to_box, validate_rays};
use crate::rng::SplitMix;
use crate::samples::{ALL_BONES, ALL_PARTS, PackedSamples, Sample, stratified_bins};
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
    let (offsets, samples) = par_pack(
        rays.len(),
        || (),
        |_, i, out| {
            let Some((t0, t1)) = clip_to_box(&rays[i], bbox_min, bbox_max) else {
                return;
            };
            let mut rng = SplitMix::new(opts.seed, i as u64);
            let rng = opts.jitter.then_some(&mut rng);
            stratified_bins(t0, t1, opts.samples_per_ray, rng, |a, b| {
                out.push(Sample {
                    t_start: a,
                    t_end: b,
                    part_mask: ALL_PARTS,
                    bone_mask: ALL_BONES,
                })
            });
        },
    );
    Ok(PackedSamples::from_parts(offsets, samples))
}

pub(crate) fn check_box(min: Vec3, max: Vec3) -> Result<(), GridError> {
    if min.is_finite() && max.is_finite() && min.cmplt(max).all() {
        Ok(())
    } else {
        Err(GridError::BadBox { min, max })
    }
}
