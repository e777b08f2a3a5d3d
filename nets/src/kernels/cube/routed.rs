//! Routed rows put back into the batch as one device op with its own backward: a part
//! net's rows replace the body's where the segmentation label routes them. Composed of
//! burn ops this was a gather of the body's rows and a masked pick, a fill, an atomic
//! scatter-add, a mask product and a sum forward, and as many back; here one launch each
//! way, and the labels are read where they are (the op reads them, no mask is built).

use burn::backend::AutodiffBackend;
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::cubecl::dtype_to_storage_type;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;

use super::launch_shape;
use super::routed_kernels::{replace_backward_kernel, replace_kernel};

/// The routed replace and its gradient on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait RoutedOps: Backend {
    /// `base` `[n, c]` with sample `i`'s row taken from `values` `[h, c]` (row
    /// `slot[i]`; `h` for none) where `labels[i] == label`; `slot`, `labels` `[n]`.
    #[fusion(meta = |base, _values, _slot, _labels, _label| base.clone())]
    fn routed_replace(
        base: FloatTensor<Self>,
        values: FloatTensor<Self>,
        slot: IntTensor<Self>,
        labels: IntTensor<Self>,
        label: i32,
    ) -> FloatTensor<Self>;

    /// The base's `[n, c]` and the part rows' `[h, c]` gradients for the output's `grad`
    /// (`values` gives the part rows' shape).
    #[fusion(meta = |values, _slot, _labels, grad, _label| (grad.clone(), values.clone()))]
    fn routed_replace_backward(
        values: FloatTensor<Self>,
        slot: IntTensor<Self>,
        labels: IntTensor<Self>,
        grad: FloatTensor<Self>,
        label: i32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

impl RoutedOps for CubeBackend {
    fn routed_replace(
        base: CubeTensor,
        values: CubeTensor,
        slot: CubeTensor,
        labels: CubeTensor,
        label: i32,
    ) -> CubeTensor {
        let [base, values, slot, labels] = [base, values, slot, labels].map(into_contiguous);
        let client = base.client.clone();
        let shape = base.meta.shape().clone();
        let out = empty_device_dtype(client.clone(), base.device.clone(), shape, DType::F32);
        let (count, dim) = launch_shape(&client, base.meta.shape().num_elements().max(1));
        let int = dtype_to_storage_type(slot.dtype);
        replace_kernel::launch(
            &client,
            count,
            dim,
            base.into_tensor_arg(),
            values.into_tensor_arg(),
            slot.into_tensor_arg(),
            labels.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            label,
            int,
        );
        out
    }

    fn routed_replace_backward(
        values: CubeTensor,
        slot: CubeTensor,
        labels: CubeTensor,
        grad: CubeTensor,
        label: i32,
    ) -> (CubeTensor, CubeTensor) {
        let [slot, labels, grad] = [slot, labels, grad].map(into_contiguous);
        let client = grad.client.clone();
        let empty =
            |shape| empty_device_dtype(client.clone(), grad.device.clone(), shape, DType::F32);
        let grad_base = empty(grad.meta.shape().clone());
        let grad_values = empty(values.meta.shape().clone());
        let (count, dim) = launch_shape(&client, grad.meta.shape().num_elements().max(1));
        let int = dtype_to_storage_type(slot.dtype);
        replace_backward_kernel::launch(
            &client,
            count,
            dim,
            grad.into_tensor_arg(),
            slot.into_tensor_arg(),
            labels.into_tensor_arg(),
            grad_base.clone().into_tensor_arg(),
            grad_values.clone().into_tensor_arg(),
            label,
            int,
        );
        (grad_base, grad_values)
    }
}

#[derive(Debug)]
struct RoutedBackward;

impl<B: RoutedOps> Backward<B, 2> for RoutedBackward {
    /// The part rows (for their shape), the slots, the labels and the part's label.
    type State = (FloatTensor<B>, IntTensor<B>, IntTensor<B>, i32);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [base_node, values_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (values, slot, labels, label) = ops.state;
        let (grad_base, grad_values) =
            B::routed_replace_backward(values, slot, labels, grad, label);
        if let Some(node) = base_node {
            grads.register::<B>(node.id, grad_base);
        }
        if let Some(node) = values_node {
            grads.register::<B>(node.id, grad_values);
        }
    }
}

impl<B: RoutedOps, C: CheckpointStrategy> RoutedOps for Autodiff<B, C> {
    fn routed_replace(
        base: FloatTensor<Self>,
        values: FloatTensor<Self>,
        slot: IntTensor<Self>,
        labels: IntTensor<Self>,
        label: i32,
    ) -> FloatTensor<Self> {
        let (base, base_node) = base.into_parts();
        let (values, values_node) = values.into_parts();
        match RoutedBackward
            .prepare::<C>([base_node, values_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out =
                    B::routed_replace(base, values.clone(), slot.clone(), labels.clone(), label);
                prep.finish((values, slot, labels, label), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::routed_replace(base, values, slot, labels, label))
            }
        }
    }

    /// The gradients as constants (they are not differentiated again).
    fn routed_replace_backward(
        values: FloatTensor<Self>,
        slot: IntTensor<Self>,
        labels: IntTensor<Self>,
        grad: FloatTensor<Self>,
        label: i32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (grad_base, grad_values) = B::routed_replace_backward(
            values.into_primitive(),
            slot,
            labels,
            grad.into_primitive(),
            label,
        );
        (Self::from_inner(grad_base), Self::from_inner(grad_values))
    }
}

/// `base` (`[n, ..]`) with sample `i`'s row from `values` (`[h, ..]`, row `slot[i]`, `h`
/// for none) where `labels[i] == label` (`slot`, `labels` `[n]`). Only for tensors on a
/// CubeCL device.
pub(crate) fn replace<const D: usize>(
    base: Tensor<D>,
    values: Tensor<D>,
    slot: Tensor<1, Int>,
    labels: Tensor<1, Int>,
    label: i32,
) -> Tensor<D> {
    let shape = base.dims();
    let (n, h) = (shape[0], values.dims()[0]);
    let columns = shape[1..].iter().product::<usize>();
    let out = Dispatch::routed_replace(
        base.reshape([n, columns]).into_dispatch(),
        values.reshape([h, columns]).into_dispatch(),
        slot.into_dispatch(),
        labels.into_dispatch(),
        label,
    );
    Tensor::<2>::from_dispatch(out).reshape(shape)
}
