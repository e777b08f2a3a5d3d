//! Small host <-> tensor helpers. Index lists and constant weights are built on the host
//! (they are piecewise constant in the inputs, so no gradient flows through them) and then
//! uploaded; only the differentiable arithmetic runs as tensor ops.

use burn::prelude::*;

/// A float tensor from a host vector.
pub(crate) fn floats<const D: usize>(
    values: Vec<f32>,
    shape: [usize; D],
    device: &Device,
) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// A 1-D int tensor from host indices. Build big index lists as `i32`, the int dtype of
/// Flex and wgpu, so the upload is a copy and not a conversion.
pub(crate) fn ints<E: burn::tensor::Element>(values: Vec<E>, device: &Device) -> Tensor<1, Int> {
    let n = values.len();
    Tensor::from_data(TensorData::new(values, [n]), device)
}

/// Reads a float tensor back to the host (a sync point on GPU backends).
pub(crate) fn host<const D: usize>(tensor: &Tensor<D>) -> Vec<f32> {
    crate::device::read_floats(tensor.clone()).expect("reading a float tensor back to the host")
}

/// Asserts that `tested` holds `reference`'s values to `tolerance` relative (absolute
/// below 1), every one finite; `what` names them in a failure.
#[cfg(test)]
pub(crate) fn assert_close_to(what: &str, tested: &[f32], reference: &[f32], tolerance: f32) {
    assert_eq!(tested.len(), reference.len(), "{what}: lengths");
    for (i, (u, v)) in tested.iter().zip(reference).enumerate() {
        assert!(
            u.is_finite() && (u - v).abs() <= tolerance * (1.0 + v.abs()),
            "{what}[{i}]: tested {u}, reference {v}"
        );
    }
}

/// Numerically stable softplus, `max(x, 0) + ln(1 + exp(-|x|))`: never overflows, and its
/// gradient (a sigmoid) is exact for large |x|.
pub(crate) fn softplus<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let relu = x.clone().clamp_min(0.0);
    relu + x.abs().neg().exp().log1p()
}
