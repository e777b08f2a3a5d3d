//! Initial weights, drawn from an RNG the caller owns ([`WeightRng`]), so two fields built
//! at once (trainers and renders side by side in tests, benches and the server) never
//! share a generator and one seed always gives one field.
//!
//! The draws are burn-flex's: its generator (rand's `StdRng` seeded with
//! `seed_from_u64`), `TensorData::random`'s element order, and burn-nn's `Linear`
//! initialisers (Kaiming-uniform with gain 1/sqrt(3), or a given uniform range). A field
//! built with a seed therefore has the weights that seeding burn's process-wide RNG gave.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::{Distribution, TensorData};
use rand::SeedableRng;
use rand::rngs::StdRng;

/// The generator a field's initial weights are drawn from; see the module docs.
pub struct WeightRng {
    rng: StdRng,
}

impl WeightRng {
    /// A generator whose draws follow from `seed` alone.
    pub fn seeded(seed: u64) -> Self {
        Self {
            rng: StdRng::seed_from_u64(seed),
        }
    }

    /// A `shape` tensor of f32 draws from `distribution`, in row-major order, on `device`.
    pub fn tensor<const D: usize>(
        &mut self,
        shape: [usize; D],
        distribution: Distribution,
        device: &Device,
    ) -> Tensor<D> {
        let data = TensorData::random::<f32, _, _>(shape, distribution, &mut self.rng);
        Tensor::from_data(data, device)
    }

    /// A `d_input -> d_output` linear layer (weight `[d_input, d_output]`, then bias
    /// `[d_output]`), both uniform in `[-b, b]`: `b` is `output_bound` where given, burn's
    /// default Kaiming-uniform bound 1/sqrt(d_input) otherwise.
    pub fn linear(
        &mut self,
        d_input: usize,
        d_output: usize,
        output_bound: Option<f64>,
        device: &Device,
    ) -> Linear {
        // burn-nn's `Initializer::KaimingUniform { gain: 1/sqrt(3), fan_out_only: false }`,
        // computed as it computes it.
        let gain = 1.0 / 3.0f64.sqrt();
        let kaiming = 3.0f64.sqrt() * gain * (1.0 / (d_input as f64).sqrt());
        let (low, high) = match output_bound {
            Some(b) => (-b, b),
            None => (-kaiming, kaiming),
        };
        let uniform = Distribution::Uniform(low, high);
        let weight = self.tensor([d_input, d_output], uniform, device);
        let bias = self.tensor([d_output], uniform, device);
        Linear {
            weight: Param::from_tensor(weight),
            bias: Some(Param::from_tensor(bias)),
        }
    }
}
