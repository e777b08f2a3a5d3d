//! grids: acceleration structures for ray marching a human. Owns the capsule BVH over the
//! posed skeleton (observation space), the occupancy grid over canonical space, and the
//! dense and accelerated samplers with packed output.
//!
//! Knows nothing of neural networks, burn, datasets or the body model: capsules, rays and
//! the posed-to-canonical map come in as plain data and callbacks.

pub mod capsule;

pub use capsule::{Capsule, Part};
