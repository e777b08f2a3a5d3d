//! The fused CPU kernels, one home: each does what a composed burn reference does, in one
//! parallel pass on the Flex backend (with its own backward where it is differentiated),
//! and is tested against that reference. Where a tensor is not a plain f32 Flex tensor
//! (the wgpu device), the callers take the device kernels (`cube`, the `wgpu` feature) or
//! the composed ops.
//!
//! - `hash`: the multiresolution hash encoding, all levels at once.
//! - `frequency`: the windowed sinusoidal encoding.
//! - `mlp`: an MLP's forward and backward.
//! - [`adam`]: Adam in one pass per parameter.
//! - [`grad_sum`]: two chunks' gradients summed in place.

pub mod adam;
#[cfg(feature = "wgpu")]
pub(crate) mod cube;
pub(crate) mod flex_data;
pub(crate) mod frequency;
pub mod grad_sum;
pub(crate) mod hash;
pub(crate) mod mlp;
