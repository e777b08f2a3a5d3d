//! The accelerated sampler's hot path, one pass per ray: the exact intervals inside the
//! grown capsules, cut into bins up to one step past the first core entry, each bin kept
//! if a bone of a capsule it overlaps maps its midpoint near an occupied canonical cell.
//! The same samples as [`crate::sample_in_front_of_cores`] followed by a conservative
//! [`crate::cull_with_grid`], with nothing built per frame.
//!
//! What makes it fast: a frame's pixel rays share one origin (the camera centre) and
//! neighbouring rays look the same way. Per chunk of rays that share an origin, the
//! capsules whose bounding spheres lie outside the chunk's cone of directions are dropped
//! once, and the rest are prepared for that origin ([`CapsuleFromOrigin`]); a ray then
//! rejects most of those with one bounding-sphere distance and runs the exact f64 test
//! on the few it may meet. Chunks whose rays do not share an origin test every capsule.

use glam::Vec3;
use rayon::prelude::*;

use crate::cull::{CanonicalCull, check_cull};
use crate::intersect::{CapsuleFromOrigin, ray_capsule, validate_capsules};
use crate::packing::{CHUNK, SampleColumns, par_pack_samples};
use crate::ray::validate_rays;
use crate::rng::SplitMix;
use crate::samples::{PackedSamples, Sample, stratified_bins};
use crate::{AcceleratedOpts, Capsule, GridError, Ray};

/// A capsule that may meet some ray of a chunk, prepared for the chunk's origin.
#[derive(Clone, Copy)]
struct Candidate {
    /// Bounding sphere: centre relative to the origin, squared radius (padded against
    /// f32 rounding: it only decides which capsules reach the exact test).
    centre: Vec3,
    reach2: f32,
    exact: CapsuleFromOrigin,
    index: u32,
}

/// The capsules and cores a chunk of rays sharing one origin may meet, prepared for that
/// origin (a chunk whose rays do not share one has no view: every capsule is tested).
struct ChunkView {
    capsules: Vec<Candidate>,
    cores: Vec<Candidate>,
}

/// A capsule a ray crosses, with what the bins need of it.
#[derive(Clone, Copy)]
struct Hit {
    t_in: f32,
    t_out: f32,
    part: u8,
    bone: u64,
    /// The ray through the bone's rigid map: canonical `q(t) = q0 + t dq`.
    q0: Vec3,
    dq: Vec3,
}

/// See the module docs. Built per frame from the grown capsules, their cores and the
/// subject's canonical cull; it holds no per-frame grid, so building it costs nothing.
pub struct CapsuleSampler {
    capsules: Vec<Capsule>,
    cores: Vec<Capsule>,
    cull: Option<CanonicalCull>,
    max_step: f32,
}

impl CapsuleSampler {
    /// The canonical dilation (metres) a cull needs for steps up to `max_step`: a bin
    /// reaches at most 0.95 `max_step` from its midpoint (jittered bins are at most 1.9
    /// steps long) and rigid maps keep distances.
    pub fn cull_reach(max_step: f32) -> f32 {
        0.95 * max_step
    }

