//! Inverse skinning's softmax blend as one device op with its own backward: per sample,
//! the logits of its candidate bones (a trilinear read of the weight volume plus the
//! posed-space prior), their softmax and the blended canonical point. Composed of burn
//! ops this was a gather of eight volume rows a pair (their rows and weights laid out and
//! uploaded by the host), a padded `[n, K]` softmax and a gather of the points, forward
//! and back; here forward is one launch and backward one (the volume's gradient by
//! atomic adds) after a fill.

use burn::backend::AutodiffBackend;
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::cubecl::dtype_to_storage_type;
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::{empty_device_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;

use super::launch_shape;
pub(crate) use super::skin_kernels::{GRID_PARAMS, PAIR_PARAMS};
use super::skin_kernels::{blend_backward_kernel, blend_kernel};

/// The blend and its gradients on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait SkinBlendOps: Backend {
    /// `[n, 3]` canonical points from the weight `volume` `[C R^3]`, the pairs' canonical
    /// points `xb` `[m, 3]`, their numbers `pairs` `[m 5 + 7]` (see `skin_kernels`) and
    /// `slots` `[n, K]` (sample `s`'s `j`-th pair, or `m` for none).
    #[fusion(meta = blend_meta)]
    fn skin_blend(
        volume: FloatTensor<Self>,
        xb: FloatTensor<Self>,
        pairs: FloatTensor<Self>,
        slots: IntTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The volume's `[C R^3]` and the pairs' points' `[m, 3]` gradients for the output's
    /// `grad` `[n, 3]`.
    #[fusion(meta = |volume, xb, _pairs, _slots, _grad| (volume.clone(), xb.clone()))]
    fn skin_blend_backward(
        volume: FloatTensor<Self>,
        xb: FloatTensor<Self>,
        pairs: FloatTensor<Self>,
        slots: IntTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

fn blend_meta(
    _volume: &TensorSpec,
    xb: &TensorSpec,
    _pairs: &TensorSpec,
    slots: &TensorSpec,
) -> TensorSpec {
    TensorSpec::new([slots.shape[0], 3].into(), xb.dtype)
}

impl SkinBlendOps for CubeBackend {
    fn skin_blend(
        volume: CubeTensor,
        xb: CubeTensor,
        pairs: CubeTensor,
        slots: CubeTensor,
    ) -> CubeTensor {
        let [volume, xb, pairs, slots] = [volume, xb, pairs, slots].map(into_contiguous);
        let n = slots.meta.shape()[0];
        let client = xb.client.clone();
        let out = empty_device_dtype(client.clone(), xb.device.clone(), [n, 3].into(), DType::F32);
        let (count, dim) = launch_shape(&client, n.max(1));
        let int = dtype_to_storage_type(slots.dtype);
        blend_kernel::launch(
            &client,
            count,
            dim,
            volume.into_tensor_arg(),
            xb.into_tensor_arg(),
            pairs.into_tensor_arg(),
            slots.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            int,
        );
        out
    }

    fn skin_blend_backward(
        volume: CubeTensor,
        xb: CubeTensor,
        pairs: CubeTensor,
        slots: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        let [volume, xb, pairs, slots, grad] =
            [volume, xb, pairs, slots, grad].map(into_contiguous);
        let n = slots.meta.shape()[0];
        let client = xb.client.clone();
        let grad_volume = zeros_client(
            client.clone(),
            volume.device.clone(),
            volume.meta.shape().clone(),
            DType::F32,
        );
        // Every pair sits in one slot, so its gradient is written exactly once.
        let grad_xb = empty_device_dtype(
            client.clone(),
            xb.device.clone(),
            xb.meta.shape().clone(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, n.max(1));
        let int = dtype_to_storage_type(slots.dtype);
        blend_backward_kernel::launch(
            &client,
            count,
            dim,
            volume.into_tensor_arg(),
            xb.into_tensor_arg(),
            pairs.into_tensor_arg(),
            slots.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_volume.clone().into_tensor_arg(),
            grad_xb.clone().into_tensor_arg(),
            int,
        );
        (grad_volume, grad_xb)
    }
}

#[derive(Debug)]
struct SkinBlendBackward;

impl<B: SkinBlendOps> Backward<B, 2> for SkinBlendBackward {
    /// The volume, the pairs' points, their numbers and the slots.
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, IntTensor<B>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [volume_node, xb_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (volume, xb, pairs, slots) = ops.state;
        let (grad_volume, grad_xb) = B::skin_blend_backward(volume, xb, pairs, slots, grad);
        if let Some(node) = volume_node {
            grads.register::<B>(node.id, grad_volume);
        }
        if let Some(node) = xb_node {
            grads.register::<B>(node.id, grad_xb);
        }
    }
}

impl<B: SkinBlendOps, C: CheckpointStrategy> SkinBlendOps for Autodiff<B, C> {
    fn skin_blend(
        volume: FloatTensor<Self>,
        xb: FloatTensor<Self>,
        pairs: FloatTensor<Self>,
        slots: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (volume, volume_node) = volume.into_parts();
        let (xb, xb_node) = xb.into_parts();
        let pairs = pairs.into_primitive();
        match SkinBlendBackward
            .prepare::<C>([volume_node, xb_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::skin_blend(volume.clone(), xb.clone(), pairs.clone(), slots.clone());
                prep.finish((volume, xb, pairs, slots), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::skin_blend(volume, xb, pairs, slots)),
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn skin_blend_backward(
        volume: FloatTensor<Self>,
        xb: FloatTensor<Self>,
        pairs: FloatTensor<Self>,
        slots: IntTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_volume, grad_xb) = B::skin_blend_backward(
            volume.into_primitive(),
            xb.into_primitive(),
            pairs.into_primitive(),
            slots,
            grad.into_primitive(),
        );
        (Self::from_inner(grad_volume), Self::from_inner(grad_xb))
    }
}

/// The blended canonical points `[n, 3]` of `n = slots.dims()[0]` samples (see
/// [`SkinBlendOps::skin_blend`]). Only for tensors on a CubeCL device.
pub(crate) fn blend(
    volume: Tensor<1>,
    xb: Tensor<2>,
    pairs: Tensor<1>,
    slots: Tensor<2, Int>,
) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::skin_blend(
        volume.into_dispatch(),
        xb.into_dispatch(),
        pairs.into_dispatch(),
        slots.into_dispatch(),
    ))
}
