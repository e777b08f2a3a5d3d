//! The accelerated sampler's hot path, one pass per ray: the exact intervals inside the
//! grown capsules, cut into bins up to one step past the first core entry, each bin kept
//! if a bone of a capsule it overlaps maps its midpoint near an occupied canonical cell.
//! The same samples as [`crate::sample_in_front_of_cores`] followed by a conservative
//! [`crate::cull_with_grid`], with nothing built per frame.
//!
//! Where the grid holds the field's densities (after an occupancy update), a ray also
//! stops where its light is spent: the kept bins' optical depth, read from the grid
//! through the bone that gives the least, is added up along the ray, and once it passes
//! [`SPENT_OPTICAL_DEPTH`] the ray takes bins only as far again as the cull's reach.
//!
//! What makes it fast: a frame's pixel rays share one origin (the camera centre) and
//! neighbouring rays look the same way, so per chunk of rays a `ChunkView` keeps the
//! few capsules they may meet, prepared for that origin (chunks whose rays do not share
//! an origin test every capsule). Along a ray, the bins of a merged interval are visited
//! in order, so which capsules hold a bin's midpoint is kept up to date as the sweep
//! passes capsule ends (`Sweep`) instead of asked of every capsule per bin.

use glam::Vec3;
use rayon::prelude::*;

use crate::chunk_view::{ChunkView, CoreNesting};
use crate::cull::{CanonicalCull, check_cull};
use crate::intersect::{DirectionF64, ray_capsule, validate_capsules};
use crate::packing::{CHUNK, SampleColumns, par_pack_samples};
use crate::ray::validate_rays;
use crate::rng::SplitMix64;
use crate::samples::{Sample, stratified_bins};
use crate::{AcceleratedOpts, Capsule, GridError, PackedSamples, Ray};

/// Optical depth after which a ray's light is spent: a transmittance of 1e-4. What lies
/// behind adds at most that share of the colour.
pub const SPENT_OPTICAL_DEPTH: f32 = 9.21;

/// A capsule a ray crosses, with what the bins need of it.
#[derive(Clone, Copy)]
struct Hit {
    t_in: f32,
    t_out: f32,
    /// Index of the part's bit ([`crate::Part::bit`]) and the bone.
    part: u8,
    bone: u8,
    /// Its slot in the chunk's view.
    slot: u32,
    /// The ray through the bone's rigid map, in the dilated grid's cell units:
    /// `q(t) = q0 + t dq` ([`crate::DilatedOccupancy::cell_ray`]).
    q0: Vec3,
    dq: Vec3,
}

/// A worker's buffers, reused from ray to ray.
#[derive(Default)]
struct Scratch {
    hits: Vec<Hit>,
    /// A merged interval's hits by exit: `(t_out, index in the interval)`.
    exits: Vec<(f32, u32)>,
}

/// See the module docs. Built per frame from the grown capsules, their cores and the
/// subject's canonical cull; it holds no per-frame grid, so building it costs nothing.
pub struct AcceleratedSampler {
    capsules: Vec<Capsule>,
    cores: Vec<Capsule>,
    nesting: CoreNesting,
    cull: Option<CanonicalCull>,
    max_step: f32,
}

impl AcceleratedSampler {
    /// The canonical dilation (metres) a cull needs for steps up to `max_step`: a bin
    /// reaches at most 0.95 `max_step` from its midpoint (jittered bins are at most 1.9
    /// steps long) and rigid maps keep distances.
    pub fn cull_reach(max_step: f32) -> f32 {
        0.95 * max_step
    }

    /// A sampler over the grown `capsules` and their `cores`, for steps up to `max_step`;
    /// without `cull`, no bin is culled by occupancy. The cull's dilation must cover
    /// [`AcceleratedSampler::cull_reach`] and its maps every bone of the capsules.
    pub fn new(
        capsules: &[Capsule],
        cores: &[Capsule],
        cull: Option<CanonicalCull>,
        max_step: f32,
    ) -> Result<AcceleratedSampler, GridError> {
        validate_capsules(capsules)?;
        validate_capsules(cores)?;
        if !(max_step.is_finite() && max_step > 0.0) {
            return Err(GridError::BadOption {
                field: "max_step",
                value: max_step,
                expected: "finite and > 0",
            });
        }
        if let Some(cull) = &cull {
            check_cull(cull, capsules, Self::cull_reach(max_step))?;
        }
        Ok(AcceleratedSampler {
            capsules: capsules.to_vec(),
            cores: cores.to_vec(),
            nesting: CoreNesting::new(capsules, cores),
            cull,
            max_step,
        })
    }

