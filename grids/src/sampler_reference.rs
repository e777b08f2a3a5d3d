//! The reference sampler: samples only where the posed capsules are (over the [`CapsuleBvh`]),
//! culled by the canonical occupancy grid. Plain and obvious, and slow: the
//! [`crate::AcceleratedSampler`] is tested against it, sample for sample.

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::intervals::{candidates_at, merge_hits};
use crate::packing::par_pack_samples;
use crate::ray::validate_rays;
use crate::rng::SplitMix64;
use crate::samples::{PackedSamples, Sample, stratified_bins};
use crate::{CapsuleBvh, GridError, OccupancyGrid, Ray};

/// Options of [`sample_reference`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AcceleratedOpts {
    /// Sample length, metres along the ray. Each merged capsule interval is cut into
    /// `ceil(length / step)` bins of equal length (at most `step`); jitter then moves
    /// their inner boundaries by up to 0.45 of a bin, so one jittered sample is at most
    /// 1.9 `step` long, as with HumanNeRF's stratified sampling.
    pub step: f32,
    /// Stratified jitter (training); off gives regular bins (evaluation).
    pub jitter: bool,
    /// Jitter seed, e.g. the training step; mixed with the ray index.
    pub seed: u64,
}

impl AcceleratedOpts {
    /// The step that matches the dense sampler's resolution: the posed box's diagonal
    /// over `samples_per_ray` (128 in HumanNeRF). The dense sampler spreads its samples
    /// over the ray's chord through the box, never longer than the diagonal, so this
    /// step is at most as fine as dense on the longest chord and about as fine on the
    /// typical one: same quadrature inside the body, no samples in empty space.
    pub fn matching_dense(bbox_min: Vec3, bbox_max: Vec3, samples_per_ray: u32) -> Self {
        AcceleratedOpts {
            step: (bbox_max - bbox_min).length() / samples_per_ray.max(1) as f32,
            jitter: true,
            seed: 0,
        }
    }
}

/// Samples inside the BVH's merged capsule intervals at `opts.step`, each sample with
/// the parts and bones of the capsules containing its midpoint (the capsules carry
/// their data-fitted margins, see [`crate::margins`]). Zero-length intervals (tangent
/// rays) get no samples. No occupancy culling: see [`sample_reference`].
pub fn sample_in_capsules(
    bvh: &CapsuleBvh,
    rays: &[Ray],
    opts: &AcceleratedOpts,
) -> Result<PackedSamples, GridError> {
    sample_in_capsules_before(bvh, rays, None, opts)
}

/// [`sample_in_capsules`], but ray `i` is only sampled up to `t_stop[i]` (intervals are
/// clipped there before they are cut into bins): the same as sampling everything and
/// dropping what lies behind, without generating it first. `t_stop` may be infinite.
pub fn sample_in_capsules_before(
    bvh: &CapsuleBvh,
    rays: &[Ray],
    t_stop: Option<&[f32]>,
    opts: &AcceleratedOpts,
) -> Result<PackedSamples, GridError> {
    validate_rays(rays)?;
    if let Some(stop) = t_stop
        && stop.len() != rays.len()
    {
        return Err(GridError::LengthMismatch {
            what: "t_stop for the rays",
            expected: rays.len(),
            got: stop.len(),
        });
    }
    if !(opts.step.is_finite() && opts.step > 0.0) {
        return Err(GridError::BadOption {
            field: "step",
            value: opts.step,
            expected: "finite and > 0",
        });
    }
    let capsules = bvh.capsules();
    let samples = par_pack_samples(
        rays.len(),
        || (Vec::new(), Vec::new()),
        |(hits, intervals), i, out| {
            hits.clear();
            intervals.clear();
            bvh.for_each_hit(&rays[i], |h| hits.push(h));
            merge_hits(hits, capsules, intervals);
            let mut rng = SplitMix64::for_stream(opts.seed, i as u64);
            let stop = t_stop.map_or(f32::INFINITY, |s| s[i]);
            for v in intervals.iter() {
                if !(v.t_in < stop) {
                    break;
                }
                let t_out = v.t_out.min(stop);
                let length = t_out - v.t_in;
                if !(length > 0.0) {
                    continue;
                }
                // The slack keeps 0.15 / 0.01 (= 15.000001 in f32) at 15 bins.
                let n = (length / opts.step * (1.0 - 1e-5)).ceil().max(1.0) as u32;
                let rng = opts.jitter.then_some(&mut rng);
                stratified_bins(v.t_in, t_out, n, rng, |a, b| {
                    let (mut parts, mut bones) = candidates_at(0.5 * (a + b), hits, capsules);
                    if parts == 0 {
                        // Float rounding at a capsule boundary: the interval's union is
                        // still a correct (looser) candidate set.
                        (parts, bones) = (v.part_mask, v.bone_mask);
                    }
                    out.push(Sample {
                        t_start: a,
                        t_end: b,
                        part_mask: parts,
                        bone_mask: bones,
                    });
                });
            }
        },
    );
    Ok(samples)
}

/// Drops the samples whose midpoint maps (through `posed_to_canonical`) into an
/// unoccupied cell of `grid` or outside its box. `posed_to_canonical` receives every
/// sample midpoint in posed space with its candidate-bone mask, in one batch, and
/// returns canonical positions (same length); a non-finite position counts as empty.
pub fn cull_with_grid<F>(
    mut samples: PackedSamples,
    rays: &[Ray],
    grid: &OccupancyGrid,
    posed_to_canonical: F,
) -> Result<PackedSamples, GridError>
where
    F: Fn(&[Vec3], &[u64]) -> Vec<Vec3>,
{
    if rays.len() != samples.num_rays() {
        return Err(GridError::LengthMismatch {
            what: "rays for the samples",
            expected: samples.num_rays(),
            got: rays.len(),
        });
    }
    let p_posed = samples.midpoints_in_world(rays);
    let p_canonical = posed_to_canonical(&p_posed, &samples.bone_mask);
    if p_canonical.len() != p_posed.len() {
        return Err(GridError::LengthMismatch {
            what: "posed_to_canonical output",
            expected: p_posed.len(),
            got: p_canonical.len(),
        });
    }
    let keep: Vec<bool> = p_canonical
        .par_iter()
        .map(|&p| grid.is_occupied(p))
        .collect();
    samples.retain(&keep);
    Ok(samples)
}

/// The accelerated sampler: [`sample_in_capsules`] then [`cull_with_grid`].
pub fn sample_reference<F>(
    bvh: &CapsuleBvh,
    rays: &[Ray],
    grid: &OccupancyGrid,
    posed_to_canonical: F,
    opts: &AcceleratedOpts,
) -> Result<PackedSamples, GridError>
where
    F: Fn(&[Vec3], &[u64]) -> Vec<Vec3>,
{
    let samples = sample_in_capsules(bvh, rays, opts)?;
    cull_with_grid(samples, rays, grid, posed_to_canonical)
}
