//! Two chunks' gradients summed, in place where both are plain f32 tensors on
//! the CPU backend.
//!
//! burn's `GradientsAccumulator` adds two gradients into a fresh tensor: for the three
//! hash tables, three table-sized passes and allocations a step. Here the first chunk's
//! buffer takes the sum, and blocks where the second chunk's gradient is zero (the rows of
//! a table its samples never touched: most of the face and hand tables) are skipped. The
//! sum is the same f32 addition, so the same bits.

use burn::backend::Flex;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::DType;
use rayon::prelude::*;

/// Elements per parallel task.
const CHUNK: usize = 1 << 16;
/// Elements checked for zero together.
const BLOCK: usize = 64;

/// Whether every value is +0 or -0 (one branch-free pass over the bits).
#[inline]
fn all_zero(values: &[f32]) -> bool {
    values.iter().fold(0u32, |acc, v| acc | (v.to_bits() << 1)) == 0
}

/// `a + b` for every parameter of `module`, reusing `a`'s buffers.
pub fn sum_grads<M: Module>(module: &M, a: GradientsParams, b: GradientsParams) -> GradientsParams {
    let mut visitor = SumInto { sum: a, other: b };
    module.visit(&mut visitor);
    visitor.sum
}

struct SumInto {
    sum: GradientsParams,
    other: GradientsParams,
}

impl ModuleVisitor for SumInto {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let Some(b) = self.other.remove::<D>(param.id) else {
            return;
        };
        let total = match self.sum.remove::<D>(param.id) {
            Some(a) => add_into(a, b),
            None => b,
        };
        self.sum.register::<D>(param.id, total);
    }
}

/// Whether `t` is a plain (not autodiff) f32 tensor on Flex.
fn plain_flex_f32<const D: usize>(t: &Tensor<D>) -> bool {
    t.device() == Device::flex() && !t.is_autodiff() && t.dtype() == DType::F32
}

/// `a + b`, in `a`'s buffer when both are plain f32 Flex tensors of one shape (copied
/// first if another tensor shares it); burn's `add` otherwise.
fn add_into<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> Tensor<D> {
    if !(plain_flex_f32(&a) && plain_flex_f32(&b) && a.shape() == b.shape()) {
        return a.add(b);
    }
    let n = a.shape().num_elements();
    let contiguous = |t: Tensor<D>| {
        let p = t
            .try_into_primitive::<Flex>()
            .expect("checked: an f32 tensor on Flex");
        if p.layout().contiguous_offsets() == Some((0, n)) {
            p
        } else {
            p.to_contiguous()
        }
    };
    let (mut a, b) = (contiguous(a), contiguous(b));
    let b_s = b.as_slice::<f32>().expect("a contiguous f32 gradient");
    a.storage_mut::<f32>()[..n]
        .par_chunks_mut(CHUNK)
        .zip(b_s[..n].par_chunks(CHUNK))
        .for_each(|(a, b)| {
            for (a, b) in a.chunks_mut(BLOCK).zip(b.chunks(BLOCK)) {
                if all_zero(b) {
                    continue;
                }
                for (x, &y) in a.iter_mut().zip(b) {
                    *x += y;
                }
            }
        });
    Tensor::from_primitive::<Flex>(a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    /// The in-place sum equals burn's `add` bit for bit, across blocks of zeros, signed
    /// zeros and chunk boundaries, and leaves a shared first buffer's other holder as it
    /// was.
    #[test]
    fn matches_burns_add_and_respects_shared_buffers() {
        let device = Device::flex();
        let n = CHUNK + 3 * BLOCK + 5;
        let a: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..n)
            .map(|i| match (i / BLOCK) % 3 {
                0 => 0.0,
                1 if i % 2 == 0 => -0.0,
                _ => (i as f32 * 0.11).cos() * 1e-3,
            })
            .collect();
        let t = |v: &Vec<f32>| Tensor::<2>::from_data(TensorData::new(v.clone(), [n, 1]), &device);
        let expected: Vec<f32> = t(&a).add(t(&b)).try_to_vec_as::<f32>().unwrap();
        let shared = t(&a);
        let sum = add_into(shared.clone(), t(&b));
        assert_eq!(sum.try_to_vec_as::<f32>().unwrap(), expected);
        assert_eq!(
            shared.try_to_vec_as::<f32>().unwrap(),
            a,
            "the other holder changed"
        );
    }
}
