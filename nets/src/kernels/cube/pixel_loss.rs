//! The pixel loss's per-ray terms (colour over the background against the truth, the
//! labels' cross-entropy, the silhouette term) as one device op with its own backward.
//! Composed, these were a few dozen small kernels over the rays: the background's
//! blend, differences and squares, the log-softmax's max, exponentials, sums and
//! gather, the silhouette's comparisons and casts, forward and back, each one launch
//! that burn's fusion left apart. Here one launch each way (plus the rays' sum).

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
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;

use super::launch_shape;
use super::pixel_loss_kernels::{pixel_terms_backward_kernel, pixel_terms_kernel};

/// The per-ray terms and their gradients on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait PixelLossOps: Backend {
    /// `[r, 3]` per ray: the squared error of `rgb` `[r, 3]` over `background` `[3]`
    /// (by `opacity` `[r]`) against `target` `[r, 3]`, the cross-entropy of `seg`
    /// `[r, c]` at `labels` `[r]`, and `(o s - p s)^2` with `sure` `[r]` and `p` the
    /// person's labels (> 0).
    #[allow(clippy::too_many_arguments)]
    #[fusion(meta = |_rgb, opacity, _seg, _target, _labels, _sure, _bg| TensorSpec::new([opacity.shape[0], 3].into(), opacity.dtype))]
    fn pixel_terms(
        rgb: FloatTensor<Self>,
        opacity: FloatTensor<Self>,
        seg: FloatTensor<Self>,
        target: FloatTensor<Self>,
        labels: IntTensor<Self>,
        sure: FloatTensor<Self>,
        background: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The colour's `[r, 3]`, opacity's `[r]` and logits' `[r, c]` gradients for the
    /// terms' `grad` `[r, 3]`.
    #[allow(clippy::too_many_arguments)]
    #[fusion(meta = |rgb, opacity, seg, _target, _labels, _sure, _bg, _grad| (rgb.clone(), opacity.clone(), seg.clone()))]
    fn pixel_terms_backward(
        rgb: FloatTensor<Self>,
        opacity: FloatTensor<Self>,
        seg: FloatTensor<Self>,
        target: FloatTensor<Self>,
        labels: IntTensor<Self>,
        sure: FloatTensor<Self>,
        background: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

impl PixelLossOps for CubeBackend {
    fn pixel_terms(
        rgb: CubeTensor,
        opacity: CubeTensor,
        seg: CubeTensor,
        target: CubeTensor,
        labels: CubeTensor,
        sure: CubeTensor,
        background: CubeTensor,
    ) -> CubeTensor {
        let [rgb, opacity, seg, target, labels, sure, background] =
            [rgb, opacity, seg, target, labels, sure, background].map(into_contiguous);
        let rays = opacity.meta.shape()[0];
        let client = opacity.client.clone();
        let terms = empty_device_dtype(
            client.clone(),
            opacity.device.clone(),
            [rays, 3].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, rays.max(1));
        let int = dtype_to_storage_type(labels.dtype);
        pixel_terms_kernel::launch(
            &client,
            count,
            dim,
            rgb.into_tensor_arg(),
            opacity.into_tensor_arg(),
            seg.into_tensor_arg(),
            target.into_tensor_arg(),
            labels.into_tensor_arg(),
            sure.into_tensor_arg(),
            background.into_tensor_arg(),
            terms.clone().into_tensor_arg(),
            int,
        );
        terms
    }

    fn pixel_terms_backward(
        rgb: CubeTensor,
        opacity: CubeTensor,
        seg: CubeTensor,
        target: CubeTensor,
        labels: CubeTensor,
        sure: CubeTensor,
        background: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let [rgb, opacity, seg, target, labels, sure, background, grad] =
            [rgb, opacity, seg, target, labels, sure, background, grad].map(into_contiguous);
        let rays = opacity.meta.shape()[0];
        let client = opacity.client.clone();
        let empty = |like: &CubeTensor| {
            empty_device_dtype(
                client.clone(),
                like.device.clone(),
                like.meta.shape().clone(),
                DType::F32,
            )
        };
        let (grad_rgb, grad_opacity, grad_seg) = (empty(&rgb), empty(&opacity), empty(&seg));
        let (count, dim) = launch_shape(&client, rays.max(1));
        let int = dtype_to_storage_type(labels.dtype);
        pixel_terms_backward_kernel::launch(
            &client,
            count,
            dim,
            rgb.into_tensor_arg(),
            opacity.into_tensor_arg(),
            seg.into_tensor_arg(),
            target.into_tensor_arg(),
            labels.into_tensor_arg(),
            sure.into_tensor_arg(),
            background.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_rgb.clone().into_tensor_arg(),
            grad_opacity.clone().into_tensor_arg(),
            grad_seg.clone().into_tensor_arg(),
            int,
        );
        (grad_rgb, grad_opacity, grad_seg)
    }
}

#[derive(Debug)]
struct PixelTermsBackward;

/// The op's inputs, kept for its backward.
type Inputs<B> = (
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
    IntTensor<B>,
    FloatTensor<B>,
    FloatTensor<B>,
);

impl<B: PixelLossOps> Backward<B, 3> for PixelTermsBackward {
    /// The colour, opacity, logits, truth, labels, silhouette weights and background.
    type State = Inputs<B>;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let (rgb, opacity, seg, target, labels, sure, background) = ops.state;
        let outs =
            B::pixel_terms_backward(rgb, opacity, seg, target, labels, sure, background, grad);
        let [rgb_node, opacity_node, seg_node] = ops.parents;
        for (node, g) in [
            (rgb_node, outs.0),
            (opacity_node, outs.1),
            (seg_node, outs.2),
        ] {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: PixelLossOps, C: CheckpointStrategy> PixelLossOps for Autodiff<B, C> {
    fn pixel_terms(
        rgb: FloatTensor<Self>,
        opacity: FloatTensor<Self>,
        seg: FloatTensor<Self>,
        target: FloatTensor<Self>,
        labels: IntTensor<Self>,
        sure: FloatTensor<Self>,
        background: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let (rgb, rgb_node) = rgb.into_parts();
        let (opacity, opacity_node) = opacity.into_parts();
        let (seg, seg_node) = seg.into_parts();
        let [target, sure, background] = [target, sure, background].map(|t| t.into_primitive());
        match PixelTermsBackward
            .prepare::<C>([rgb_node, opacity_node, seg_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let inputs = (rgb, opacity, seg, target, labels, sure, background);
                let out = B::pixel_terms(
                    inputs.0.clone(),
                    inputs.1.clone(),
                    inputs.2.clone(),
                    inputs.3.clone(),
                    inputs.4.clone(),
                    inputs.5.clone(),
                    inputs.6.clone(),
                );
                prep.finish(inputs, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::pixel_terms(
                rgb, opacity, seg, target, labels, sure, background,
            )),
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn pixel_terms_backward(
        rgb: FloatTensor<Self>,
        opacity: FloatTensor<Self>,
        seg: FloatTensor<Self>,
        target: FloatTensor<Self>,
        labels: IntTensor<Self>,
        sure: FloatTensor<Self>,
        background: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let [rgb, opacity, seg, target, sure, background, grad] =
            [rgb, opacity, seg, target, sure, background, grad].map(|t| t.into_primitive());
        let (a, b, c) =
            B::pixel_terms_backward(rgb, opacity, seg, target, labels, sure, background, grad);
        (
            Self::from_inner(a),
            Self::from_inner(b),
            Self::from_inner(c),
        )
    }
}

/// The per-ray terms `[r, 3]` (see [`PixelLossOps::pixel_terms`]). Only for tensors on a
/// CubeCL device.
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_terms(
    rgb: Tensor<2>,
    opacity: Tensor<1>,
    seg: Tensor<2>,
    target: Tensor<2>,
    labels: Tensor<1, Int>,
    sure: Tensor<1>,
    background: Tensor<1>,
) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::pixel_terms(
        rgb.into_dispatch(),
        opacity.into_dispatch(),
        seg.into_dispatch(),
        target.into_dispatch(),
        labels.into_dispatch(),
        sure.into_dispatch(),
        background.into_dispatch(),
    ))
}
