//! The one error type of the crate: bad input is reported, never panicked on.

use glam::Vec3;

/// Everything that can be wrong with the data handed to this crate. Each variant names the
/// item (ray, capsule, grid) and what was expected of it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    #[error("ray {index}: {field} is not finite")]
    NonFiniteRay { index: usize, field: &'static str },
    #[error("ray {index}: direction must be unit length (|d| = {length})")]
    DirectionNotUnit { index: usize, length: f32 },
    #[error("ray {index}: t_min {t_min} must be <= t_max {t_max}")]
    EmptyRayRange {
        index: usize,
        t_min: f32,
        t_max: f32,
    },
    #[error("capsule {index}: {field} is not finite")]
    NonFiniteCapsule { index: usize, field: &'static str },
    #[error("capsule {index}: radius {radius} is negative")]
    NegativeRadius { index: usize, radius: f32 },
    #[error("capsule {index}: bone {bone} does not fit the 64-bit bone mask")]
    BoneOutOfRange { index: usize, bone: u16 },
    #[error("capsule count changed from {expected} to {got}: refit needs the same capsules")]
    CapsuleCountChanged { expected: usize, got: usize },
    #[error("{what}: expected {expected} values, got {got}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what} {index} is not finite")]
    NonFiniteValue { what: &'static str, index: usize },
    #[error("box {min} .. {max} is not a finite box with min < max on every axis")]
    BadBox { min: Vec3, max: Vec3 },
    #[error("occupancy grid resolution {0:?}: every axis must be in 1..=1024")]
    BadResolution([u32; 3]),
    #[error("occupancy grids differ in box or resolution, cannot union them")]
    GridMismatch,
    #[error("ray {index}: label {label} is not a body part (1..=4)")]
    BadLabel { index: usize, label: u8 },
    #[error("unknown sampler {0:?}: expected \"dense\" or \"accelerated\"")]
    UnknownSampler(String),
    #[error("packed samples are malformed: {0}")]
    BadPacking(String),
    #[error("option {field} = {value}: {expected}")]
    BadOption {
        field: &'static str,
        value: f32,
        expected: &'static str,
    },
}
