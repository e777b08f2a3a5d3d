//! engine: the human and the pipeline. Owns the body model, cameras, the dataset format and
//! its loader, the synthetic talking-human generator, and (wiring `grids` and `nets`) the
//! training, rendering and evaluation pipeline.
//!
//! Library code returns typed errors that name the file, field and expected shape; the
//! binary turns them into messages and exit codes.

pub mod ablations;
pub mod atomic;
pub mod avatar;
pub mod bench_error;
pub mod bench_shared;
pub mod body;
pub mod camera;
pub mod checkpoint;
pub mod dataset;
pub mod draw;
pub mod eval;
pub mod inspect;
pub mod json_shape;
pub mod motion;
pub mod novel_identity;
pub mod sampling;
pub mod sequence;
pub mod serve;
pub mod smooth;
pub mod speed_vs_error;
pub mod subject_model;
pub mod synth;
pub mod text;
pub mod train;
