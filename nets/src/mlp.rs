//! NeRF-style ReLU MLP with input skip connections.

use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::init::WeightRng;

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
    /// Builds the network, drawing its weights from `rng` layer by layer (weight, then
    /// bias). `output_init`: `Some(b)` starts the output layer uniform in `[-b, b]`
    /// (deformation nets start near the identity map), `None` uses burn's default.
    pub fn init(
        &self,
        d_input: usize,
        d_output: usize,
        output_init: Option<f64>,
        device: &Device,
        rng: &mut WeightRng,
    ) -> Mlp {
        let mut hidden = Vec::with_capacity(self.depth);
        let mut d = d_input;
        for i in 0..self.depth {
            let d_in = if self.skips.contains(&i) && i > 0 {
                d + d_input
            } else {
                d
            };
            hidden.push(rng.linear(d_in, self.width, None, device));
            d = self.width;
        }
        let output = rng.linear(d, d_output, output_init, device);
        Mlp {
            hidden,
            output,
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
        self.forward_with_row(x, None)
    }

    /// [`Mlp::forward`] of `cat([x, row repeated n times], 1)`, without building the
    /// repeated rows: a condition that is the same for every row (a frame's identity
    /// code, expression, pose) goes through its slice of the weights once, as a bias.
    /// Same values and gradients; `[n, d_x + d_row]` is never allocated, and the
    /// matrix products see `d_x` input columns instead of `d_x + d_row`.
    ///
    /// # Shapes
    /// - `x`: `[n, d_x]`, `row`: `[1, d_row]` with `d_x + d_row = d_input`
    pub fn forward_with_row(&self, x: Tensor<2>, row: Option<Tensor<2>>) -> Tensor<2> {
        match self.fused(&x, row.as_ref()) {
            Some(out) => out,
            None => self.composed(x, row),
        }
    }

    /// [`Mlp::forward_with_row`] as burn tensor ops (every backend, skips).
    fn composed(&self, x: Tensor<2>, row: Option<Tensor<2>>) -> Tensor<2> {
        let mut h = x.clone();
        for (i, layer) in self.hidden.iter().enumerate() {
            let first = i == 0;
            if self.skips.contains(&i) && !first {
                h = Tensor::cat(vec![h, x.clone()], 1);
            }
            let row = if first || self.skips.contains(&i) {
                row.clone()
            } else {
                None
            };
            h = relu(linear_with_row(layer, h, row));
        }
        self.output.forward(h)
    }
}

impl Mlp {
    /// The fused op (`kernels::mlp`) where it applies: no skips, every layer with a
    /// bias, a non-empty batch on the CPU backend. The shared row's product and the first
    /// bias become one `[1, width]` bias, composed here so their gradients flow as usual.
    fn fused(&self, x: &Tensor<2>, row: Option<&Tensor<2>>) -> Option<Tensor<2>> {
        let [n, d_x] = x.dims();
        if !self.skips.is_empty() || n == 0 {
            return None;
        }
        let mut params = Vec::with_capacity(2 * (self.hidden.len() + 1));
        for (i, layer) in self.hidden.iter().chain([&self.output]).enumerate() {
            let w = layer.weight.val();
            let mut b = layer.bias.as_ref()?.val().unsqueeze_dim::<2>(0); // [1, d_out]
            let w = match (i, row) {
                (0, Some(row)) => {
                    let [d_in, _] = w.dims();
                    b = row.clone().matmul(w.clone().narrow(0, d_x, d_in - d_x)) + b;
                    w.narrow(0, 0, d_x)
                }
                _ => w,
            };
            params.push(w);
            params.push(b);
        }
        crate::kernels::mlp::forward(x, &params)
    }
}

