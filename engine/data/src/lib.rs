//! data: what comes in from disk. Owns the dataset format (reading with errors that name
//! the file, field and expected shape, validating, writing atomically), frame parameters
//! as JSON, the readers of what other tools write (`.npy`/`.npz` in [`npz`], numpy pickles
//! in [`pickle`], the SMPL-X model file in [`smplx_model`]), their conversion into datasets
//! (`talkin import`, [`import`]), motion files, `talkin inspect` and the raster helpers of
//! its contact sheets.
//!
//! Must not know about neural nets, samplers or training: it hands the later stages
//! validated frames, cameras and parameters.

pub mod array;
pub mod atomic;
pub mod dataset;
pub mod draw;
pub mod import;
pub mod inspect;
pub mod json_shape;
pub mod motion;
pub mod npz;
mod numpy_dtype;
pub mod params_json;
pub mod pickle;
pub mod smplx_model;
