//! train: one training step and the loop around it. Owns the wiring of `grids` to a
//! frame (capsule shells, cameras' rays, the canonical map: [`scene`]), each subject's
//! model ([`subject`]), the field's per-frame inputs ([`field_inputs`]), the step itself
//! (rays -> samples -> field -> loss -> optimizer -> grid update: [`trainer`]) and the
//! checkpoints a run writes ([`checkpoint`]).
//!
//! Must not know about rendering whole frames, evaluation, the server or the
//! experiments: those read its checkpoints.

pub mod checkpoint;
pub mod field_inputs;
pub mod scene;
pub mod subject;
pub mod trainer;

mod batch;
mod fused_adam;
mod grid_update;
mod half_batch;
mod options;
mod rng;
pub mod schedule;

pub use trainer::*;
