//! NeRF-style ReLU MLP with input skip connections.

use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::device::is_cpu;
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
            fused_on_device: MlpPath::default().fused_on_device,
            slice_rows: MlpPath::default().slice_rows,
        }
    }
}

/// Which products an MLP runs off the CPU (the CPU always takes the fused kernel where
/// it applies): a choice of the field's configuration, saved with every checkpoint, so
/// that comparing the paths is comparing two configurations, never a process's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MlpPath {
    /// MLPs without skips take the fused device op (`kernels::cube::mlp`); false: the
    /// composed burn ops (the baseline it is measured against).
    pub fused_on_device: bool,
    /// Rows a slice of the composed ops' batched products (`Mlp::sliced`); 0: no
    /// slicing.
    pub slice_rows: usize,
}

impl Default for MlpPath {
    fn default() -> Self {
        MlpPath {
            fused_on_device: true,
            slice_rows: 256,
        }
    }
}

/// `depth` x (Linear + ReLU), then a linear output layer.
#[derive(Module, Debug)]
pub struct Mlp {
    pub(crate) hidden: Vec<Linear>,
    pub(crate) output: Linear,
    skips: Vec<usize>,
    /// [`MlpPath::fused_on_device`] (not saved: the configuration says it).
    fused_on_device: bool,
    /// [`MlpPath::slice_rows`].
    slice_rows: usize,
}

impl Mlp {
    /// This MLP taking `path` off the CPU.
    pub fn with_path(mut self, path: MlpPath) -> Mlp {
        self.fused_on_device = path.fused_on_device;
        self.slice_rows = path.slice_rows;
        self
    }

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

    /// [`Mlp::forward_with_row`] as burn tensor ops (every backend, skips). Off the CPU,
    /// a batch of at least two slices goes through [`Mlp::sliced`].
    fn composed(&self, x: Tensor<2>, row: Option<Tensor<2>>) -> Tensor<2> {
        let rows = self.slice_rows;
        if rows > 0 && x.dims()[0] >= 2 * rows && !is_cpu(&x.device()) {
            return self.sliced(x, row, rows);
        }
        self.layers(x, row)
    }

    /// The layers on `[..., d]` inputs: each leading index a row.
    fn layers<const D: usize>(&self, x: Tensor<D>, row: Option<Tensor<2>>) -> Tensor<D> {
        let mut h = x.clone();
        for (i, layer) in self.hidden.iter().enumerate() {
            let first = i == 0;
            if self.skips.contains(&i) && !first {
                h = Tensor::cat(vec![h, x.clone()], D - 1);
            }
            let row = if first || self.skips.contains(&i) {
                row.clone()
            } else {
                None
            };
            h = relu(linear_with_row(layer, h, row));
        }
        linear_with_row(&self.output, h, None)
    }

    /// The layers on the batch cut into `[slices, rows, d]` (zero rows padding the last
    /// slice, cut off the output), so that each weight's gradient `x^T dy`, whose
    /// reduction runs over the whole batch, is a batched product of one slice each and
    /// a sum over slices: spread over the GPU rather than a few workgroups walking
    /// every sample. The padding rows' outputs are dropped, so their gradient is zero
    /// and they add nothing to any weight's.
    fn sliced(&self, x: Tensor<2>, row: Option<Tensor<2>>, rows: usize) -> Tensor<2> {
        let [n, d_x] = x.dims();
        let slices = n.div_ceil(rows);
        let pad = slices * rows - n;
        let x = if pad > 0 {
            let zeros = Tensor::zeros([pad, d_x], &x.device());
            Tensor::cat(vec![x, zeros], 0)
        } else {
            x
        };
        let out = self.layers(x.reshape([slices, rows, d_x]), row); // [slices, rows, d_out]
        let d_out = out.dims()[2];
        out.reshape([slices * rows, d_out]).narrow(0, 0, n)
    }
}

impl Mlp {
    /// The fused op where it applies: no skips, every layer with a bias, a non-empty
    /// batch; on the CPU backend `kernels::mlp`, on a CubeCL device `kernels::cube::mlp`
    /// (where its sizes fit and [`MlpPath::fused_on_device`]). On the CPU the shared row's product
    /// and the first bias become one `[1, width]` bias, composed here so their gradients
    /// flow as usual; the device op folds the row itself.
    fn fused(&self, x: &Tensor<2>, row: Option<&Tensor<2>>) -> Option<Tensor<2>> {
        let [n, d_x] = x.dims();
        if !self.skips.is_empty() || n == 0 || (!is_cpu(&x.device()) && !self.fused_on_device) {
            return None;
        }
        let mut params = Vec::with_capacity(2 * (self.hidden.len() + 1));
        for layer in self.hidden.iter().chain([&self.output]) {
            params.push(layer.weight.val());
            params.push(layer.bias.as_ref()?.val().unsqueeze_dim::<2>(0)); // [1, d_out]
        }
        #[cfg(feature = "wgpu")]
        if !is_cpu(&x.device()) {
            return crate::kernels::cube::mlp::forward(x, row, &params);
        }
        if let Some(row) = row {
            let w = params[0].clone();
            let [d_in, _] = w.dims();
            params[1] =
                row.clone().matmul(w.clone().narrow(0, d_x, d_in - d_x)) + params[1].clone();
            params[0] = w.narrow(0, 0, d_x);
        }
        crate::kernels::mlp::forward(x, &params)
    }
}

