//! Volume rendering's per-ray sums `sum_i w_i v_i` (colour, segmentation, opacity, depth)
//! as one device op with its own backward. Composed of burn ops each sum was a product
//! kernel, a fill and an atomic scatter-add forward, and a gather, two products and a
//! reduction back; here forward is one launch, with no atomics (so the same bits on
//! every run), and backward one.

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
use super::ray_sums_kernels::{ray_sums_backward_kernel, ray_sums_kernel};

/// The per-ray sums and their gradient on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait RaySumOps: Backend {
    /// `[r, c]` sums over each ray's samples of `weights` `[n]` times `values` (`[n, c]`,
    /// or `[1, c]` shared by every sample), the rays given by `offsets` `[r + 1]` and
    /// each sample's ray by `ray` `[n]` (the backward's).
    #[fusion(meta = sums_meta)]
    fn ray_sums(
        weights: FloatTensor<Self>,
        values: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        ray: IntTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The weights' `[n]` and the values' per-sample `[n, c]` gradients for the sums'
    /// `grad` `[r, c]`, `ray` `[n]` each sample's ray.
    #[fusion(meta = backward_meta)]
    fn ray_sums_backward(
        weights: FloatTensor<Self>,
        values: FloatTensor<Self>,
        ray: IntTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

fn sums_meta(
    _weights: &TensorSpec,
    values: &TensorSpec,
    offsets: &TensorSpec,
    _ray: &TensorSpec,
) -> TensorSpec {
    let rays = offsets.shape[0].saturating_sub(1);
    TensorSpec::new([rays, values.shape[1]].into(), values.dtype)
}

fn backward_meta(
    weights: &TensorSpec,
    values: &TensorSpec,
    _ray: &TensorSpec,
    _grad: &TensorSpec,
) -> (TensorSpec, TensorSpec) {
    let per_sample = [weights.shape[0], values.shape[1]];
    (
        weights.clone(),
        TensorSpec::new(per_sample.into(), values.dtype),
    )
}

impl RaySumOps for CubeBackend {
    fn ray_sums(
        weights: CubeTensor,
        values: CubeTensor,
        offsets: CubeTensor,
        _ray: CubeTensor,
    ) -> CubeTensor {
        let [weights, values, offsets] = [weights, values, offsets].map(into_contiguous);
        let rays = offsets.meta.shape()[0] - 1;
        let columns = values.meta.shape()[1];
        let client = weights.client.clone();
        let out = empty_device_dtype(
            client.clone(),
            weights.device.clone(),
            [rays, columns].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, (rays * columns).max(1));
        let int = dtype_to_storage_type(offsets.dtype);
        ray_sums_kernel::launch(
            &client,
            count,
            dim,
            weights.into_tensor_arg(),
            values.into_tensor_arg(),
            offsets.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            int,
        );
        out
    }

    fn ray_sums_backward(
        weights: CubeTensor,
        values: CubeTensor,
        ray: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        let [weights, values, ray, grad] = [weights, values, ray, grad].map(into_contiguous);
        let n = weights.meta.shape()[0];
        let columns = values.meta.shape()[1];
        let client = weights.client.clone();
        let empty = |shape: Vec<usize>| {
            empty_device_dtype(
                client.clone(),
                weights.device.clone(),
                shape.into(),
                DType::F32,
            )
        };
        let (grad_weights, grad_values) = (empty(vec![n]), empty(vec![n, columns]));
        let (count, dim) = launch_shape(&client, n.max(1));
        let int = dtype_to_storage_type(ray.dtype);
        ray_sums_backward_kernel::launch(
            &client,
            count,
            dim,
            weights.into_tensor_arg(),
            values.into_tensor_arg(),
            ray.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_weights.clone().into_tensor_arg(),
            grad_values.clone().into_tensor_arg(),
            int,
        );
        (grad_weights, grad_values)
    }
}

#[derive(Debug)]
struct RaySumsBackward;

impl<B: RaySumOps> Backward<B, 2> for RaySumsBackward {
    /// The weights, the values and each sample's ray.
    type State = (FloatTensor<B>, FloatTensor<B>, IntTensor<B>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [weights_node, values_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (weights, values, ray) = ops.state;
        let shared = values.shape()[0] == 1 && weights.shape()[0] != 1;
        let (grad_weights, grad_values) = B::ray_sums_backward(weights, values, ray, grad);
        if let Some(node) = weights_node {
            grads.register::<B>(node.id, grad_weights);
        }
        if let Some(node) = values_node {
            // A shared row's gradient is the sum of every sample's.
            let grad_values = if shared {
                B::float_sum_dim(grad_values, 0)
            } else {
                grad_values
            };
            grads.register::<B>(node.id, grad_values);
        }
    }
}

impl<B: RaySumOps, C: CheckpointStrategy> RaySumOps for Autodiff<B, C> {
    fn ray_sums(
        weights: FloatTensor<Self>,
        values: FloatTensor<Self>,
        offsets: IntTensor<Self>,
        ray: IntTensor<Self>,
    ) -> FloatTensor<Self> {
        let (weights, weights_node) = weights.into_parts();
        let (values, values_node) = values.into_parts();
        match RaySumsBackward
            .prepare::<C>([weights_node, values_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::ray_sums(weights.clone(), values.clone(), offsets, ray.clone());
                prep.finish((weights, values, ray), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::ray_sums(weights, values, offsets, ray)),
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn ray_sums_backward(
        weights: FloatTensor<Self>,
        values: FloatTensor<Self>,
        ray: IntTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_weights, grad_values) = B::ray_sums_backward(
            weights.into_primitive(),
            values.into_primitive(),
            ray,
            grad.into_primitive(),
        );
        (
            Self::from_inner(grad_weights),
            Self::from_inner(grad_values),
        )
    }
}

/// The `[r, c]` per-ray sums of `weights` `[n]` times `values` (`[n, c]`, or `[1, c]`
/// shared), rays `offsets` `[r + 1]`, each sample's ray `ray` `[n]` (see
/// [`RaySumOps::ray_sums`]). Only for tensors on a CubeCL device.
pub(crate) fn ray_sums(
    weights: Tensor<1>,
    values: Tensor<2>,
    offsets: Tensor<1, Int>,
    ray: Tensor<1, Int>,
) -> Tensor<2> {
    Tensor::from_dispatch(Dispatch::ray_sums(
        weights.into_dispatch(),
        values.into_dispatch(),
        offsets.into_dispatch(),
        ray.into_dispatch(),
    ))
}
