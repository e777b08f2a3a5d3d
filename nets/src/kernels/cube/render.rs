//! Volume rendering's weights as one device op with its own backward: per ray, the
//! transmittance before each sample times its alpha, and the transmittance left at the
//! end. Composed of burn ops this was a segmented Hillis-Steele scan (a mask upload and
//! a handful of kernels per doubling) plus a dozen elementwise kernels, forward and back.

use burn::backend::AutodiffBackend;
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::cubecl::dtype_to_storage_type;
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, TensorMetadata, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;

use super::launch_shape;
use super::render_kernels::{weights_backward_kernel, weights_kernel};

/// The rendering weights and their gradient on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait RenderWeightOps: Backend {
    /// `tau` `[n]` (optical depths, >= 0) and `offsets` `[r + 1]` (each ray's first
    /// sample, then `n`) to the weights `[n]` and the final transmittance `[r]`.
    #[fusion(meta = weights_meta)]
    fn render_weights(
        tau: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        small: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// The optical depths' gradient `[n]`, from the forward's outputs and their gradients.
    #[fusion(meta = |tau, _offsets, _weights, _t_end, _gw, _gt, _small| tau.clone())]
    fn render_weights_backward(
        tau: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        weights: FloatTensor<Self>,
        t_end: FloatTensor<Self>,
        grad_weights: FloatTensor<Self>,
        grad_t_end: FloatTensor<Self>,
        small: f32,
    ) -> FloatTensor<Self>;
}

fn weights_meta(tau: &TensorSpec, offsets: &TensorSpec, _small: &f32) -> (TensorSpec, TensorSpec) {
    let rays = offsets.shape[0].saturating_sub(1);
    (tau.clone(), TensorSpec::new([rays].into(), tau.dtype))
}

impl RenderWeightOps for CubeBackend {
    fn render_weights(
        tau: CubeTensor,
        offsets: CubeTensor,
        small: f32,
    ) -> (CubeTensor, CubeTensor) {
        let (tau, offsets) = (into_contiguous(tau), into_contiguous(offsets));
        let n = tau.meta.shape()[0];
        let rays = offsets.meta.shape()[0] - 1;
        let client = tau.client.clone();
        let weights =
            empty_device_dtype(client.clone(), tau.device.clone(), [n].into(), DType::F32);
        let t_end = empty_device_dtype(
            client.clone(),
            tau.device.clone(),
            [rays].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, rays.max(1));
        let int = dtype_to_storage_type(offsets.dtype);
        weights_kernel::launch(
            &client,
            count,
            dim,
            tau.into_tensor_arg(),
            offsets.into_tensor_arg(),
            weights.clone().into_tensor_arg(),
            t_end.clone().into_tensor_arg(),
            small,
            int,
        );
        (weights, t_end)
    }

    fn render_weights_backward(
        tau: CubeTensor,
        offsets: CubeTensor,
        weights: CubeTensor,
        t_end: CubeTensor,
        grad_weights: CubeTensor,
        grad_t_end: CubeTensor,
        small: f32,
    ) -> CubeTensor {
        let [tau, offsets, weights, t_end, grad_weights, grad_t_end] =
            [tau, offsets, weights, t_end, grad_weights, grad_t_end].map(into_contiguous);
        let n = tau.meta.shape()[0];
        let rays = offsets.meta.shape()[0] - 1;
        let client = tau.client.clone();
        let grad_tau =
            empty_device_dtype(client.clone(), tau.device.clone(), [n].into(), DType::F32);
        let (count, dim) = launch_shape(&client, rays.max(1));
        let int = dtype_to_storage_type(offsets.dtype);
        weights_backward_kernel::launch(
            &client,
            count,
            dim,
            tau.into_tensor_arg(),
            offsets.into_tensor_arg(),
            weights.into_tensor_arg(),
            t_end.into_tensor_arg(),
            grad_weights.into_tensor_arg(),
            grad_t_end.into_tensor_arg(),
            grad_tau.clone().into_tensor_arg(),
            small,
            int,
        );
        grad_tau
    }
}

/// The backward of the weights. The op has two outputs and burn gives each its own node:
/// both nodes are this step, told apart by the state's flag, and each passes a zero for
/// the other output's gradient (the two gradients of tau then add up in burn).
#[derive(Debug)]
struct WeightsBackward;

impl<B: RenderWeightOps> Backward<B, 1> for WeightsBackward {
    /// tau, offsets, weights, t_end, and whether this node is the weights (else t_end).
    type State = (
        FloatTensor<B>,
        IntTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        bool,
        f32,
    );

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [tau_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (tau, offsets, weights, t_end, is_weights, small) = ops.state;
        let Some(node) = tau_node else { return };
        let (grad_weights, grad_t_end) = if is_weights {
            (
                grad,
                B::float_zeros(t_end.shape(), &t_end.device(), t_end.dtype().into()),
            )
        } else {
            (
                B::float_zeros(weights.shape(), &weights.device(), weights.dtype().into()),
                grad,
            )
        };
        let grad_tau = B::render_weights_backward(
            tau,
            offsets,
            weights,
            t_end,
            grad_weights,
            grad_t_end,
            small,
        );
        grads.register::<B>(node.id, grad_tau);
    }
}

impl<B: RenderWeightOps, C: CheckpointStrategy> RenderWeightOps for Autodiff<B, C> {
    fn render_weights(
        tau: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        small: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let nodes = [tau.node(), tau.node()];
        let tau = tau.into_primitive();
        let (weights, t_end) = B::render_weights(tau.clone(), offsets.clone(), small);
        let state = |is_weights| {
            (
                tau.clone(),
                offsets.clone(),
                weights.clone(),
                t_end.clone(),
                is_weights,
                small,
            )
        };
        let wrap = |out: FloatTensor<B>, is_weights: bool, node| match WeightsBackward
            .prepare::<C>([node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(state(is_weights), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        let [weights_node, end_node] = nodes;
        (
            wrap(weights.clone(), true, weights_node),
            wrap(t_end.clone(), false, end_node),
        )
    }

    /// The gradient as a constant (it is not differentiated again).
    fn render_weights_backward(
        tau: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        weights: FloatTensor<Self>,
        t_end: FloatTensor<Self>,
        grad_weights: FloatTensor<Self>,
        grad_t_end: FloatTensor<Self>,
        small: f32,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::render_weights_backward(
            tau.into_primitive(),
            offsets,
            weights.into_primitive(),
            t_end.into_primitive(),
            grad_weights.into_primitive(),
            grad_t_end.into_primitive(),
            small,
        ))
    }
}

/// The weights `[n]` and final transmittances `[r]` of optical depths `tau` `[n]` on
/// rays `offsets` (`[r + 1]`, on `tau`'s device). Only for tensors on a CubeCL device.
pub(crate) fn render_weights(
    tau: Tensor<1>,
    offsets: Tensor<1, Int>,
    small: f32,
) -> (Tensor<1>, Tensor<1>) {
    let (weights, t_end) =
        Dispatch::render_weights(tau.into_dispatch(), offsets.into_dispatch(), small);
    (Tensor::from_dispatch(weights), Tensor::from_dispatch(t_end))
}
