//! The hash encoding as one device op with its own backward (burn's backend extension:
//! the kernels on CubeCL's backend, lazily through fusion, differentiated by autodiff).
//!
//! Composed of burn ops, a level's corners cost ~20 integer kernels, and the encoding's
//! forward and backward a few hundred launches per call; here forward is one launch and
//! backward two (the table's gradient by atomic adds, the points' by recomputing each
//! level's corners), all in parallel over (point, level) or points.

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
use burn::tensor::{DType, TensorData};
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::{empty_device_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;

use super::hash_kernels::{LEVEL_PARAMS, encode_kernel, point_grad_kernel, table_grad_kernel};
use super::launch_shape;

/// The encoding and its gradients on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait HashEncodeOps: Backend {
    /// `[n, L F]` from `table` `[rows, F]`, `points` `[n, 3]` in the unit cube and
    /// `levels` `[L LEVEL_PARAMS]` (see `hash_kernels`).
    #[fusion(meta = encode_meta)]
    fn hash_encode(
        table: FloatTensor<Self>,
        points: FloatTensor<Self>,
        levels: FloatTensor<Self>,
        id_hash: u32,
    ) -> FloatTensor<Self>;

    /// The table's `[rows, F]` and the points' `[n, 3]` gradients for the output's `grad`.
    #[fusion(meta = |table, points, _levels, _grad, _id| (table.clone(), points.clone()))]
    fn hash_encode_backward(
        table: FloatTensor<Self>,
        points: FloatTensor<Self>,
        levels: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        id_hash: u32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

fn encode_meta(
    table: &TensorSpec,
    points: &TensorSpec,
    levels: &TensorSpec,
    _id_hash: &u32,
) -> TensorSpec {
    let width = levels.shape[0] / LEVEL_PARAMS * table.shape[1];
    TensorSpec::new([points.shape[0], width].into(), table.dtype)
}

/// Points, levels and features a level of an encoding's operands.
fn dims(points: &CubeTensor, levels: &CubeTensor, table: &CubeTensor) -> (usize, usize, usize) {
    let n = points.meta.shape()[0];
    let n_levels = levels.meta.shape()[0] / LEVEL_PARAMS;
    (n, n_levels, table.meta.shape()[1])
}

impl HashEncodeOps for CubeBackend {
    fn hash_encode(
        table: CubeTensor,
        points: CubeTensor,
        levels: CubeTensor,
        id_hash: u32,
    ) -> CubeTensor {
        let (table, points, levels) = (
            into_contiguous(table),
            into_contiguous(points),
            into_contiguous(levels),
        );
        let (n, n_levels, f) = dims(&points, &levels, &table);
        let out = empty_device_dtype(
            points.client.clone(),
            points.device.clone(),
            [n, n_levels * f].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&points.client, (n * n_levels).max(1));
        encode_kernel::launch(
            &out.client.clone(),
            count,
            dim,
            points.into_tensor_arg(),
            table.into_tensor_arg(),
            levels.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            id_hash,
            n_levels,
            f,
        );
        out
    }

    fn hash_encode_backward(
        table: CubeTensor,
        points: CubeTensor,
        levels: CubeTensor,
        grad: CubeTensor,
        id_hash: u32,
    ) -> (CubeTensor, CubeTensor) {
        let (table, points, levels, grad) = (
            into_contiguous(table),
            into_contiguous(points),
            into_contiguous(levels),
            into_contiguous(grad),
        );
        let (n, n_levels, f) = dims(&points, &levels, &table);
        let client = points.client.clone();
        let table_grad = zeros_client(
            client.clone(),
            points.device.clone(),
            table.meta.shape().clone(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, (n * n_levels).max(1));
        table_grad_kernel::launch(
            &client,
            count,
            dim,
            points.clone().into_tensor_arg(),
            grad.clone().into_tensor_arg(),
            levels.clone().into_tensor_arg(),
            table_grad.clone().into_tensor_arg(),
            id_hash,
            n_levels,
            f,
        );
        let point_grad = empty_device_dtype(
            client.clone(),
            points.device.clone(),
            [n, 3].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, n.max(1));
        point_grad_kernel::launch(
            &client,
            count,
            dim,
            points.into_tensor_arg(),
            table.into_tensor_arg(),
            grad.into_tensor_arg(),
            levels.into_tensor_arg(),
            point_grad.clone().into_tensor_arg(),
            id_hash,
            n_levels,
            f,
        );
        (table_grad, point_grad)
    }
}

#[derive(Debug)]
struct HashEncodeBackward;

impl<B: HashEncodeOps> Backward<B, 2> for HashEncodeBackward {
    /// The table, the points, the levels and the identity's hash.
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, u32);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [table_node, point_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (table, points, levels, id_hash) = ops.state;
        let (table_grad, point_grad) =
            B::hash_encode_backward(table, points, levels, grad, id_hash);
        if let Some(node) = table_node {
            grads.register::<B>(node.id, table_grad);
        }
        if let Some(node) = point_node {
            grads.register::<B>(node.id, point_grad);
        }
    }
}

impl<B: HashEncodeOps, C: CheckpointStrategy> HashEncodeOps for Autodiff<B, C> {
    fn hash_encode(
        table: FloatTensor<Self>,
        points: FloatTensor<Self>,
        levels: FloatTensor<Self>,
        id_hash: u32,
    ) -> FloatTensor<Self> {
        let (table, table_node) = table.into_parts();
        let (points, point_node) = points.into_parts();
        let levels = levels.into_primitive();
        match HashEncodeBackward
            .prepare::<C>([table_node, point_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::hash_encode(table.clone(), points.clone(), levels.clone(), id_hash);
                prep.finish((table, points, levels, id_hash), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::hash_encode(table, points, levels, id_hash)),
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn hash_encode_backward(
        table: FloatTensor<Self>,
        points: FloatTensor<Self>,
        levels: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        id_hash: u32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (table_grad, point_grad) = B::hash_encode_backward(
            table.into_primitive(),
            points.into_primitive(),
            levels.into_primitive(),
            grad.into_primitive(),
            id_hash,
        );
        (Self::from_inner(table_grad), Self::from_inner(point_grad))
    }
}

/// The encoding of `unit_points` `[n, 3]` (`n > 0`, in the unit cube) with `table`
/// `[rows, F]`: `levels` holds each level's numbers (see `hash_kernels`), `id_hash` the
/// identity's hash. Only for tensors on a CubeCL device.
pub(crate) fn encode(
    table: Tensor<2>,
    unit_points: Tensor<2>,
    levels: &[f32],
    id_hash: u32,
) -> Tensor<2> {
    let device = unit_points.device();
    let levels = Tensor::<1>::from_data(TensorData::new(levels.to_vec(), [levels.len()]), &device);
    Tensor::from_dispatch(Dispatch::hash_encode(
        table.into_dispatch(),
        unit_points.into_dispatch(),
        levels.into_dispatch(),
        id_hash,
    ))
}
