//! Host views of Flex tensors for the fused encodings: their kernels read and write plain
//! f32 slices.

use burn::backend::flex::FlexTensor;
use burn::tensor::{DType, TensorData};

/// A contiguous f32 view of a Flex tensor (copied only if strided); `None` for other
/// dtypes.
pub(crate) fn f32_data(t: &FlexTensor) -> Option<std::borrow::Cow<'_, [f32]>> {
    if t.dtype() != DType::F32 {
        return None;
    }
    match t.as_slice::<f32>() {
        Some(s) => Some(std::borrow::Cow::Borrowed(s)),
        None => t
            .to_contiguous()
            .as_slice::<f32>()
            .map(|s| std::borrow::Cow::Owned(s.to_vec())),
    }
}

/// A 2-D Flex tensor owning `values` (row-major).
pub(crate) fn flex_tensor(values: Vec<f32>, shape: [usize; 2]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}
