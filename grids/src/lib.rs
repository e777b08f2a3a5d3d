//! grids: acceleration structures for ray marching a human. Owns the capsule BVH over the
//! posed skeleton (observation space), the occupancy grid over canonical space, and the
//! dense and accelerated samplers with packed output.
//!
//! Knows nothing of neural networks, burn, datasets or the body model: capsules, rays and
//! the posed-to-canonical map come in as plain data and callbacks.

pub mod bvh;
pub mod capsule;
pub mod error;
pub mod intersect;
pub mod intervals;
pub mod occupancy;
mod packing;
pub mod ray;
mod rng;

pub use bvh::CapsuleBvh;
pub use capsule::{Capsule, Part};
pub use error::GridError;
pub use intersect::{CapsuleHit, brute_force_hits, ray_capsule};
pub use intervals::{Interval, RayIntervals};
pub use occupancy::{OccUpdateOpts, OccUpdateReport, OccupancyGrid};
pub use ray::Ray;
