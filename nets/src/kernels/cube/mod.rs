//! The device kernels (CubeCL, the `wgpu` feature): each a burn backend extension with its
//! own backward, used where tensors live on a CubeCL device, and tested against the
//! composed burn ops the other devices run.
//!
//! - `frequency`: the frequency encoding of the deformation nets.
//! - `hash`: the multiresolution hash encoding, all levels in one launch.
//! - `heads`: a net output's columns through their activations.
//! - `pixel_loss`: the pixel loss's per-ray terms (colour, labels, silhouette).
//! - `render`: volume rendering's weights, one unit per ray.
//! - `ray_sums`: volume rendering's per-ray sums (colour, labels, opacity, depth).
//! - `routed`: a part net's routed rows put back into the batch.
//! - `skin`: inverse skinning over each sample's candidate bones (their points, logits, blend).
//! - `adam`: Adam, one elementwise kernel per parameter.
//! - `mlp`: a ReLU MLP without skips, a unit per row, its weights' gradients by chunks.

use cubecl::{CubeCount, CubeDim, calculate_cube_count_elemwise, client::Client};

pub(crate) mod adam;
mod adam_kernels;
pub(crate) mod frequency;
mod frequency_kernels;
pub(crate) mod hash;
mod hash_kernels;
pub(crate) mod heads;
mod heads_kernels;
pub(crate) mod mlp;
mod mlp_kernels;
pub(crate) mod pixel_loss;
mod pixel_loss_kernels;
pub(crate) mod ray_sums;
mod ray_sums_kernels;
pub(crate) mod render;
mod render_kernels;
pub(crate) mod routed;
mod routed_kernels;
pub(crate) mod skin;
mod skin_kernels;

/// The launch grid for `units` work items, one unit each.
fn launch_shape(client: &Client, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new(client, units);
    (calculate_cube_count_elemwise(client, units, dim), dim)
}
