//! The frequency encoding (D_nr's and D_hands' input) as one device op with its own
//! backward. Composed of burn ops it was a product by the frequencies, a sine, a cosine,
//! the window's products and a concatenation forward, and the concatenation's cuts, the
//! sine's and cosine's derivatives, products and a sum over the bands back; here one
//! launch each way, and backward reads the saved output instead of evaluating any
//! trigonometry (as the CPU's fused op does, `kernels::frequency`).

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

use super::frequency_kernels::{frequency_backward_kernel, frequency_kernel};
use super::launch_shape;
use crate::util::floats;

/// The frequency encoding and its gradient on a backend.
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"), Autodiff)]
pub trait FrequencyOps: Backend {
    /// `[n, d (1 + 2 L)]` rows `[x, w_k sin(2^k x), w_k cos(2^k x)]` (bands major) of `x`
    /// `[n, d]` with band weights `window` `[L]`.
    #[fusion(meta = encode_meta)]
    fn frequency_encode(x: FloatTensor<Self>, window: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The input's gradient `[n, d]` for the output's `grad`, from the forward output
    /// `out` (`x` gives the shape).
    #[fusion(meta = |x, _out, _grad| x.clone())]
    fn frequency_encode_backward(
        x: FloatTensor<Self>,
        out: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

fn encode_meta(x: &TensorSpec, window: &TensorSpec) -> TensorSpec {
    let [n, d] = [x.shape[0], x.shape[1]];
    TensorSpec::new([n, d * (1 + 2 * window.shape[0])].into(), x.dtype)
}

impl FrequencyOps for CubeBackend {
    fn frequency_encode(x: CubeTensor, window: CubeTensor) -> CubeTensor {
        let [x, window] = [x, window].map(into_contiguous);
        let (n, d) = (x.meta.shape()[0], x.meta.shape()[1]);
        let width = d * (1 + 2 * window.meta.shape()[0]);
        let client = x.client.clone();
        let out = empty_device_dtype(
            client.clone(),
            x.device.clone(),
            [n, width].into(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, (n * d).max(1));
        frequency_kernel::launch(
            &client,
            count,
            dim,
            x.into_tensor_arg(),
            window.into_tensor_arg(),
            out.clone().into_tensor_arg(),
        );
        out
    }

    fn frequency_encode_backward(x: CubeTensor, out: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let [out, grad] = [out, grad].map(into_contiguous);
        let client = grad.client.clone();
        let shape = x.meta.shape().clone();
        let grad_x = empty_device_dtype(
            client.clone(),
            grad.device.clone(),
            shape.clone(),
            DType::F32,
        );
        let (count, dim) = launch_shape(&client, shape.num_elements().max(1));
        frequency_backward_kernel::launch(
            &client,
            count,
            dim,
            grad.into_tensor_arg(),
            out.into_tensor_arg(),
            grad_x.clone().into_tensor_arg(),
        );
        grad_x
    }
}

#[derive(Debug)]
struct FrequencyBackward;

impl<B: FrequencyOps> Backward<B, 1> for FrequencyBackward {
    /// The input (for its shape) and the forward output.
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let Some(node) = x_node else { return };
        let (x, out) = ops.state;
        grads.register::<B>(node.id, B::frequency_encode_backward(x, out, grad));
    }
}

impl<B: FrequencyOps, C: CheckpointStrategy> FrequencyOps for Autodiff<B, C> {
    fn frequency_encode(x: FloatTensor<Self>, window: FloatTensor<Self>) -> FloatTensor<Self> {
        let (x, x_node) = x.into_parts();
        let window = window.into_primitive();
        match FrequencyBackward
            .prepare::<C>([x_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let out = B::frequency_encode(x.clone(), window);
                prep.finish((x, out.clone()), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::frequency_encode(x, window)),
        }
    }

    /// The gradient as a constant (it is not differentiated again).
    fn frequency_encode_backward(
        x: FloatTensor<Self>,
        out: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::frequency_encode_backward(
            x.into_primitive(),
            out.into_primitive(),
            grad.into_primitive(),
        ))
    }
}

/// The encoding `[n, d (1 + 2 L)]` of `x` `[n, d]` with band weights `window` (`L` of
/// them; see [`FrequencyOps::frequency_encode`]). Only for tensors on a CubeCL device.
pub(crate) fn encode(x: Tensor<2>, window: &[f32]) -> Tensor<2> {
    let window = floats(window.to_vec(), [window.len()], &x.device());
    Tensor::from_dispatch(Dispatch::frequency_encode(
        x.into_dispatch(),
        window.into_dispatch(),
    ))
}
