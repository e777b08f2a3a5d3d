//! NeRF-style ReLU MLP with input skip connections.

use burn::module::Initializer;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Width and depth of one MLP (the input and output widths come from where it is used).
#[derive(Config, Debug)]
pub struct MlpConfig {
    /// Number of hidden layers (each `width` wide, ReLU); an output layer follows.
    pub depth: usize,
    /// Hidden width.
    pub width: usize,
    /// Hidden layers whose input gets the network input concatenated (NeRF: `[4]`).
    #[config(default = "Vec::new()")]
    pub skips: Vec<usize>,
}

impl MlpConfig {
    /// Builds the network. `output_init`: `Some(b)` starts the output layer uniform in
    /// `[-b, b]` (deformation nets start near the identity map), `None` uses burn's default.
    pub fn init(
        &self,
        d_input: usize,
        d_output: usize,
        output_init: Option<f64>,
        device: &Device,
    ) -> Mlp {
        let mut hidden = Vec::with_capacity(self.depth);
        let mut d = d_input;
        for i in 0..self.depth {
            let d_in = if self.skips.contains(&i) && i > 0 {
                d + d_input
            } else {
                d
            };
            hidden.push(LinearConfig::new(d_in, self.width).init(device));
            d = self.width;
        }
        let mut out = LinearConfig::new(d, d_output);
        if let Some(b) = output_init {
            out = out.with_initializer(Initializer::Uniform { min: -b, max: b });
        }
        Mlp {
            hidden,
            output: out.init(device),
            skips: self
                .skips
                .iter()
                .copied()
                .filter(|&s| s > 0 && s < self.depth)
                .collect(),
        }
    }
}

/// `depth` x (Linear + ReLU), then a linear output layer.
#[derive(Module, Debug)]
pub struct Mlp {
    pub(crate) hidden: Vec<Linear>,
    pub(crate) output: Linear,
    skips: Vec<usize>,
}

impl Mlp {
    /// # Shapes
    /// - `x`: `[n, d_input]`
    /// - output: `[n, d_output]`
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let mut h = x.clone();
        for (i, layer) in self.hidden.iter().enumerate() {
            if self.skips.contains(&i) {
                h = Tensor::cat(vec![h, x.clone()], 1);
            }
            h = relu(layer.forward(h));
        }
        self.output.forward(h)
    }
}
