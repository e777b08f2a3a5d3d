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

#[cfg(test)]
mod tests {
    use burn::module::Initializer;
    use burn::nn::LinearConfig;

    use super::*;
    use crate::util::host;

    /// The draws are burn-flex's: what seeding burn's generator and drawing with burn's
    /// tensor and layer initialisers give, value for value and in order.
    #[test]
    fn draws_what_burns_seeded_generator_draws() {
        let device = Device::flex();
        let bound = 1e-5;
        device.seed(7);
        // burn-nn's layers draw lazily, on first use: weight, then bias.
        let default = LinearConfig::new(5, 3).init(&device);
        let mut theirs = vec![host(&default.weight.val())];
        theirs.push(host(&default.bias.unwrap().val()));
        let uniform = LinearConfig::new(4, 2)
            .with_initializer(Initializer::Uniform {
                min: -bound,
                max: bound,
            })
            .init(&device);
        theirs.push(host(&uniform.weight.val()));
        theirs.push(host(&uniform.bias.unwrap().val()));
        let normal = Distribution::Normal(0.0, 0.1);
        theirs.push(host(&Tensor::<2>::random([4, 2], normal, &device)));

        let mut rng = WeightRng::seeded(7);
        let default = rng.linear(5, 3, None, &device);
        let mut ours = vec![host(&default.weight.val())];
        ours.push(host(&default.bias.unwrap().val()));
        let uniform = rng.linear(4, 2, Some(bound), &device);
        ours.push(host(&uniform.weight.val()));
        ours.push(host(&uniform.bias.unwrap().val()));
        ours.push(host(&rng.tensor([4, 2], normal, &device)));
        assert_eq!(ours, theirs);
        // And the draws are not all alike (a generator that returned one value would pass
        // the comparison above only if burn's did too).
        assert!(ours[0].windows(2).all(|w| w[0] != w[1]), "{:?}", ours[0]);
    }
}
