//! Inverse skinning as one device op with its own backward: per sample, each candidate
//! bone's canonical point (the bone's transform of the sample), its logit (a trilinear
//! read of the weight volume plus the posed-space prior), their softmax and the blended
//! canonical point. Composed of burn ops this was a gather of eight volume rows a pair
//! (their rows and weights laid out and uploaded by the host), a padded `[n, K]` softmax
//! and a gather of the points, forward and back; here forward is one launch and backward
//! one (the volume's and the transforms' gradients by atomic adds) after a fill, and the
//! host uploads each sample once with its candidate bones' mask instead of each pair.

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
pub(crate) use super::skin_kernels::{
    CAPSULE_PARAMS, CAPSULE_STARTS, FINGER_TAU, FIRST_FINGER, FRAME_HEAD, MASK_BITS, N_JOINTS, TAU,
};
use super::skin_kernels::{warp_backward_kernel, warp_kernel};

/// The warp and its gradients on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait SkinWarpOps: Backend {
    /// `[n, 3]` canonical points from the weight `volume` `[C R^3]`, the joints'
    /// `transforms` `[55, 12]`, the posed `points` `[n, 3]`, the `frame`'s numbers and
    /// each sample's candidate bones `masks` `[n, 2]` (see `skin_kernels`).
    #[fusion(meta = warp_meta)]
    fn skin_warp(
        volume: FloatTensor<Self>,
        transforms: FloatTensor<Self>,
        points: FloatTensor<Self>,
        frame: FloatTensor<Self>,
        masks: IntTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The volume's `[C R^3]` and the transforms' `[55, 12]` gradients for the output's
    /// `grad` `[n, 3]`; the transforms' only with `with_transforms` (else not written).
    #[fusion(meta = |volume, transforms, _points, _frame, _masks, _grad, _with| {
        (volume.clone(), transforms.clone())
    })]
    fn skin_warp_backward(
        volume: FloatTensor<Self>,
        transforms: FloatTensor<Self>,
        points: FloatTensor<Self>,
        frame: FloatTensor<Self>,
        masks: IntTensor<Self>,
        grad: FloatTensor<Self>,
        with_transforms: u32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

fn warp_meta(
    _volume: &TensorSpec,
    _transforms: &TensorSpec,
    points: &TensorSpec,
    _frame: &TensorSpec,
    masks: &TensorSpec,
) -> TensorSpec {
    TensorSpec::new([masks.shape[0], 3].into(), points.dtype)
}

impl SkinWarpOps for CubeBackend {
    fn skin_warp(
        volume: CubeTensor,
        transforms: CubeTensor,
        points: CubeTensor,
        frame: CubeTensor,
        masks: CubeTensor,
    ) -> CubeTensor {
        let [volume, transforms, points, frame, masks] =
            [volume, transforms, points, frame, masks].map(into_contiguous);
        let n = masks.meta.shape()[0];
        let client = points.client.clone();
        let out = empty_device_dtype(
            client.clone(),
            points.device.clone(),
            [n, 3].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, n.max(1));
        let int = dtype_to_storage_type(masks.dtype);
        warp_kernel::launch(
            &client,
            count,
            dim,
            volume.into_tensor_arg(),
            transforms.into_tensor_arg(),
            points.into_tensor_arg(),
            frame.into_tensor_arg(),
            masks.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            int,
        );
        out
    }

    fn skin_warp_backward(
        volume: CubeTensor,
        transforms: CubeTensor,
        points: CubeTensor,
        frame: CubeTensor,
        masks: CubeTensor,
        grad: CubeTensor,
        with_transforms: u32,
    ) -> (CubeTensor, CubeTensor) {
        let [volume, transforms, points, frame, masks, grad] =
            [volume, transforms, points, frame, masks, grad].map(into_contiguous);
        let n = masks.meta.shape()[0];
        let client = points.client.clone();
        let shape = |like: &CubeTensor| like.meta.shape().clone();
        let grad_volume = zeros_client(
            client.clone(),
            volume.device.clone(),
            shape(&volume),
            DType::F32,
        );
        // Unread without `with_transforms`, so not zeroed (a fill kernel less).
        let grad_transforms = if with_transforms != 0 {
            zeros_client(
                client.clone(),
                transforms.device.clone(),
                shape(&transforms),
                DType::F32,
            )
        } else {
            empty_device_dtype(
                client.clone(),
                transforms.device.clone(),
                shape(&transforms),
                DType::F32,
            )
        };
        let (count, dim) = launch_shape(&client, n.max(1));
        let int = dtype_to_storage_type(masks.dtype);
        warp_backward_kernel::launch(
            &client,
            count,
            dim,
            volume.into_tensor_arg(),
            transforms.into_tensor_arg(),
            points.into_tensor_arg(),
            frame.into_tensor_arg(),
            masks.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_volume.clone().into_tensor_arg(),
            grad_transforms.clone().into_tensor_arg(),
            with_transforms != 0,
            int,
        );
        (grad_volume, grad_transforms)
    }
}

#[derive(Debug)]
struct SkinWarpBackward;

impl<B: SkinWarpOps> Backward<B, 2> for SkinWarpBackward {
    /// The volume, the transforms, the points, the frame's numbers and the masks.
    type State = (
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        IntTensor<B>,
    );

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [volume_node, transforms_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (volume, transforms, points, frame, masks) = ops.state;
        let with_transforms = transforms_node.is_some() as u32;
        let (grad_volume, grad_transforms) = B::skin_warp_backward(
            volume,
            transforms,
            points,
            frame,
            masks,
            grad,
            with_transforms,
        );
        if let Some(node) = volume_node {
            grads.register::<B>(node.id, grad_volume);
        }
        if let Some(node) = transforms_node {
            grads.register::<B>(node.id, grad_transforms);
        }
    }
}

impl<B: SkinWarpOps, C: CheckpointStrategy> SkinWarpOps for Autodiff<B, C> {
    fn skin_warp(
        volume: FloatTensor<Self>,
        transforms: FloatTensor<Self>,
        points: FloatTensor<Self>,
        frame: FloatTensor<Self>,
        masks: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (volume, volume_node) = volume.into_parts();
        let (transforms, transforms_node) = transforms.into_parts();
        let points = points.into_primitive();
        let frame = frame.into_primitive();
        match SkinWarpBackward
            .prepare::<C>([volume_node, transforms_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::skin_warp(
                    volume.clone(),
                    transforms.clone(),
                    points.clone(),
                    frame.clone(),
                    masks.clone(),
                );
                prep.finish((volume, transforms, points, frame, masks), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::skin_warp(volume, transforms, points, frame, masks))
            }
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn skin_warp_backward(
        volume: FloatTensor<Self>,
        transforms: FloatTensor<Self>,
        points: FloatTensor<Self>,
        frame: FloatTensor<Self>,
        masks: IntTensor<Self>,
        grad: FloatTensor<Self>,
        with_transforms: u32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_volume, grad_transforms) = B::skin_warp_backward(
            volume.into_primitive(),
            transforms.into_primitive(),
            points.into_primitive(),
            frame.into_primitive(),
            masks,
            grad.into_primitive(),
            with_transforms,
        );
        (
            Self::from_inner(grad_volume),
            Self::from_inner(grad_transforms),
        )
    }
}

/// The canonical points `[n, 3]` of `n = masks.dims()[0]` samples (see
/// [`SkinWarpOps::skin_warp`]). Only for tensors on a CubeCL device.
pub(crate) fn warp(
    volume: Tensor<1>,
    transforms: Tensor<2>,
    points: Tensor<2>,
    frame: Tensor<1>,
    masks: Tensor<2, Int>,
) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::skin_warp(
        volume.into_dispatch(),
        transforms.into_dispatch(),
        points.into_dispatch(),
        frame.into_dispatch(),
        masks.into_dispatch(),
    ))
}