/// `layer.forward(cat([x, row repeated], -1))` with the row's product computed once,
/// on `[..., d_x]` inputs. The weight goes in as a `[1, .., d_in, d_out]` matrix product
/// rather than burn's `linear`, whose weight gradient flattens the leading dimensions
/// back into one `[d_in, rows] x [rows, d_out]` product (what [`Mlp::sliced`] avoids);
/// for a 2-D input the two are the same product.
fn linear_with_row<const D: usize>(
    layer: &Linear,
    x: Tensor<D>,
    row: Option<Tensor<2>>,
) -> Tensor<D> {
    let dims = x.dims();
    let d_x = dims[D - 1];
    let rows: usize = dims[..D - 1].iter().product();
    let w = layer.weight.val(); // [d_in, d_out]
    let [d_in, d_out] = w.dims();
    let bias = || layer.bias.as_ref().map(|b| b.val().unsqueeze_dim::<2>(0)); // [1, d_out]
    match row {
        // An empty batch: the plain path keeps its shape `[.., 0, d_out]`.
        Some(row) if rows == 0 => {
            let out = layer.forward(Tensor::cat(
                vec![x.reshape([0, d_x]), row.repeat_dim(0, 0)],
                1,
            ));
            let mut out_dims = dims;
            out_dims[D - 1] = d_out;
            out.reshape(out_dims)
        }
        Some(row) => {
            let mut c = row.matmul(w.clone().narrow(0, d_x, d_in - d_x)); // [1, d_out]
            if let Some(b) = bias() {
                c = c + b;
            }
            x.matmul(w.narrow(0, 0, d_x).unsqueeze::<D>()) + c.unsqueeze::<D>()
        }
        None if D == 2 => layer.forward(x),
        None => {
            let out = x.matmul(w.unsqueeze::<D>());
            match bias() {
                Some(b) => out + b.unsqueeze::<D>(),
                None => out,
            }
        }
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

    /// The sliced layers ([`Mlp::sliced`]) against the plain ones on `device`: values and
    /// the gradients of the input, the shared row and every layer's weight and bias,
    /// for a batch with a ragged last slice (zero padding), one that fills its slices,
    /// with a shared row and a skip layer and without.
    fn sliced_against_plain(device: &Device, tol: f32) {
        use crate::util::{assert_close_to, host};
        for (n, skips, with_row) in [
            (37, vec![], true),
            (32, vec![2], false),
            (45, vec![2], true),
        ] {
            let d_row = if with_row { 3 } else { 0 };
            let mlp = MlpConfig::new(3, 16).with_skips(skips.clone()).init(
                5 + d_row,
                4,
                None,
                device,
                &mut WeightRng::seeded(3),
            );
            let x = tensor(n, 5, 2, device).require_grad();
            let row = with_row.then(|| tensor(1, d_row, 7, device).require_grad());
            let plain = mlp.layers(x.clone(), row.clone());
            let sliced = mlp.sliced(x.clone(), row.clone(), 8);
            let what = format!("n {n}, skips {skips:?}, row {with_row}");
            assert_close_to(&what, &host(&sliced), &host(&plain), tol);
            let grads = |out: Tensor<2>| {
                let g = out.powi_scalar(2).sum().backward();
                let mut all = vec![host(&x.grad(&g).unwrap())];
                if let Some(row) = &row {
                    all.push(host(&row.grad(&g).unwrap()));
                }
                for layer in mlp.hidden.iter().chain([&mlp.output]) {
                    all.push(host(&layer.weight.val().grad(&g).unwrap()));
                    all.push(host(&layer.bias.as_ref().unwrap().val().grad(&g).unwrap()));
                }
                all
            };
            for (i, (u, v)) in grads(plain).iter().zip(grads(sliced)).enumerate() {
                assert_close_to(&format!("{what}, gradient {i}"), &v, u, tol);
            }
        }
    }

    #[test]
    fn the_sliced_layers_match_the_plain_ones() {
        sliced_against_plain(&Device::flex().autodiff(), 1e-5);
    }

    /// [`sliced_against_plain`] on the wgpu device, where [`Mlp::forward`] takes the
    /// sliced path.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_sliced_mlp_matches_the_plain_one() {
        sliced_against_plain(&crate::device::test_wgpu().autodiff(), 1e-5);
    }

    /// The fused device op (`kernels::cube::mlp`) against the composed ops on the wgpu
    /// device: depths 2 and 3, widths 16 and 64, the body net's 24 inputs, one row, a
    /// ragged tile, several chunks of rows with a ragged last one and a batch large enough
    /// for the composed side to slice; shared rows of 3, 16 and 69 (the face's expression,
    /// jaw and identity) and none; and without autodiff, as renders run it.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_fused_mlp_matches_the_composed_ops() {
        let device = crate::device::test_wgpu();
        let cases = [
            (2, 16, 5, 3, 1, 4),
            (2, 16, 5, 3, 1100, 4),
            (3, 64, 24, 0, 3001, 7),
            (2, 64, 24, 69, 2000, 4),
            (2, 64, 24, 16, 20_000, 4),
        ];
        // 1e-4: a bias's gradient sums 20,000 rows in f32, in another order on each side.
        fused_against_composed(&device.clone().autodiff(), &cases, 1e-4);
        let mlp = MlpConfig::new(2, 64).init(24, 4, None, &device, &mut WeightRng::seeded(1));
        let x = tensor(777, 24, 3, &device);
        let fused = mlp
            .fused(&x, None)
            .expect("the fused op applies without autodiff");
        crate::util::assert_close_to(
            "inference",
            &crate::util::host(&fused),
            &crate::util::host(&mlp.composed(x, None)),
            2e-5,
        );
    }

    /// The fused op against the composed ops on `device`: values and the gradients of the
    /// input, the shared row and every layer's weight and bias, for each case's (depth,
    /// width, input width, shared row width (0: none), rows, output width), to `tol` of
    /// the largest magnitude.
    fn fused_against_composed(
        device: &Device,
        cases: &[(usize, usize, usize, usize, usize, usize)],
        tol: f32,
    ) {
        let close = |u: &[f32], v: &[f32], what: &str| {
            assert_eq!(u.len(), v.len(), "{what}");
            let scale = u.iter().fold(1e-6f32, |m, e| m.max(e.abs()));
            for (p, q) in u.iter().zip(v) {
                assert!((p - q).abs() <= tol * scale, "{what}: {p} vs {q}");
            }
        };
        let host = |t: Tensor<2>| crate::util::host(&t);
        for &(depth, width, d_x, d_row, n, d_out) in cases {
            let mlp = MlpConfig::new(depth, width).init(
                d_x + d_row,
                d_out,
                None,
                device,
                &mut WeightRng::seeded(1),
            );
            let x = tensor(n, d_x, 3, device).require_grad();
            let row = (d_row > 0).then(|| tensor(1, d_row, 5, device).require_grad());
            let fused = mlp.fused(&x, row.as_ref()).expect("the fused op applies");
            let composed = mlp.composed(x.clone(), row.clone());
            let what = format!("depth {depth}, width {width}, row {d_row}, n {n}");
            close(&host(composed.clone()), &host(fused.clone()), &what);
            // A loss whose gradient differs per row and column.
            let weights = tensor(n, d_out, 11, device);
            let grads = |out: Tensor<2>| {
                let g = (out * weights.clone()).sum().backward();
                let mut all = vec![host(x.grad(&g).unwrap())];
                if let Some(row) = &row {
                    all.push(host(row.grad(&g).unwrap()));
                }
                for layer in mlp.hidden.iter().chain([&mlp.output]) {
                    all.push(host(layer.weight.val().grad(&g).unwrap()));
                    let b = layer.bias.as_ref().unwrap().val().grad(&g).unwrap();
                    all.push(crate::util::host(&b));
                }
                all
            };
            for (i, (u, v)) in grads(composed).iter().zip(&grads(fused)).enumerate() {
                close(u, v, &format!("{what}, gradient {i}"));
            }
        }
    }

    /// The fused op gives the composed ops' values and gradients (every parameter and the
    /// input), over several chunks with a ragged last one, with and without a shared row,
    /// at depths 1 to 3, and in inference without autodiff.
    #[test]
    fn the_fused_op_matches_the_composed_ops() {
        let cases = [
            (2, 16, 5, 3, 1100, 4),
            (2, 16, 5, 0, 1100, 4),
            (1, 16, 5, 3, 1100, 4),
            (3, 16, 5, 0, 1100, 4),
        ];
        fused_against_composed(&Device::flex().autodiff(), &cases, 2e-5);
        let close = |u: &[f32], v: &[f32], what: &str| {
            let scale = u.iter().fold(1e-6f32, |m, e| m.max(e.abs()));
            for (p, q) in u.iter().zip(v) {
                assert!((p - q).abs() <= 2e-5 * scale, "{what}: {p} vs {q}");
            }
        };
        let host = |t: Tensor<2>| t.try_to_vec_as::<f32>().unwrap();
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