/// `layer.forward(cat([x, row repeated], 1))` with the row's product computed once.
fn linear_with_row(layer: &Linear, x: Tensor<2>, row: Option<Tensor<2>>) -> Tensor<2> {
    let [n, d_x] = x.dims();
    match row {
        // An empty batch: the plain path keeps its shape `[0, d_out]`.
        Some(row) if n == 0 => layer.forward(Tensor::cat(vec![x, row.repeat_dim(0, 0)], 1)),
        Some(row) => {
            let w = layer.weight.val();
            let [d_in, _] = w.dims();
            let mut c = row.matmul(w.clone().narrow(0, d_x, d_in - d_x)); // [1, d_out]
            if let Some(b) = &layer.bias {
                c = c + b.val().unsqueeze_dim(0);
            }
            x.matmul(w.narrow(0, 0, d_x)) + c
        }
        None => layer.forward(x),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(rows: usize, cols: usize, seed: usize, device: &Device) -> Tensor<2> {
        let v: Vec<f32> = (0..rows * cols)
            .map(|i| (((i + seed) * 7919 % 199) as f32 / 99.0) - 1.0)
            .collect();
        Tensor::from_data(TensorData::new(v, [rows, cols]), device)
    }

    /// The shared row as a bias gives the values and gradients of the repeated,
    /// concatenated input, with a skip layer (which sees the row again) and without.
    #[test]
    fn a_shared_row_matches_the_repeated_input() {
        let device = Device::flex().autodiff();
        for skips in [vec![], vec![2]] {
            let mlp = MlpConfig::new(3, 16).with_skips(skips.clone()).init(
                7,
                4,
                None,
                &device,
                &mut WeightRng::seeded(1),
            );
            let (x, row) = (tensor(9, 4, 1, &device), tensor(1, 3, 5, &device));
            let x = x.require_grad();
            let row = row.require_grad();
            let plain = mlp.forward(Tensor::cat(
                vec![x.clone(), row.clone().repeat_dim(0, 9)],
                1,
            ));
            let shared = mlp.forward_with_row(x.clone(), Some(row.clone()));
            let (a, b) = (
                plain.clone().try_to_vec_as::<f32>().unwrap(),
                shared.clone().try_to_vec_as::<f32>().unwrap(),
            );
            for (p, q) in a.iter().zip(&b) {
                assert!((p - q).abs() < 1e-5, "{p} vs {q} (skips {skips:?})");
            }
            let grads = |out: Tensor<2>| {
                let g = out.powi_scalar(2).sum().backward();
                let w = |t: Tensor<2>| t.try_to_vec_as::<f32>().unwrap();
                (
                    w(x.grad(&g).unwrap()),
                    w(row.grad(&g).unwrap()),
                    w(mlp.hidden[0].weight.val().grad(&g).unwrap()),
                )
            };
            let (ga, gb) = (grads(plain), grads(shared));
            for (u, v) in [(ga.0, gb.0), (ga.1, gb.1), (ga.2, gb.2)] {
                assert_eq!(u.len(), v.len());
                let scale = u.iter().fold(1e-6f32, |m, e| m.max(e.abs()));
                for (p, q) in u.iter().zip(&v) {
                    assert!(
                        (p - q).abs() <= 1e-4 * scale,
                        "{p} vs {q} (skips {skips:?})"
                    );
                }
            }
        }
    }

    /// The fused op gives the composed ops' values and gradients (every parameter and the
    /// input), over several chunks with a ragged last one, with and without a shared row,
    /// at depths 1 to 3, and in inference without autodiff.
    #[test]
    fn the_fused_op_matches_the_composed_ops() {
        let close = |u: &[f32], v: &[f32], what: &str| {
            assert_eq!(u.len(), v.len(), "{what}");
            let scale = u.iter().fold(1e-6f32, |m, e| m.max(e.abs()));
            for (p, q) in u.iter().zip(v) {
                assert!((p - q).abs() <= 2e-5 * scale, "{what}: {p} vs {q}");
            }
        };
        let host = |t: Tensor<2>| t.try_to_vec_as::<f32>().unwrap();
        let device = Device::flex().autodiff();
        for (depth, with_row) in [(2, true), (2, false), (1, true), (3, false)] {
            let d_row = if with_row { 3 } else { 0 };
            let mlp = MlpConfig::new(depth, 16).init(
                5 + d_row,
                4,
                None,
                &device,
                &mut WeightRng::seeded(1),
            );
            let n = 1100;
            let x = tensor(n, 5, 3, &device).require_grad();
            let row = with_row.then(|| tensor(1, 3, 5, &device).require_grad());
            let fused = mlp.fused(&x, row.as_ref()).expect("the fused op applies");
            let composed = mlp.composed(x.clone(), row.clone());
            let what = format!("depth {depth}, row {with_row}");
            close(&host(composed.clone()), &host(fused.clone()), &what);
            // A loss whose gradient differs per row and column.
            let weights = tensor(n, 4, 11, &device);
            let grads = |out: Tensor<2>| {
                let g = (out * weights.clone()).sum().backward();
                let mut all = vec![host(x.grad(&g).unwrap())];
                if let Some(row) = &row {
                    all.push(host(row.grad(&g).unwrap()));
                }
                for layer in mlp.hidden.iter().chain([&mlp.output]) {
                    all.push(host(layer.weight.val().grad(&g).unwrap()));
                    let b = layer.bias.as_ref().unwrap().val().grad(&g).unwrap();
                    all.push(b.try_to_vec_as::<f32>().unwrap());
                }
                all
            };
            for (i, (u, v)) in grads(composed).iter().zip(&grads(fused)).enumerate() {
                close(u, v, &format!("{what}, gradient {i}"));
            }
        }
        let device = Device::flex();
        let mlp = MlpConfig::new(2, 16).init(5, 4, None, &device, &mut WeightRng::seeded(1));
        let x = tensor(700, 5, 3, &device);
        let fused = mlp
            .fused(&x, None)
            .expect("the fused op applies without autodiff");
        close(&host(mlp.composed(x, None)), &host(fused), "inference");
    }

    /// The fused op's gradients do not depend on which thread ran which chunk.
    #[test]
    fn the_fused_gradients_are_reproducible() {
        let device = Device::flex().autodiff();
        let mlp = MlpConfig::new(2, 32).init(6, 3, None, &device, &mut WeightRng::seeded(1));
        let run = || {
            let x = tensor(5000, 6, 1, &device).require_grad();
            let g = mlp.forward(x.clone()).powi_scalar(2).sum().backward();
            let w = mlp.hidden[0].weight.val().grad(&g).unwrap();
            (
                x.grad(&g).unwrap().try_to_vec_as::<f32>().unwrap(),
                w.try_to_vec_as::<f32>().unwrap(),
            )
        };
        let first = run();
        for _ in 0..4 {
            assert!(run() == first);
        }
    }

    /// An empty batch keeps its shape.
    #[test]
    fn a_shared_row_with_no_rows_gives_no_rows() {
        let device = Device::flex();
        let mlp = MlpConfig::new(2, 8).init(5, 4, None, &device, &mut WeightRng::seeded(1));
        let out = mlp.forward_with_row(
            Tensor::zeros([0, 3], &device),
            Some(tensor(1, 2, 0, &device)),
        );
        assert_eq!(out.dims(), [0, 4]);
    }
}
