//! grids: acceleration structures for ray marching a human. Owns the posed skeleton's
//! capsules (observation space) and the BVH over them (obvhs: margin fitting and the
//! exact reference), the occupancy grid over canonical space, and the dense and
//! accelerated samplers with packed output.
//!
//! Knows nothing of neural networks, burn, datasets or the body model: capsules, rays and
//! the posed-to-canonical map come in as plain data and callbacks.
//!
//! # Conventions
//! - Spaces: capsules, rays and `p_posed` are in posed (world) space, metres;
//!   `p_canonical` is the canonical (rest) space of the [`OccupancyGrid`]. Only the
//!   engine's `posed_to_canonical` callback crosses between them.
//! - [`Ray`]: `origin + t * direction`, unit `direction`, `t` in metres within
//!   `[t_min, t_max]` (`t_max` may be infinite). Bad rays and capsules (NaN, inf,
//!   non-unit, negative radius, bone >= 64) are a [`GridError`], never a panic.
//! - Masks: parts as 4 bits ([`Part::bit`]), bones as a `u64` with bit `bone` set
//!   (SMPL-X joints 0..55).
//! - Packed output: flat per-item arrays plus `ray_offsets` (`rays + 1` entries), as in
//!   nerfacc; no padding ([`PackedSamples`], [`RayIntervals`]).
//! - Randomness is a pure function of a `u64` seed and the ray or cell index: results do
//!   not depend on thread count. [`SplitMix64`] is the workspace's one generator; the
//!   crates above draw from it too.
//!
//! # One frame
//! 1. Once per subject: [`fit_part_margins`] on the training masks' foreground rays gives
//!    [`PartMargins`] (how far clothes and hair stick out, per part).
//! 2. Per frame: the posed capsules, grown by the margins (`margins.inflate`).
//! 3. Per batch of rays: [`sample_dense`] (the baseline) or the accelerated sampler,
//!    picked by [`SamplerKind`]: [`AcceleratedSampler`] (exact capsule intervals up to the
//!    first core, culled per bin by the canonical [`OccupancyGrid`] through
//!    [`CanonicalCull`]; nothing built per frame). [`sample_reference`] and
//!    [`sample_in_front_of_cores`] over the [`CapsuleBvh`] are the plain reference it is
//!    tested against.
//! 4. During training: [`OccupancyGrid::update_every_n_steps`] with the field's density.
//!
//! ```
//! use glam::{Vec3, vec3};
//! use talkin_grids::*;
//!
//! let torso = Capsule { a: vec3(0.0, 0.9, 0.0), b: vec3(0.0, 1.4, 0.0), radius: 0.15,
//!                       part: Part::Body, bone: 3 };
//! // A foreground pixel whose ray passes 2 cm outside the bare torso (a loose shirt).
//! let pixel = LabelledRay {
//!     ray: Ray::new(vec3(0.17, 1.1, -3.0), Vec3::Z, 0.0, f32::INFINITY)?,
//!     label: Part::Body.label(),
//! };
//! let report = fit_part_margins(&[torso], &[pixel], &MarginFitOpts::default())?;
//! assert!((report.margins.get(Part::Body) - 0.02).abs() < 1e-4);
//! assert_eq!(report.parts[0].covered_after, 1);
//!
//! let bvh = CapsuleBvh::build(&report.margins.inflate(&[torso]))?;
//! let (bbox_min, bbox_max) = (vec3(-0.5, 0.0, -0.5), vec3(0.5, 2.0, 0.5));
//! let opts = AcceleratedOpts::matching_dense(bbox_min, bbox_max, 128);
//! let mut grid = OccupancyGrid::new(bbox_min, bbox_max, [64; 3])?;
//! grid.mark_capsules(&[torso], 0.05)?; // rest pose == posed pose in this example
//! let rays = [pixel.ray];
//! let identity = |p_posed: &[Vec3], _bones: &[u64]| p_posed.to_vec();
//! let samples = sample_reference(&bvh, &rays, &grid, identity, &opts)?;
//! let dense = sample_dense(&rays, bbox_min, bbox_max, &DenseOpts::default())?;
//! assert!(samples.num_samples() > 0 && samples.num_samples() < dense.num_samples());
//! # Ok::<(), GridError>(())
//! ```

// `!(a <= b)` is how this crate makes NaN fail a geometric test; clippy would have us
// write the NaN-unsafe `a > b`.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod bvh;
pub mod capsule;
mod chunk_view;
pub mod cull;
pub mod error;
pub mod intersect;
pub mod intervals;
pub mod margins;
pub mod occupancy;
mod packing;
pub mod ray;
mod rng;
pub mod sampler;
pub mod sampler_accelerated;
pub mod sampler_dense;
pub mod sampler_reference;
pub mod samples;
pub mod truncate;

pub use bvh::CapsuleBvh;
pub use capsule::{Capsule, Part, capsule_bounds};
pub use cull::{CanonicalCull, DilatedOccupancy};
pub use error::GridError;
pub use intersect::{CapsuleHit, brute_force_hits, ray_capsule};
pub use intervals::{Interval, RayIntervals};
pub use margins::{
    LabelledRay, MarginFitOpts, MarginReport, PartFit, PartMargins, RayCoverage, count_covered,
    fit_part_margins,
};
pub use occupancy::{OccUpdateOpts, OccUpdateReport, OccupancyGrid};
pub use ray::Ray;
pub use rng::SplitMix64;
pub use sampler::SamplerKind;
pub use sampler_accelerated::{AcceleratedSampler, SPENT_OPTICAL_DEPTH};
pub use sampler_dense::{DenseOpts, sample_dense};
pub use sampler_reference::{
    AcceleratedOpts, cull_with_grid, sample_in_capsules, sample_in_capsules_before,
    sample_reference,
};
pub use samples::{ALL_BONES, ALL_PARTS, PackedSamples, SURFACE_SLACK_M};
pub use truncate::{first_core_entry, sample_in_front_of_cores, truncate_behind_cores};
