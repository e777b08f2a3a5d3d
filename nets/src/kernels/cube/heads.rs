//! A net output's columns through their activation (density through softplus, colour
//! through the sigmoid, labels as they are) as one device op with its own backward.
//! Composed, each was a column cut and the activation's elementwise ops forward, and
//! back the activation's derivative, a fill of the whole output and the cut's slice
//! assignment; here one launch each way, the backward writing the whole output's
//! gradient (zero outside the columns) at once.

use burn::backend::AutodiffBackend;
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;

use super::heads_kernels::{heads_backward_kernel, heads_kernel};
use super::launch_shape;

/// What a head's columns go through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Activation {
    None = 0,
    Softplus = 1,
    Sigmoid = 2,
}

/// The activated columns and their gradient on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait HeadOps: Backend {
    /// `[n, count]`: columns `start..start + count` of `raw` `[n, k]` through
    /// `activation` (0 none, 1 softplus, 2 sigmoid).
    #[fusion(meta = heads_meta)]
    fn head_columns(
        raw: FloatTensor<Self>,
        start: u32,
        count: u32,
        activation: u32,
    ) -> FloatTensor<Self>;

    /// `raw`'s gradient `[n, k]` for the columns' `grad` `[n, count]`.
    #[fusion(meta = |raw, _grad, _start, _activation| raw.clone())]
    fn head_columns_backward(
        raw: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        start: u32,
        activation: u32,
    ) -> FloatTensor<Self>;
}

fn heads_meta(raw: &TensorSpec, _start: &u32, count: &u32, _activation: &u32) -> TensorSpec {
    TensorSpec::new([raw.shape[0], *count as usize].into(), raw.dtype)
}

impl HeadOps for CubeBackend {
    fn head_columns(raw: CubeTensor, start: u32, count: u32, activation: u32) -> CubeTensor {
        let raw = into_contiguous(raw);
        let n = raw.meta.shape()[0];
        let client = raw.client.clone();
        let shape = [n, count as usize];
        let out = empty_device_dtype(client.clone(), raw.device.clone(), shape.into(), DType::F32);
        let (count, dim) = launch_shape(&client, (n * count as usize).max(1));
        heads_kernel::launch(
            &client,
            count,
            dim,
            raw.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            start,
            activation,
        );
        out
    }

    fn head_columns_backward(
        raw: CubeTensor,
        grad: CubeTensor,
        start: u32,
        activation: u32,
    ) -> CubeTensor {
        let [raw, grad] = [raw, grad].map(into_contiguous);
        let client = raw.client.clone();
        let shape = raw.meta.shape().clone();
        let grad_raw = empty_device_dtype(
            client.clone(),
            raw.device.clone(),
            shape.clone(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, shape.num_elements().max(1));
        heads_backward_kernel::launch(
            &client,
            count,
            dim,
            raw.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_raw.clone().into_tensor_arg(),
            start,
            activation,
        );
        grad_raw
    }
}

#[derive(Debug)]
struct HeadBackward;

impl<B: HeadOps> Backward<B, 1> for HeadBackward {
    /// The net's output, the first column and the activation.
    type State = (FloatTensor<B>, u32, u32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [raw_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let Some(node) = raw_node else { return };
        let (raw, start, activation) = ops.state;
        grads.register::<B>(
            node.id,
            B::head_columns_backward(raw, grad, start, activation),
        );
    }
}

impl<B: HeadOps, C: CheckpointStrategy> HeadOps for Autodiff<B, C> {
    fn head_columns(
        raw: FloatTensor<Self>,
        start: u32,
        count: u32,
        activation: u32,
    ) -> FloatTensor<Self> {
        let (raw, raw_node) = raw.into_parts();
        match HeadBackward
            .prepare::<C>([raw_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::head_columns(raw.clone(), start, count, activation);
                prep.finish((raw, start, activation), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::head_columns(raw, start, count, activation)),
        }
    }

    /// The gradient as a constant (it is not differentiated again).
    fn head_columns_backward(
        raw: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        start: u32,
        activation: u32,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::head_columns_backward(
            raw.into_primitive(),
            grad.into_primitive(),
            start,
            activation,
        ))
    }
}

/// Columns `start..start + count` of `raw` `[n, k]` through `activation`, `[n, count]`.
/// Only for tensors on a CubeCL device.
pub(crate) fn columns(
    raw: Tensor<2>,
    start: usize,
    count: usize,
    activation: Activation,
) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::head_columns(
        raw.into_dispatch(),
        start as u32,
        count as u32,
        activation as u32,
    ))
}
