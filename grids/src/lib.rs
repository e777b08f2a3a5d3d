//! grids: acceleration structures for ray marching a human. Owns the capsule BVH over the
//! posed skeleton (observation space), the occupancy grid over canonical space, and the
//! dense and accelerated samplers with packed output.
//!
//! Knows nothing of neural networks, burn, datasets or the body model: capsules, rays and
//! the posed-to-canonical map come in as plain data and callbacks.

// `!(a <= b)` is how this crate makes NaN fail a geometric test; clippy would have us
// write the NaN-unsafe `a > b`.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod bvh;
pub mod capsule;
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
pub mod samples;

pub use bvh::CapsuleBvh;
pub use capsule::{Capsule, Part};
pub use error::GridError;
pub use intersect::{CapsuleHit, brute_force_hits, ray_capsule};
pub use intervals::{Interval, RayIntervals};
pub use margins::{
    LabelledRay, MarginFitOpts, MarginReport, PartFit, PartMargins, fit_part_margins,
};
pub use occupancy::{OccUpdateOpts, OccUpdateReport, OccupancyGrid};
pub use ray::Ray;
pub use sampler::SamplerKind;
pub use sampler_accelerated::{
    AcceleratedOpts, cull_with_grid, sample_accelerated, sample_in_capsules,
};
pub use sampler_dense::{DenseOpts, sample_dense};
pub use samples::{ALL_BONES, ALL_PARTS, PackedSamples};
