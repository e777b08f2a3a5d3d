//! avatar: what a trained avatar is: an [`Avatar`] (the field's modules from `talkin-nets`
//! with its subjects, loaded from a run's checkpoint), each trained [`subject`] (rest skeleton, capsule shells, canonical occupancy grid, fitted
//! from a dataset), a posed frame's [`scene`] and samplers, the field's per-frame
//! [`field_inputs`], a run's [`refined`] training fits, and the [`checkpoint`] format that
//! stores them with the weights. Training builds and writes avatars; rendering,
//! evaluation and the server load them.
//!
//! Must not know about training steps, losses, optimisers or a run's recipe (a
//! checkpoint keeps the run's state as JSON it does not interpret), nor about rendering
//! whole frames, the server or the command line.

pub mod checkpoint;
pub mod field_inputs;
pub mod refined;
pub mod scene;
pub mod subject;
mod trained;

pub use trained::{Avatar, AvatarError};
