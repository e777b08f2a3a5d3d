//! data: what comes in from disk. Owns the dataset format (reading with errors that name
//! the file, field and expected shape, validating, writing atomically), frame parameters
//! as JSON, the arrays users hand over (`.npy`/`.npz` in [`npz`], the SMPL-X model file in
//! [`smplx_model`]), motion files, the [`census`] of a run's frames (pixels by part,
//! articulation, the pixel's footprint), `talkin inspect` and the raster helpers of its
//! contact sheets.
//!
//! Must not know about neural nets, samplers or training: it hands the later stages
//! validated frames, cameras and parameters. Nor about other tools' layouts: converting a
//! fitter's output into a dataset is `talkin-import`'s.

pub mod array;
pub mod atomic;
pub mod census;
pub mod dataset;
pub mod draw;
pub mod inspect;
pub mod json_shape;
pub mod motion;
pub mod npz;
pub mod numpy_dtype;
pub mod params_json;
pub mod smplx_model;