    /// Samples every ray: its merged grown-capsule intervals up to `opts.step` past its
    /// first core entry, cut into bins of at most `opts.step` (stratified jitter as
    /// [`crate::sample_in_capsules`]), each with the parts and bones of the capsules
    /// holding its midpoint. `opts.step` must not exceed the sampler's `max_step`.
    pub fn sample(&self, rays: &[Ray], opts: &AcceleratedOpts) -> Result<PackedSamples, GridError> {
        validate_rays(rays)?;
        if !(opts.step.is_finite() && opts.step > 0.0 && opts.step <= self.max_step) {
            return Err(GridError::BadOption {
                field: "step",
                value: opts.step,
                expected: "finite, > 0 and <= the sampler's max_step",
            });
        }
        let views: Vec<Option<ChunkView>> = rays
            .par_chunks(CHUNK)
            .map(|c| ChunkView::new(c, &self.capsules, &self.cores, &self.nesting))
            .collect();
        Ok(par_pack_samples(
            rays.len(),
            Scratch::default,
            |scratch, i, out| {
                self.sample_ray(&rays[i], i, views[i / CHUNK].as_ref(), opts, scratch, out)
            },
        ))
    }

    /// Collects in `hits`, by entry, every capsule `ray` crosses that it enters before
    /// `stop`: `step` past its first core entry (through the chunk's `view`, or testing
    /// every capsule). Returns `stop`.
    fn crossings(
        &self,
        ray: &Ray,
        view: Option<&ChunkView>,
        step: f32,
        hits: &mut Vec<Hit>,
    ) -> f32 {
        hits.clear();
        let mut push = |slot: u32, k: u32, t_in: f32, t_out: f32| {
            let c = &self.capsules[k as usize];
            hits.push(Hit {
                t_in,
                t_out,
                part: c.part.bit().trailing_zeros() as u8,
                bone: c.bone as u8,
                slot,
                q0: Vec3::ZERO,
                dq: Vec3::ZERO,
            });
        };
        let dir = DirectionF64::new(ray.direction);
        // Unit within the rays' tolerance; the view's bounding-sphere rejects need it
        // exactly.
        let unit = ray.direction.normalize();
        match view {
            Some(view) => view.crossings(ray, &dir, unit, push),
            None => {
                for (k, c) in self.capsules.iter().enumerate() {
                    if let Some((t_in, t_out)) = ray_capsule(ray, c) {
                        push(0, k as u32, t_in, t_out);
                    }
                }
            }
        }
        // By entry: the cores are searched in this order, the bins sweep in it.
        hits.sort_unstable_by(|x, y| x.t_in.total_cmp(&y.t_in));
        let t_core = match view {
            Some(view) => view.core_entry(ray, &dir, unit, hits.iter().map(|h| (h.slot, h.t_in))),
            None => self
                .cores
                .iter()
                .filter_map(|c| ray_capsule(ray, c))
                .fold(f32::INFINITY, |t, (t_in, _)| t.min(t_in)),
        };
        let stop = t_core + step;
        let kept = hits.partition_point(|h| h.t_in < stop);
        hits.truncate(kept);
        if let Some(cull) = &self.cull {
            for h in hits.iter_mut() {
                let m = &cull.canonical_from_posed[h.bone as usize];
                (h.q0, h.dq) = cull.grid.cell_ray(
                    m.transform_point3(ray.origin),
                    m.transform_vector3(ray.direction),
                );
            }
        }
        stop
    }

    fn sample_ray(
        &self,
        ray: &Ray,
        index: usize,
        view: Option<&ChunkView>,
        opts: &AcceleratedOpts,
        scratch: &mut Scratch,
        out: &mut SampleColumns,
    ) {
        let Scratch { hits, exits } = scratch;
        let stop = self.crossings(ray, view, opts.step, hits);
        if hits.is_empty() {
            return;
        }
        let mut rng = SplitMix64::for_stream(opts.seed, index as u64);
        // The grid's densities, where it holds any: the ray stops once they spend it.
        let densities = self
            .cull
            .as_ref()
            .filter(|c| c.stop_where_spent && c.grid.has_density());
        let (mut depth, mut spent_at) = (0.0f32, f32::INFINITY);
        let mut first = 0;
        while first < hits.len() && hits[first].t_in <= spent_at {
            // One merged interval: hits[first..last] overlap or touch.
            let mut t_out = hits[first].t_out;
            let mut last = first + 1;
            while last < hits.len() && hits[last].t_in <= t_out {
                t_out = t_out.max(hits[last].t_out);
                last += 1;
            }
            let group = &hits[first..last];
            let t_in = group[0].t_in;
            first = last;
            let t_end = t_out.min(stop);
            let length = t_end - t_in;
            if !(length > 0.0) {
                continue;
            }
            let n = (length / opts.step * (1.0 - 1e-5)).ceil().max(1.0) as u32;
            let rng = opts.jitter.then_some(&mut rng);
            let mut sweep = Sweep::new(group, exits);
            stratified_bins(t_in, t_end, n, rng, |a, b| {
                if a > spent_at {
                    return;
                }
                if let Some(s) = sweep.bin(self.cull.as_ref(), a, b) {
                    out.push(s);
                    if let Some(cull) = densities
                        && spent_at.is_infinite()
                    {
                        depth += sweep.least_density(cull, a, b) * (b - a);
                        if depth >= SPENT_OPTICAL_DEPTH {
                            spent_at = b + cull.grid.reach();
                        }
                    }
                }
            });
        }
    }
}

