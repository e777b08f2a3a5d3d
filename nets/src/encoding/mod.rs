//! Input encodings: sinusoidal positional encoding (with HumanNeRF's Hann window) and the
//! multiresolution hash grid, behind one [`Encoding`] that presets choose by config.
//! Each runs as one fused op on the Flex CPU backend (`crate::kernels`, with its own
//! backward) and as composed tensor ops elsewhere (wgpu); tests hold the two equal.

pub mod frequency;
mod hash_corners;
pub mod hash_grid;
pub(crate) mod hash_primes;

use burn::prelude::*;

use crate::init::WeightRng;

pub use frequency::{FrequencyConfig, FrequencyEncoding, HannWindowConfig};
pub use hash_grid::{HashGrid, HashGridConfig};

/// Which point encoding a radiance net uses.
#[derive(Config, Debug)]
pub enum EncodingConfig {
    /// NeRF positional encoding (the `paper` preset: 10 bands).
    Frequency(FrequencyConfig),
    /// Multiresolution hash grid (the `fast` preset).
    HashGrid(HashGridConfig),
}

impl EncodingConfig {
    /// Builds the encoding; a hash grid draws its table from `rng`.
    pub fn init(&self, device: &Device, rng: &mut WeightRng) -> Encoding {
        match self {
            EncodingConfig::Frequency(c) => Encoding::Frequency(c.init()),
            EncodingConfig::HashGrid(c) => Encoding::HashGrid(c.init(device, rng)),
        }
    }
}

/// A point encoding of canonical positions.
#[derive(Module, Debug)]
pub enum Encoding {
    /// Sinusoidal.
    Frequency(FrequencyEncoding),
    /// Hash grid.
    HashGrid(HashGrid),
}

impl Encoding {
    /// Output width for 3-D points.
    pub fn output_dim(&self) -> usize {
        match self {
            Encoding::Frequency(e) => e.output_dim(3),
            Encoding::HashGrid(e) => e.output_dim(),
        }
    }

    /// Encodes points of identity `identity` given in the unit cube of the canonical
    /// bounding box (the sinusoids ignore the identity; the hash grid gives each its own
    /// features).
    ///
    /// # Shapes
    /// - `unit_points`: `[n, 3]` in [0, 1]^3
    /// - output: `[n, output_dim]`
    pub fn forward(&self, unit_points: Tensor<2>, identity: usize, step: usize) -> Tensor<2> {
        match self {
            // Sinusoids want coordinates in about [-1, 1].
            Encoding::Frequency(e) => e.forward(unit_points.mul_scalar(2.0).sub_scalar(1.0), step),
            Encoding::HashGrid(e) => e.forward(unit_points, identity),
        }
    }
}
