//! Adam's device kernel: one unit per element of a parameter, never a loop over it.

use cubecl::prelude::*;

/// `m = m b1 + g (1 - b1)`, `v = v b2 + g^2 (1 - b2)`, `p -= (m c) / (sqrt(v) + eps) lr`,
/// one unit per element.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn adam_kernel(
    param: &Tensor<f32>,
    grad: &Tensor<f32>,
    moment_1: &Tensor<f32>,
    moment_2: &Tensor<f32>,
    param_out: &mut Tensor<f32>,
    moment_1_out: &mut Tensor<f32>,
    moment_2_out: &mut Tensor<f32>,
    beta_1: f32,
    beta_2: f32,
    combined: f32,
    epsilon: f32,
    lr: f32,
) {
    let i = ABSOLUTE_POS;
    if i >= param.len() {
        terminate!();
    }
    let g = grad[i];
    let m = moment_1[i] * beta_1 + g * (1.0 - beta_1);
    let v = moment_2[i] * beta_2 + g * g * (1.0 - beta_2);
    let step = (m * combined) / (f32::sqrt(v) + epsilon);
    moment_1_out[i] = m;
    moment_2_out[i] = v;
    param_out[i] = param[i] - step * lr;
}
