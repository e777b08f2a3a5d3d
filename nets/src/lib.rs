//! talkin-nets: the burn side of talkin. Owns the encodings (sinusoidal with a Hann
//! window, multiresolution hash grid), the TalkinNeRF field (inverse LBS with a learned
//! weight volume, D_nr, F_body with segmentation, F_face, D_hands + F_hands with hard
//! routing, optional per-frame codes), volume rendering of packed samples, and the losses
//! (the distortion of a ray's weights among them), and the stage timer ([`profile`]) a
//! bench reads to see where a step's time goes.
//!
//! It must not know about the acceleration structures (`grids`) or the pipeline
//! (`engine`): samples, candidate masks and per-frame transforms come in as plain slices.
//! The backend is chosen at run time through burn's `Device`: [`ComputeDevice`] parses
//! `--device cpu|wgpu[:N]` and opens Flex (CPU) or wgpu; `.autodiff()` for training.
//! Device tensors come back to the host through [`read_floats`], which counts the reads
//! on a GPU (each waits for the queued work).
//!
//! ```
//! use burn::prelude::*;
//! use talkin_nets::volume::{OwnedRaySamples, render_packed};
//!
//! let device = Device::flex();
//! // Two rays: one with two samples, one empty (packed: flat arrays + offsets).
//! let rays = OwnedRaySamples {
//!     offsets: vec![0, 2, 2],
//!     t_start: vec![0.0, 0.5],
//!     t_end: vec![0.5, 1.0],
//! };
//! let sigma = Tensor::<1>::from_floats([2.0, 1e6], &device); // [n]
//! let rgb = Tensor::<2>::from_floats([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], &device); // [n, 3]
//! let seg = Tensor::<2>::zeros([2, 5], &device); // [n, 5]
//! let out = render_packed(sigma, rgb, seg, &rays.view()).unwrap();
//! let opacity = out.opacity.try_to_vec_as::<f32>().unwrap();
//! assert!((opacity[0] - 1.0).abs() < 1e-6 && opacity[1] == 0.0);
//! ```
pub mod device;
pub mod encoding;
pub mod error;
pub mod field;
pub mod init;
pub mod kernels;
pub mod loss;
pub mod mlp;
pub mod profile;
mod rows;
pub mod skinning;
mod util;
pub mod volume;

pub use burn::prelude::Device;
pub use device::{
    ComputeDevice, DeviceError, device_readbacks, is_cpu, max_tensor_bytes, read_floats,
};
pub use error::NetsError;
pub use field::{
    Density, FieldConfig, FieldInput, FieldOutput, FrameCodes, FrameConditions, PoseGrads,
    PoseLeaves, TalkinField, UnitMap,
};
pub use volume::{RaySamples, RenderedRays, render_packed};
