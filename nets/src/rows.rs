//! Row gathers and row sums that stay parallel on every backend.
//!
//! burn differentiates `select` into `select_assign`, and burn-cubecl runs `select_assign`
//! with one GPU thread per column, each looping over every index in order: a `[n]` sum
//! gets one thread for the whole batch, a hash table's `[rows, 2]` gradient two. burn
//! differentiates `gather` into `scatter` with `Add`, which burn-cubecl runs with one
//! thread per value and an atomic add (on adapters that add f32 atomically: Vulkan's
//! `shaderBufferFloat32AtomicAdd`, which NVIDIA's driver and lavapipe have). So off the
//! CPU, rows are read with `gather` over an index repeated across the columns, and summed
//! into rows with `scatter`. On the CPU (Flex) `select` and `select_assign` stay: they are
//! parallel there, and the CPU keeps its bits. The price on a GPU: sums of many values into
//! one row land in no fixed order, so their last bits vary between runs.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::device::is_cpu;

/// `rows` (`[n]`) repeated across the columns of a `[n, ..]` tensor of shape `shape`.
fn index_like<const D: usize>(rows: Tensor<1, Int>, shape: [usize; D]) -> Tensor<D, Int> {
    let n = shape[0];
    let columns: usize = shape[1..].iter().product();
    let repeated = if columns == 1 {
        rows.reshape([n, 1])
    } else {
        rows.reshape([n, 1]).repeat_dim(1, columns)
    };
    repeated.reshape(shape)
}

/// Rows `rows` of `table`: `[R, ..]` -> `[n, ..]` (like `table.select(0, rows)`).
pub(crate) fn gather_rows<const D: usize>(table: Tensor<D>, rows: Tensor<1, Int>) -> Tensor<D> {
    if is_cpu(&table.device()) {
        return table.select(0, rows);
    }
    let mut shape = table.dims();
    shape[0] = rows.dims()[0];
    if shape[0] == 0 {
        return Tensor::zeros(shape, &table.device());
    }
    table.gather(0, index_like(rows, shape))
}

/// `target` (`[R, ..]`) with row `k` of `values` (`[n, ..]`) added to row `rows[k]`;
/// repeated rows add up (like `target.select_assign(0, rows, values, Add)`).
pub(crate) fn add_rows<const D: usize>(
    target: Tensor<D>,
    rows: Tensor<1, Int>,
    values: Tensor<D>,
) -> Tensor<D> {
    if is_cpu(&target.device()) {
        return target.select_assign(0, rows, values, IndexingUpdateOp::Add);
    }
    let shape = values.dims();
    if shape[0] == 0 {
        return target;
    }
    target.scatter(0, index_like(rows, shape), values, IndexingUpdateOp::Add)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scatter and gather forms, forced on the CPU, give the values and gradients of
    /// `select`/`select_assign` (what a GPU runs is the same ops on another backend).
    #[test]
    fn gather_and_scatter_forms_match_select() {
        let device = Device::flex().autodiff();
        let table: Vec<f32> = (0..5 * 3).map(|k| k as f32 * 0.25 - 1.0).collect();
        let table = Tensor::<2>::from_data(TensorData::new(table, [5, 3]), &device).require_grad();
        let rows = Tensor::<1, Int>::from_ints([4, 0, 4, 2, 4, 1], &device);
        let picked = table.clone().select(0, rows.clone());
        let gathered = table.clone().gather(0, index_like(rows.clone(), [6, 3]));
        assert_eq!(
            picked.clone().try_to_vec_as::<f32>().unwrap(),
            gathered.clone().try_to_vec_as::<f32>().unwrap()
        );
        let weights = Tensor::<2>::from_data(
            TensorData::new((0..18).map(|k| (k as f32).sin()).collect(), [6, 3]),
            &device,
        );
        let g_select = table
            .grad(&(picked * weights.clone()).sum().backward())
            .unwrap();
        let g_gather = table
            .grad(&(gathered * weights.clone()).sum().backward())
            .unwrap();
        let close = |a: Vec<f32>, b: Vec<f32>| {
            assert_eq!(a.len(), b.len());
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-6 * (1.0 + x.abs()), "{a:?} vs {b:?}");
            }
        };
        close(
            g_select.try_to_vec_as::<f32>().unwrap(),
            g_gather.try_to_vec_as::<f32>().unwrap(),
        );
        let zeros = Tensor::<2>::zeros([5, 3], &device);
        let summed_select =
            zeros
                .clone()
                .select_assign(0, rows.clone(), weights.clone(), IndexingUpdateOp::Add);
        let summed_scatter =
            zeros.scatter(0, index_like(rows, [6, 3]), weights, IndexingUpdateOp::Add);
        close(
            summed_select.try_to_vec_as::<f32>().unwrap(),
            summed_scatter.try_to_vec_as::<f32>().unwrap(),
        );
    }

    /// One-dimensional rows, and no rows at all.
    #[test]
    fn one_dimension_and_empty_index() {
        let device = Device::flex();
        let t = Tensor::<1>::from_floats([1.0, 2.0, 3.0], &device);
        let rows = Tensor::<1, Int>::from_ints([2, 2, 0], &device);
        assert_eq!(
            t.clone()
                .gather(0, index_like(rows.clone(), [3]))
                .try_to_vec_as::<f32>()
                .unwrap(),
            vec![3.0, 3.0, 1.0]
        );
        let empty = Tensor::<1, Int>::from_data(TensorData::new(Vec::<i32>::new(), [0]), &device);
        assert_eq!(gather_rows(t.clone(), empty.clone()).dims(), [0]);
        let values = Tensor::<1>::zeros([0], &device);
        assert_eq!(add_rows(t, empty, values).dims(), [3]);
    }
}
