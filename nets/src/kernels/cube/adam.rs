//! Adam as one elementwise device kernel per parameter tensor: the parameter, both
//! moments and the gradient read once, the three written once, in burn's f32 operation
//! order (`kernels::adam` on the CPU). burn's Adam is a dozen tensor ops a parameter,
//! each with an intermediate tensor for fusion to join or not.

use super::adam_kernels::adam_kernel;
use super::launch_shape;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;

/// One Adam step on a backend (not differentiated).
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait AdamOps: Backend {
    /// The parameter and both moments after a step with `grad`; `combined` and
    /// `epsilon` are burn's bias-corrected factors (see `kernels::adam`).
    #[allow(clippy::too_many_arguments)]
    #[fusion(meta = |param, _g, _m, _v, _b1, _b2, _c, _e, _lr| (param.clone(), param.clone(), param.clone()))]
    fn adam_step(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        beta_1: f32,
        beta_2: f32,
        combined: f32,
        epsilon: f32,
        lr: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

impl AdamOps for CubeBackend {
    fn adam_step(
        param: CubeTensor,
        grad: CubeTensor,
        moment_1: CubeTensor,
        moment_2: CubeTensor,
        beta_1: f32,
        beta_2: f32,
        combined: f32,
        epsilon: f32,
        lr: f32,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let [param, grad, moment_1, moment_2] =
            [param, grad, moment_1, moment_2].map(into_contiguous);
        let client = param.client.clone();
        let shape = param.meta.shape().clone();
        let out = || {
            empty_device_dtype(
                client.clone(),
                param.device.clone(),
                shape.clone(),
                DType::F32,
            )
        };
        let (param_out, moment_1_out, moment_2_out) = (out(), out(), out());
        let (count, dim) = launch_shape(&client, shape.num_elements().max(1));
        adam_kernel::launch(
            &client,
            count,
            dim,
            param.into_tensor_arg(),
            grad.into_tensor_arg(),
            moment_1.into_tensor_arg(),
            moment_2.into_tensor_arg(),
            param_out.clone().into_tensor_arg(),
            moment_1_out.clone().into_tensor_arg(),
            moment_2_out.clone().into_tensor_arg(),
            beta_1,
            beta_2,
            combined,
            epsilon,
            lr,
        );
        (param_out, moment_1_out, moment_2_out)
    }
}

/// One Adam step of a parameter on a CubeCL device: the parameter and both moments.
pub(crate) fn step<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moment_1: Tensor<D>,
    moment_2: Tensor<D>,
    factors: [f32; 5],
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let [beta_1, beta_2, combined, epsilon, lr] = factors;
    let (p, m, v) = Dispatch::adam_step(
        param.into_dispatch(),
        grad.into_dispatch(),
        moment_1.into_dispatch(),
        moment_2.into_dispatch(),
        beta_1,
        beta_2,
        combined,
        epsilon,
        lr,
    );
    (
        Tensor::from_dispatch(p),
        Tensor::from_dispatch(m),
        Tensor::from_dispatch(v),
    )
}
