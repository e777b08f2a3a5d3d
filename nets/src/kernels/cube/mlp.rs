//! A ReLU MLP without skips as one device op with its own backward (the fast preset's
//! 2x64 nets), its first layer fed the batch and a row shared by every sample (a frame's
//! identity code, expression, pose). Composed of burn ops, a call is a matrix product, a
//! bias and a ReLU a layer, plus the shared row's product, and in backward a mask and two
//! products a layer, whose weight products reduce over the whole batch. Here forward is
//! one launch (each cube folds the row into the first bias once) and backward four: the
//! deltas, every layer's weight gradients as partial sums over chunks of rows, their sum,
//! and the row's two small products.
//!
//! The kernels keep a unit's running sums in registers, so the sizes are bounded: hidden
//! width at most [`MAX_WIDTH`], batch input at most [`MAX_IN`], output at most
//! [`MAX_OUT`], at least two hidden layers; other MLPs keep the composed ops.

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{AutodiffBackend, Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::{CubeCount, CubeDim};

use super::launch_shape;
use super::mlp_kernels::{
    delta_kernel, forward_kernel, row_grad_kernel, weight_partial_kernel, weight_sum_kernel,
};

/// Widest hidden layer the kernels take (a unit's sums: `width` registers).
pub(crate) const MAX_WIDTH: usize = 64;
/// Widest batch input (the input's gradient: `d_in` registers a unit).
pub(crate) const MAX_IN: usize = 128;
/// Widest output.
pub(crate) const MAX_OUT: usize = 64;
/// Units of a weight-gradient cube.
const UNITS: usize = 256;
/// Floats of shared memory a weight-gradient cube may use (16 KiB: WebGPU's default).
const SHARED_FLOATS: usize = 4096;
/// The weight gradients' chunks of rows: at most this many (their partial sums are summed
/// one unit per weight, a loop over the chunks).
const MAX_CHUNKS: usize = 512;

/// The gradients of the input, the row, the first weight and bias, the stacked middle
/// weights and biases, and the last weight and bias (the trait spells the tuple out: its
/// macro reads the outputs from the tuple's type).
type Grads<T> = (T, T, T, T, T, T, T, T);

/// The MLP and its gradients on a backend. Weights are `[d_in, d_out]`, biases
/// `[1, d_out]`; the hidden layers after the first are stacked (`[depth - 1, width,
/// width]` and `[depth - 1, 1, width]`).
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait MlpOps: Backend {
    /// The output `[n, d_out]` of `x` `[n, d_in]` with the shared `row` `[1, d_row]`
    /// (`w_first` is `[d_in + d_row, width]`).
    #[fusion(meta = |x, _row, _wf, _bf, _wm, _bm, wl, _bl| out_spec(x, wl))]
    fn mlp_forward(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        b_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        b_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        b_last: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The output and the hidden activations `[depth width, n]` (what backward reads);
    /// not differentiated.
    #[fusion(meta = |x, _row, _wf, _bf, wm, _bm, wl, _bl| (out_spec(x, wl), hidden_spec(x, wm)))]
    fn mlp_forward_saving(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        b_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        b_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        b_last: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// The gradients of the input, the row and every weight and bias (first, stacked
    /// middle, last) for the output's gradient `grad`.
    #[fusion(meta = backward_meta)]
    #[allow(clippy::type_complexity)]
    fn mlp_backward(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        hidden: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
        FloatTensor<Self>,
    );
}

fn out_spec(x: &TensorSpec, w_last: &TensorSpec) -> TensorSpec {
    TensorSpec::new([x.shape[0], w_last.shape[1]].into(), x.dtype)
}

fn hidden_spec(x: &TensorSpec, w_mid: &TensorSpec) -> TensorSpec {
    let [depth, width] = [w_mid.shape[0] + 1, w_mid.shape[1]];
    TensorSpec::new([depth * width, x.shape[0]].into(), x.dtype)
}

fn backward_meta(
    x: &TensorSpec,
    row: &TensorSpec,
    w_first: &TensorSpec,
    w_mid: &TensorSpec,
    w_last: &TensorSpec,
    _hidden: &TensorSpec,
    _grad: &TensorSpec,
) -> Grads<TensorSpec> {
    let spec = |shape: Vec<usize>| TensorSpec::new(shape.into(), x.dtype);
    let (width, d_out) = (w_first.shape[1], w_last.shape[1]);
    (
        x.clone(),
        row.clone(),
        w_first.clone(),
        spec(vec![1, width]),
        w_mid.clone(),
        spec(vec![w_mid.shape[0], 1, width]),
        w_last.clone(),
        spec(vec![1, d_out]),
    )
}

/// Rows, input, hidden width, output and stacked middle layers of an MLP's operands.
struct Dims {
    n: usize,
    d_in: usize,
    width: usize,
    d_out: usize,
    n_mid: usize,
}

impl Dims {
    fn of(x: &CubeTensor, w_mid: &CubeTensor, w_last: &CubeTensor) -> Self {
        let (x, w_mid) = (x.meta.shape(), w_mid.meta.shape());
        Dims {
            n: x[0],
            d_in: x[1],
            width: w_mid[1],
            d_out: w_last.meta.shape()[1],
            n_mid: w_mid[0],
        }
    }
}

fn empty(like: &CubeTensor, shape: Vec<usize>) -> CubeTensor {
    empty_device_dtype(
        like.client.clone(),
        like.device.clone(),
        shape.into(),
        DType::F32,
    )
}

impl MlpOps for CubeBackend {
    fn mlp_forward(
        x: CubeTensor,
        row: CubeTensor,
        w_first: CubeTensor,
        b_first: CubeTensor,
        w_mid: CubeTensor,
        b_mid: CubeTensor,
        w_last: CubeTensor,
        b_last: CubeTensor,
    ) -> CubeTensor {
        Self::mlp_forward_saving(x, row, w_first, b_first, w_mid, b_mid, w_last, b_last).0
    }

    fn mlp_forward_saving(
        x: CubeTensor,
        row: CubeTensor,
        w_first: CubeTensor,
        b_first: CubeTensor,
        w_mid: CubeTensor,
        b_mid: CubeTensor,
        w_last: CubeTensor,
        b_last: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        let [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last] =
            [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last].map(into_contiguous);
        let d = Dims::of(&x, &w_mid, &w_last);
        let hidden = empty(&x, vec![(d.n_mid + 1) * d.width, d.n]);
        let out = empty(&x, vec![d.n, d.d_out]);
        let client = x.client.clone();
        let (count, dim) = launch_shape(&client, d.n.max(1));
        forward_kernel::launch(
            &client,
            count,
            dim,
            x.into_tensor_arg(),
            row.into_tensor_arg(),
            w_first.into_tensor_arg(),
            b_first.into_tensor_arg(),
            w_mid.into_tensor_arg(),
            b_mid.into_tensor_arg(),
            w_last.into_tensor_arg(),
            b_last.into_tensor_arg(),
            hidden.clone().into_tensor_arg(),
            out.clone().into_tensor_arg(),
            d.d_in,
            d.width,
            d.d_out,
        );
        (out, hidden)
    }

    fn mlp_backward(
        x: CubeTensor,
        row: CubeTensor,
        w_first: CubeTensor,
        w_mid: CubeTensor,
        w_last: CubeTensor,
        hidden: CubeTensor,
        grad: CubeTensor,
    ) -> Grads<CubeTensor> {
        let [x, row, w_first, w_mid, w_last, hidden, grad] =
            [x, row, w_first, w_mid, w_last, hidden, grad].map(into_contiguous);
        let d = Dims::of(&x, &w_mid, &w_last);
        let d_row = row.meta.shape()[1];
        let client = x.client.clone();
        let delta = empty(&x, vec![(d.n_mid + 1) * d.width, d.n]);
        let grad_x = empty(&x, vec![d.n, d.d_in]);
        let (count, dim) = launch_shape(&client, d.n.max(1));
        delta_kernel::launch(
            &client,
            count,
            dim,
            grad.clone().into_tensor_arg(),
            w_first.clone().into_tensor_arg(),
            w_mid.into_tensor_arg(),
            w_last.into_tensor_arg(),
            hidden.clone().into_tensor_arg(),
            delta.clone().into_tensor_arg(),
            grad_x.clone().into_tensor_arg(),
            d.d_in,
            d.width,
            d.d_out,
        );
        let w = d.width;
        let grads = [
            empty(&x, vec![d.d_in + d_row, w]),
            empty(&x, vec![1, w]),
            empty(&x, vec![d.n_mid, w, w]),
            empty(&x, vec![d.n_mid, 1, w]),
            empty(&x, vec![w, d.d_out]),
            empty(&x, vec![1, d.d_out]),
        ];
        weight_grads(&d, [&x, &hidden, &delta, &grad], &grads);
        let grad_row = empty(&x, vec![1, d_row]);
        let (count, dim) = launch_shape(&client, (d_row * w + d_row).max(1));
        row_grad_kernel::launch(
            &client,
            count,
            dim,
            row.into_tensor_arg(),
            w_first.into_tensor_arg(),
            grads[1].clone().into_tensor_arg(),
            grads[0].clone().into_tensor_arg(),
            grad_row.clone().into_tensor_arg(),
            d.d_in,
            w,
        );
        let [gwf, gbf, gwm, gbm, gwl, gbl] = grads;
        (grad_x, grad_row, gwf, gbf, gwm, gbm, gwl, gbl)
    }
}

/// Every layer's weight and bias gradients from the input, the hidden activations, their
/// deltas and the output's gradient: partial sums over chunks of rows (a cube per chunk
/// and layer), then their sum into `grads` (first, stacked middle and last weights and
/// biases).
fn weight_grads(d: &Dims, [x, hidden, delta, grad]: [&CubeTensor; 4], grads: &[CubeTensor; 6]) {
    let client = x.client.clone();
    let w = d.width;
    let layer_entries = [(d.d_in + 1) * w, (w + 1) * w, (w + 1) * d.d_out];
    let entries = layer_entries[0] + d.n_mid * layer_entries[1] + layer_entries[2];
    // A layer's 4 x 4 blocks of entries (its input with the bias's row, by its deltas).
    let blocks = |a: usize, dd: usize| (a + 1).div_ceil(4) * dd.div_ceil(4);
    let most = blocks(d.d_in, w).max(blocks(w, w)).max(blocks(w, d.d_out));
    // Shared rows: the widest input with the bias's row and the widest delta, in fours.
    let a_rows = 4 * (d.d_in.max(w) + 1).div_ceil(4);
    let d_rows = 4 * d.d_out.max(w).div_ceil(4);
    // An odd stride of at most 33 floats whose two tiles fit in shared memory.
    let mut stride = (SHARED_FLOATS / (a_rows + d_rows)).min(33);
    if stride.is_multiple_of(2) {
        stride -= 1;
    }
    let tile = stride - 1;
    let chunk_rows = d.n.div_ceil(MAX_CHUNKS).div_ceil(tile).max(8) * tile;
    let chunks = d.n.div_ceil(chunk_rows).max(1);
    let partial = empty(x, vec![chunks, entries]);
    let u32_of = |v: usize| u32::try_from(v).expect("an MLP's operands fit u32 indices");
    weight_partial_kernel::launch(
        &client,
        CubeCount::new_2d(u32_of(chunks), u32_of(d.n_mid + 2)),
        CubeDim::new_1d(UNITS as u32),
        x.clone().into_tensor_arg(),
        hidden.clone().into_tensor_arg(),
        delta.clone().into_tensor_arg(),
        grad.clone().into_tensor_arg(),
        partial.clone().into_tensor_arg(),
        u32_of(chunk_rows),
        d.d_in,
        w,
        d.d_out,
        a_rows,
        d_rows,
        tile,
        UNITS,
        most.div_ceil(UNITS),
    );
    let (count, dim) = launch_shape(&client, entries);
    let [gwf, gbf, gwm, gbm, gwl, gbl] = grads.clone();
    weight_sum_kernel::launch(
        &client,
        count,
        dim,
        partial.into_tensor_arg(),
        gwf.into_tensor_arg(),
        gbf.into_tensor_arg(),
        gwm.into_tensor_arg(),
        gbm.into_tensor_arg(),
        gwl.into_tensor_arg(),
        gbl.into_tensor_arg(),
        d.d_in,
        w,
        d.d_out,
    );
}

#[derive(Debug)]
struct MlpBackward;

impl<B: MlpOps> Backward<B, 8> for MlpBackward {
    /// The input, the row, the three weights and the hidden activations.
    type State = (
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
    );

    fn backward(self, ops: Ops<Self::State, 8>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let (x, row, w_first, w_mid, w_last, hidden) = ops.state;
        let (gx, grow, gwf, gbf, gwm, gbm, gwl, gbl) =
            B::mlp_backward(x, row, w_first, w_mid, w_last, hidden, grad);
        let all = [gx, grow, gwf, gbf, gwm, gbm, gwl, gbl];
        for (node, g) in ops.parents.into_iter().zip(all) {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: MlpOps, C: CheckpointStrategy> MlpOps for Autodiff<B, C> {
    fn mlp_forward(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        b_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        b_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        b_last: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let all = [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last];
        let nodes = all.each_ref().map(|t| t.node());
        let [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last] =
            all.map(|t| t.into_primitive());
        match MlpBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (out, hidden) = B::mlp_forward_saving(
                    x.clone(),
                    row.clone(),
                    w_first.clone(),
                    b_first,
                    w_mid.clone(),
                    b_mid,
                    w_last.clone(),
                    b_last,
                );
                prep.finish((x, row, w_first, w_mid, w_last, hidden), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::mlp_forward(
                x, row, w_first, b_first, w_mid, b_mid, w_last, b_last,
            )),
        }
    }

    /// Both outputs as constants.
    fn mlp_forward_saving(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        b_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        b_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        b_last: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last] =
            [x, row, w_first, b_first, w_mid, b_mid, w_last, b_last].map(|t| t.into_primitive());
        let (out, hidden) =
            B::mlp_forward_saving(x, row, w_first, b_first, w_mid, b_mid, w_last, b_last);
        (Self::from_inner(out), Self::from_inner(hidden))
    }

    /// The gradients as constants (they are not differentiated again).
    fn mlp_backward(
        x: FloatTensor<Self>,
        row: FloatTensor<Self>,
        w_first: FloatTensor<Self>,
        w_mid: FloatTensor<Self>,
        w_last: FloatTensor<Self>,
        hidden: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> Grads<FloatTensor<Self>> {
        let [x, row, w_first, w_mid, w_last, hidden, grad] =
            [x, row, w_first, w_mid, w_last, hidden, grad].map(|t| t.into_primitive());
        let (gx, grow, gwf, gbf, gwm, gbm, gwl, gbl) =
            B::mlp_backward(x, row, w_first, w_mid, w_last, hidden, grad);
        (
            Self::from_inner(gx),
            Self::from_inner(grow),
            Self::from_inner(gwf),
            Self::from_inner(gbf),
            Self::from_inner(gwm),
            Self::from_inner(gbm),
            Self::from_inner(gwl),
            Self::from_inner(gbl),
        )
    }
}

/// `cat([x, row repeated n times], 1)` (`x` `[n, d_x]`, `n > 0`; `row` `[1, d_row]`)
/// through a ReLU MLP without skips as one device op, where the kernels take its sizes;
/// `None` otherwise (the caller composes tensor ops). `params` are, layer by layer, the
/// weight `[d_in, d_out]` and the bias `[1, d_out]`, the first weight `[d_x + d_row,
/// width]`. Without a row, a zero row and a zero weight row stand in. Only for tensors
/// on a CubeCL device.
pub(crate) fn forward(
    x: &Tensor<2>,
    row: Option<&Tensor<2>>,
    params: &[Tensor<2>],
) -> Option<Tensor<2>> {
    let layers = params.len() / 2;
    if !params.len().is_multiple_of(2) || layers < 3 {
        return None;
    }
    let [_, d_x] = x.dims();
    let d_row = row.map_or(0, |r| r.dims()[1]);
    let width = params[0].dims()[1];
    let d_out = params[2 * layers - 1].dims()[1];
    let mut d = d_x + d_row;
    for pair in params.chunks_exact(2) {
        let [rows, cols] = pair[0].dims();
        if rows != d || pair[1].dims() != [1, cols] {
            return None;
        }
        d = cols;
    }
    let hidden_equal = params[..2 * layers - 2]
        .chunks_exact(2)
        .all(|pair| pair[0].dims()[1] == width);
    if !hidden_equal || width > MAX_WIDTH || d_x > MAX_IN || d_out > MAX_OUT {
        return None;
    }
    let device = x.device();
    let (row, w_first) = match row {
        Some(row) => (row.clone(), params[0].clone()),
        None => (
            Tensor::zeros([1, 1], &device),
            Tensor::cat(
                vec![params[0].clone(), Tensor::zeros([1, width], &device)],
                0,
            ),
        ),
    };
    let middle = &params[2..2 * layers - 2];
    let stack = |offset: usize| -> Tensor<3> {
        let mut parts: Vec<Tensor<3>> = middle
            .iter()
            .skip(offset)
            .step_by(2)
            .map(|t| t.clone().unsqueeze_dim::<3>(0))
            .collect();
        if parts.len() == 1 {
            parts.remove(0)
        } else {
            Tensor::cat(parts, 0)
        }
    };
    let out = Dispatch::mlp_forward(
        x.clone().into_dispatch(),
        row.into_dispatch(),
        w_first.into_dispatch(),
        params[1].clone().into_dispatch(),
        stack(0).into_dispatch(),
        stack(1).into_dispatch(),
        params[2 * layers - 2].clone().into_dispatch(),
        params[2 * layers - 1].clone().into_dispatch(),
    );
    Some(Tensor::from_dispatch(out))
}