/// The bins of one merged interval, visited in order: which of its capsules hold the
/// current midpoint, kept up to date as the midpoint passes their entries and exits.
/// A capsule holds `mid` iff `t_in <= mid <= t_out` (what [`crate::sample_in_capsules`]
/// asks of every capsule per bin).
struct Sweep<'a> {
    /// The interval's hits by entry.
    group: &'a [Hit],
    /// `(t_out, index in group)` by exit.
    exits: &'a [(f32, u32)],
    entered: usize,
    exited: usize,
    /// How many held capsules have each part and each bone, and those as masks.
    part_count: [u32; 8],
    bone_count: [u32; 64],
    parts: u8,
    bones: u64,
    /// The hit whose bone found the last kept bin occupied: tried first for the next.
    last_occupied: usize,
}

impl<'a> Sweep<'a> {
    fn new(group: &'a [Hit], exits: &'a mut Vec<(f32, u32)>) -> Sweep<'a> {
        exits.clear();
        exits.extend(group.iter().enumerate().map(|(k, h)| (h.t_out, k as u32)));
        exits.sort_unstable_by(|x, y| x.0.total_cmp(&y.0));
        Sweep {
            group,
            exits,
            entered: 0,
            exited: 0,
            part_count: [0; 8],
            bone_count: [0; 64],
            parts: 0,
            bones: 0,
            last_occupied: 0,
        }
    }

    /// Moves the midpoint to `mid` (never backwards).
    #[inline]
    fn advance(&mut self, mid: f32) {
        while let Some(h) = self.group.get(self.entered)
            && h.t_in <= mid
        {
            self.part_count[h.part as usize] += 1;
            self.bone_count[h.bone as usize] += 1;
            self.parts |= 1 << h.part;
            self.bones |= 1 << h.bone;
            self.entered += 1;
        }
        while let Some(&(t_out, k)) = self.exits.get(self.exited)
            && t_out < mid
        {
            let h = &self.group[k as usize];
            self.part_count[h.part as usize] -= 1;
            self.bone_count[h.bone as usize] -= 1;
            if self.part_count[h.part as usize] == 0 {
                self.parts &= !(1 << h.part);
            }
            if self.bone_count[h.bone as usize] == 0 {
                self.bones &= !(1 << h.bone);
            }
            self.exited += 1;
        }
    }

    /// The sample `[a, b]`, or `None` if the cull drops it: no bone of a capsule
    /// overlapping it maps its midpoint into the dilated canonical grid.
    #[inline]
    fn bin(&mut self, cull: Option<&CanonicalCull>, a: f32, b: f32) -> Option<Sample> {
        let mid = 0.5 * (a + b);
        self.advance(mid);
        if let Some(cull) = cull
            && !self.occupied(cull, a, b, mid)
        {
            return None;
        }
        let (mut parts, mut bones) = (self.parts, self.bones);
        if parts == 0 {
            // Float rounding at a capsule boundary: the interval's union is a correct
            // (looser) candidate set.
            for h in self.group {
                parts |= 1 << h.part;
                bones |= 1 << h.bone;
            }
        }
        Some(Sample {
            t_start: a,
            t_end: b,
            part_mask: parts,
            bone_mask: bones,
        })
    }

    /// The least density (per metre) the grid gives the midpoint of `[a, b]` through the
    /// bones of the capsules overlapping it: the sample is dense only if every bone that
    /// may skin it says so.
    #[inline]
    fn least_density(&self, cull: &CanonicalCull, a: f32, b: f32) -> f32 {
        let mid = 0.5 * (a + b);
        let mut least = f32::INFINITY;
        for h in self.group {
            if h.t_in <= b && a <= h.t_out {
                least = least.min(cull.grid.density_cell(h.q0 + mid * h.dq));
                if least == 0.0 {
                    break;
                }
            }
        }
        if least.is_finite() { least } else { 0.0 }
    }

    /// Whether some bone of a capsule overlapping `[a, b]` maps `mid` into an occupied
    /// cell: the bone that found the last bin occupied first, then every other.
    #[inline]
    fn occupied(&mut self, cull: &CanonicalCull, a: f32, b: f32, mid: f32) -> bool {
        let overlaps = |h: &Hit| h.t_in <= b && a <= h.t_out;
        let h = &self.group[self.last_occupied];
        let mut tried = 0u64;
        if overlaps(h) {
            if cull.grid.is_occupied_cell(h.q0 + mid * h.dq) {
                return true;
            }
            tried = 1 << h.bone;
        }
        for (k, h) in self.group.iter().enumerate() {
            if overlaps(h) && tried & (1 << h.bone) == 0 {
                tried |= 1 << h.bone;
                if cull.grid.is_occupied_cell(h.q0 + mid * h.dq) {
                    self.last_occupied = k;
                    return true;
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests;