    /// A sampler over the grown `capsules` and their `cores`, for steps up to `max_step`;
    /// without `cull`, no bin is culled by occupancy. The cull's dilation must cover
    /// [`CapsuleSampler::cull_reach`] and its maps every bone of the capsules.
    pub fn new(
        capsules: &[Capsule],
        cores: &[Capsule],
        cull: Option<CanonicalCull>,
        max_step: f32,
    ) -> Result<CapsuleSampler, GridError> {
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
        Ok(CapsuleSampler {
            capsules: capsules.to_vec(),
            cores: cores.to_vec(),
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
        let views: Vec<Option<ChunkView>> =
            rays.par_chunks(CHUNK).map(|c| self.chunk_view(c)).collect();
        Ok(par_pack_samples(rays.len(), Vec::new, |hits, i, out| {
            self.sample_ray(&rays[i], i, views[i / CHUNK].as_ref(), opts, hits, out)
        }))
    }

    /// The candidates of a chunk whose rays share an origin and start at `t_min >= 0`:
    /// the capsules whose bounding sphere meets the cone around the chunk's mean
    /// direction that holds all its directions.
    fn chunk_view(&self, rays: &[Ray]) -> Option<ChunkView> {
        let origin = rays.first()?.origin;
        if rays.iter().any(|r| r.origin != origin || r.t_min < 0.0) {
            return None;
        }
        let sum: Vec3 = rays.iter().map(|r| r.direction).sum();
        let axis = sum.try_normalize()?;
        let cos_min = rays
            .iter()
            .map(|r| r.direction.normalize().dot(axis))
            .fold(1.0f32, f32::min);
        let (cos_s, sin_s) = (
            cos_min.clamp(-1.0, 1.0),
            (1.0 - cos_min * cos_min).max(0.0).sqrt(),
        );
        let prepare = |list: &[Capsule]| -> Vec<Candidate> {
            list.iter()
                .enumerate()
                .filter_map(|(k, c)| {
                    let centre = 0.5 * (c.a + c.b) - origin;
                    let dist = centre.length();
                    let radius = 0.5 * (c.b - c.a).length() + c.radius;
                    // The sphere seen from the origin is a cone of half-angle h around
                    // its centre; it meets the chunk's cone (half-angle s) if the axes
                    // are at most s + h apart: cos(apart) >= cos(s + h), with 1e-4 of
                    // slack against f32 rounding.
                    let sin_h = radius / dist;
                    let seen = !(sin_h < 1.0 - 1e-5) || {
                        let cos_h = (1.0 - sin_h * sin_h).sqrt();
                        let cos_both = cos_s * cos_h - sin_s * sin_h;
                        // s + h >= pi: the cones cover every direction between them.
                        cos_s <= -cos_h || centre.dot(axis) / dist >= cos_both - 1e-4
                    };
                    let reach = radius + 1e-5 * dist + 1e-6;
                    seen.then(|| Candidate {
                        centre,
                        reach2: reach * reach,
                        exact: CapsuleFromOrigin::new(c, origin),
                        index: k as u32,
                    })
                })
                .collect()
        };
        Some(ChunkView {
            capsules: prepare(&self.capsules),
            cores: prepare(&self.cores),
        })
    }

    /// Calls `f(capsule index, t_in, t_out)` for every capsule of `list` (or, without a
    /// view, of `all`) the ray crosses.
    #[inline]
    fn for_each_hit(
        ray: &Ray,
        view: Option<&[Candidate]>,
        all: &[Capsule],
        mut f: impl FnMut(usize, f32, f32),
    ) {
        match view {
            Some(list) => {
                // Unit within the rays' tolerance; the sphere test needs it exactly.
                let d = ray.direction.normalize();
                let dd = ray.direction.as_dvec3();
                let dd2 = dd.length_squared();
                for c in list {
                    // Closest approach of the line to the bounding sphere's centre.
                    let s = c.centre.dot(d);
                    if (c.centre - s * d).length_squared() > c.reach2 {
                        continue;
                    }
                    if let Some((t_in, t_out)) = c.exact.hit(dd, dd2, ray.t_min, ray.t_max) {
                        f(c.index as usize, t_in, t_out);
                    }
                }
            }
            None => {
                for (k, c) in all.iter().enumerate() {
                    if let Some((t_in, t_out)) = ray_capsule(ray, c) {
                        f(k, t_in, t_out);
                    }
                }
            }
        }
    }

    fn sample_ray(
        &self,
        ray: &Ray,
        index: usize,
        view: Option<&ChunkView>,
        opts: &AcceleratedOpts,
        hits: &mut Vec<Hit>,
        out: &mut SampleColumns,
    ) {
        let mut t_core = f32::INFINITY;
        Self::for_each_hit(
            ray,
            view.map(|v| &v.cores[..]),
            &self.cores,
            |_, t_in, _| t_core = t_core.min(t_in),
        );
        let stop = t_core + opts.step;
        hits.clear();
        Self::for_each_hit(
            ray,
            view.map(|v| &v.capsules[..]),
            &self.capsules,
            |k, t_in, t_out| {
                if t_in < stop {
                    let c = &self.capsules[k];
                    let (q0, dq) = match &self.cull {
                        Some(cull) => {
                            let m = &cull.canonical_from_posed[c.bone as usize];
                            (
                                m.transform_point3(ray.origin),
                                m.transform_vector3(ray.direction),
                            )
                        }
                        None => (Vec3::ZERO, Vec3::ZERO),
                    };
                    hits.push(Hit {
                        t_in,
                        t_out,
                        part: c.part.bit(),
                        bone: 1u64 << c.bone,
                        q0,
                        dq,
                    });
                }
            },
        );
        if hits.is_empty() {
            return;
        }
        hits.sort_unstable_by(|x, y| x.t_in.total_cmp(&y.t_in));
        let mut rng = SplitMix::new(opts.seed, index as u64);
        let mut first = 0;
        while first < hits.len() {
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
            stratified_bins(t_in, t_end, n, rng, |a, b| {
                if let Some(s) = self.bin(group, a, b) {
                    out.push(s);
                }
            });
        }
    }

    /// The sample `[a, b]` of a merged interval's capsules `group`, or `None` if the cull
    /// drops it: no bone of a capsule overlapping it maps its midpoint into the dilated
    /// canonical grid.
    #[inline]
    fn bin(&self, group: &[Hit], a: f32, b: f32) -> Option<Sample> {
        let mid = 0.5 * (a + b);
        let (mut parts, mut bones) = (0u8, 0u64);
        let mut occupied = self.cull.is_none();
        let mut tried = 0u64;
        for h in group {
            // Branch-free: which capsules hold the midpoint is unpredictable.
            let inside = (h.t_in <= mid) & (mid <= h.t_out);
            parts |= h.part & 0u8.wrapping_sub(inside as u8);
            bones |= h.bone & 0u64.wrapping_sub(inside as u64);
        }
        if !occupied && let Some(cull) = &self.cull {
            for h in group {
                if h.t_in <= b && a <= h.t_out && tried & h.bone == 0 {
                    tried |= h.bone;
                    if cull.grid.is_occupied(h.q0 + mid * h.dq) {
                        occupied = true;
                        break;
                    }
                }
            }
        }
        if !occupied {
            return None;
        }
        if parts == 0 {
            // Float rounding at a capsule boundary: the group's union is a correct
            // (looser) candidate set.
            for h in group {
                parts |= h.part;
                bones |= h.bone;
            }
        }
        Some(Sample {
            t_start: a,
            t_end: b,
            part_mask: parts,
            bone_mask: bones,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::{Affine3A, Quat, vec3};

    use super::*;
    use crate::intersect::signed_distance;
    use crate::rng::SplitMix;
    use crate::{CapsuleBvh, DilatedOccupancy, OccupancyGrid, Part, sample_in_front_of_cores};

    /// Three limbs of different bones (one a sphere), their cores, and per bone a rigid
    /// map.
    fn scene() -> (Vec<Capsule>, Vec<Capsule>, Vec<Affine3A>) {
        // (a, b, radius, part, bone); the head is a sphere.
        #[rustfmt::skip]
        let limbs = [
            (vec3(0.0, 0.0, 0.0), vec3(0.0, 0.5, 0.0), 0.15, Part::Body, 3),
            (vec3(0.0, 0.5, 0.0), vec3(0.3, 0.6, 0.0), 0.06, Part::Arms, 16),
            (vec3(0.3, 0.6, 0.0), vec3(0.4, 0.6, 0.02), 0.02, Part::Hands, 20),
            (vec3(0.0, 0.7, 0.0), vec3(0.0, 0.7, 0.0), 0.1, Part::Head, 15),
        ];
        let capsules: Vec<Capsule> = limbs
            .into_iter()
            .map(|(a, b, radius, part, bone)| Capsule {
                a,
                b,
                radius,
                part,
                bone,
            })
            .collect();
        let cores = capsules
            .iter()
            .map(|c| Capsule {
                radius: 0.6 * c.radius,
                ..*c
            })
            .collect();
        let maps = (0..64)
            .map(|b| {
                let angle = 0.1 * b as f32;
                Affine3A::from_rotation_translation(
                    Quat::from_axis_angle(vec3(0.3, 1.0, 0.2).normalize(), angle),
                    vec3(0.01 * b as f32, -0.02, 0.05),
                )
            })
            .collect();
        (capsules, cores, maps)
    }

    fn points(n: usize, lo: Vec3, hi: Vec3, seed: u64) -> Vec<Vec3> {
        let mut rng = SplitMix::new(seed, 0);
        (0..n)
            .map(|_| lo + (hi - lo) * vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect()
    }

    /// Pixel rays from a camera at `origin` in small square tiles of 128 (8 x 16 rays over
    /// 4 x 4 cm at the scene's plane z = 0), a tile every 10 cm over the scene: each tile
    /// is one chunk with a narrow, round cone of directions, as a frame's neighbouring
    /// foreground rays, so capsules at a cone's edge are the hard case.
    fn tiled_rays(origin: Vec3) -> Vec<Ray> {
        let mut rays = Vec::new();
        for ty in 0..12 {
            for tx in 0..9 {
                let corner = vec3(-0.3 + 0.1 * tx as f32, -0.25 + 0.1 * ty as f32, 0.0);
                for y in 0..16 {
                    for x in 0..8 {
                        let f = vec3((x as f32 + 0.5) / 8.0, (y as f32 + 0.5) / 16.0, 0.0);
                        let target = corner + 0.04 * f;
                        rays.push(Ray::new(origin, target - origin, 0.0, f32::INFINITY).unwrap());
                    }
                }
            }
        }
        assert_eq!(CHUNK, 128, "one tile a chunk");
        rays
    }

    /// Rays from one camera at `origin` towards random points of the scene, in random
    /// order (every chunk's cone spans the scene).
    fn camera_rays(origin: Vec3, n: usize, seed: u64) -> Vec<Ray> {
        points(n, vec3(-0.25, -0.2, -0.2), vec3(0.55, 0.85, 0.2), seed)
            .into_iter()
            .map(|p| Ray::new(origin, p - origin, 0.0, f32::INFINITY).unwrap())
            .collect()
    }

    fn opts(step: f32, seed: u64) -> AcceleratedOpts {
        AcceleratedOpts {
            step,
            jitter: true,
            seed,
        }
    }

    /// Samples `rays` with an unculled sampler and with the exact BVH pipeline, asserts
    /// they agree sample for sample (t within 1e-5, same parts and bones), and returns
    /// the sampler's.
    fn assert_matches_exact(rays: &[Ray], step: f32, seed: u64) -> PackedSamples {
        let (capsules, cores, _) = scene();
        let sampler = CapsuleSampler::new(&capsules, &cores, None, step).unwrap();
        let bvh = CapsuleBvh::build(&capsules).unwrap();
        let core_bvh = CapsuleBvh::build(&cores).unwrap();
        let got = sampler.sample(rays, &opts(step, seed)).unwrap();
        let want =
            sample_in_front_of_cores(&bvh, &core_bvh, rays, step, &opts(step, seed)).unwrap();
        got.check_layout().unwrap();
        assert_eq!(got.num_rays(), want.num_rays());
        for i in 0..rays.len() {
            let (g, w) = (got.range(i), want.range(i));
            assert_eq!(g.len(), w.len(), "ray {i}: {:?}", rays[i]);
            for (s, t) in g.zip(w) {
                assert!((got.t_start[s] - want.t_start[t]).abs() < 1e-5, "ray {i}");
                assert!((got.t_end[s] - want.t_end[t]).abs() < 1e-5, "ray {i}");
                assert_eq!(got.part_mask[s], want.part_mask[t], "ray {i}");
                assert_eq!(got.bone_mask[s], want.bone_mask[t], "ray {i}");
            }
        }
        got
    }

    /// Without a cull it is the exact BVH pipeline, sample for sample: shared-origin
    /// chunks (prepared capsules, cone culling: narrow cones of pixel tiles and wide ones
    /// of random rays) and mixed-origin chunks alike.
    #[test]
    fn matches_the_exact_pipeline() {
        let mut rays = tiled_rays(vec3(0.1, 0.4, -2.5));
        rays.extend(camera_rays(vec3(0.1, 0.4, -2.5), 700, 1));
        // A camera inside the scene's box looking every way (cones wider than 90
        // degrees), one inside the body capsule, and a chunk of mixed origins.
        let mut rng = SplitMix::new(2, 0);
        for origin in [vec3(0.1, 0.3, 0.3), vec3(0.05, 0.2, 0.0)] {
            for _ in 0..256 {
                let d = vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
                rays.push(Ray::new(origin, d, 0.0, f32::INFINITY).unwrap());
            }
        }
        for (k, r) in camera_rays(vec3(-1.0, 0.5, -2.0), 300, 3)
            .into_iter()
            .enumerate()
        {
            rays.push(Ray {
                origin: r.origin + 0.01 * (k % 3) as f32 * Vec3::X,
                ..r
            });
        }
        let got = assert_matches_exact(&rays, 0.006, 4);
        assert!(got.num_samples() > 5_000, "{}", got.num_samples());
    }

    /// The cull keeps every bin holding a point that lies in a grown capsule, in front
    /// of the first core entry, and that some bone of a capsule holding it maps into an
    /// occupied canonical cell (the exact map's candidates); and it does cull.
    #[test]
    fn cull_never_drops_a_point_the_exact_map_keeps() {
        let (capsules, cores, maps) = scene();
        let mut canonical =
            OccupancyGrid::new(vec3(-0.6, -0.4, -0.6), vec3(0.8, 1.0, 0.6), [100; 3]).unwrap();
        canonical.mark(&points(
            20_000,
            vec3(-0.6, -0.4, -0.6),
            vec3(0.8, 1.0, 0.6),
            5,
        ));
        let step = 0.006;
        let cull = CanonicalCull {
            grid: Arc::new(
                DilatedOccupancy::new(&canonical, CapsuleSampler::cull_reach(step)).unwrap(),
            ),
            canonical_from_posed: maps.clone(),
        };
        let sampler = CapsuleSampler::new(&capsules, &cores, Some(cull), step).unwrap();
        let unculled = CapsuleSampler::new(&capsules, &cores, None, step).unwrap();
        let rays = camera_rays(vec3(0.1, 0.4, -2.5), 2000, 6);
        let samples = sampler.sample(&rays, &opts(step, 7)).unwrap();
        let all = unculled.sample(&rays, &opts(step, 7)).unwrap();
        assert!(samples.num_samples() < all.num_samples() * 9 / 10);
        assert!(samples.num_samples() > all.num_samples() / 10);
        let mut checked = 0;
        for (i, ray) in rays.iter().enumerate() {
            let t_core = cores
                .iter()
                .filter_map(|c| ray_capsule(ray, c))
                .map(|(t, _)| t)
                .fold(f32::INFINITY, f32::min);
            for k in 0..3000 {
                let t = 1.5 + k as f32 / 3000.0 * 2.0;
                let p = ray.at(t);
                let kept = t < t_core
                    && capsules.iter().any(|c| {
                        signed_distance(p, c) < -1e-5
                            && canonical.is_occupied(maps[c.bone as usize].transform_point3(p))
                    });
                if kept {
                    checked += 1;
                    assert!(
                        samples
                            .range(i)
                            .any(|s| samples.t_start[s] <= t && t <= samples.t_end[s]),
                        "ray {i}: t {t} is kept by the exact map but in no sample"
                    );
                }
            }
        }
        assert!(checked > 1_000, "{checked}");
    }

    /// Hard rays: parallel to a limb's axis, grazing a capsule, starting inside a
    /// capsule or a core, starting behind the camera (`t_min < 0`), and directions a
    /// little off unit length (within the rays' tolerance).
    #[test]
    fn hard_rays_match_the_exact_pipeline() {
        let ray = |o: Vec3, d: Vec3, t_min: f32| Ray::new(o, d, t_min, f32::INFINITY).unwrap();
        let mut rays = vec![
            // Along the body's axis, from below, through both caps.
            ray(vec3(0.0, -1.0, 0.0), Vec3::Y, 0.0),
            // Along it, 0.149 off the axis (inside the 0.15 radius, outside the core).
            ray(vec3(0.149, -1.0, 0.0), Vec3::Y, 0.0),
            // Tangent to the head sphere, and a hair inside it.
            ray(vec3(0.1, 0.7, -2.0), Vec3::Z, 0.0),
            ray(vec3(0.0999, 0.7, -2.0), Vec3::Z, 0.0),
            // From inside the body shell and inside its core.
            ray(vec3(0.12, 0.25, 0.0), vec3(0.3, 0.2, 1.0), 0.0),
            ray(vec3(0.0, 0.25, 0.0), vec3(0.3, 0.2, 1.0), 0.0),
            // Starting 2 m behind the origin: the scene lies partly behind it.
            ray(vec3(0.0, 0.3, 0.5), -Vec3::Z, -2.0),
        ];
        let mut off_unit = ray(vec3(0.0, 0.3, -2.0), vec3(0.05, 0.1, 1.0), 0.0);
        off_unit.direction *= 1.0008;
        rays.push(off_unit);
        let got = assert_matches_exact(&rays, 0.005, 1);
        assert!(got.range(0).len() > 10 && got.range(6).len() > 10);
    }

    #[test]
    fn bad_input_is_an_error() {
        let (capsules, cores, maps) = scene();
        let sampler = CapsuleSampler::new(&capsules, &cores, None, 0.005).unwrap();
        let good = camera_rays(vec3(0.0, 0.4, -2.0), 3, 1);
        let nan = Ray {
            origin: Vec3::NAN,
            ..good[0]
        };
        assert!(sampler.sample(&[good[0], nan], &opts(0.005, 0)).is_err());
        assert!(sampler.sample(&good, &opts(0.01, 0)).is_err());
        assert!(sampler.sample(&good, &opts(f32::NAN, 0)).is_err());
        assert!(CapsuleSampler::new(&capsules, &cores, None, 0.0).is_err());
        let bad = Capsule {
            radius: f32::NAN,
            ..capsules[0]
        };
        assert!(CapsuleSampler::new(&[bad], &cores, None, 0.005).is_err());
        // A cull that does not dilate far enough for the step.
        let grid = OccupancyGrid::new(vec3(-1.0, -1.0, -1.0), vec3(1.0, 1.0, 1.0), [8; 3]).unwrap();
        let cull = || CanonicalCull {
            grid: Arc::new(DilatedOccupancy::new(&grid, 0.0).unwrap()),
            canonical_from_posed: maps.clone(),
        };
        assert!(CapsuleSampler::new(&capsules, &cores, Some(cull()), 0.005).is_err());
        // Empty input is fine.
        let empty = sampler.sample(&[], &opts(0.005, 0)).unwrap();
        assert_eq!(empty.num_rays(), 0);
    }
}
