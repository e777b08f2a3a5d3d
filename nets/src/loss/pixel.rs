use burn::tensor::activation::log_softmax;
use burn::tensor::{Int, Tensor};

/// Mean squared error over all elements.
///
/// # Shapes
/// - `pred`, `target`: any shape, equal
/// - output: `[1]`
pub fn mse<const D: usize>(pred: Tensor<D>, target: Tensor<D>) -> Tensor<1> {
    assert_eq!(pred.dims(), target.dims(), "mse: shapes differ");
    let diff = pred - target;
    (diff.clone() * diff).mean()
}

/// Mean cross-entropy of rendered segmentation logits against integer labels
/// (`-mean_r log softmax(logits_r)[label_r]`), computed with a log-softmax so that large
/// logits stay finite.
///
/// Labels must lie in `0..classes` (TalkinNeRF uses 5 classes); that is the caller's
/// invariant, checked in debug builds.
///
/// # Shapes
/// - `logits`: `[rays, classes]`
/// - `labels`: `[rays]`
/// - output: `[1]`
pub fn seg_cross_entropy(logits: Tensor<2>, labels: Tensor<1, Int>) -> Tensor<1> {
    let [rays, classes] = logits.dims();
    assert_eq!(
        labels.dims(),
        [rays],
        "seg_cross_entropy: labels must be [rays]"
    );
    debug_assert!(
        {
            let l = labels.to_data().convert::<i64>();
            l.as_slice::<i64>()
                .map(|s| s.iter().all(|&v| v >= 0 && (v as usize) < classes))
                .unwrap_or(true)
        },
        "seg_cross_entropy: a label is outside 0..{classes}"
    );
    let log_p = log_softmax(logits, 1); // [rays, classes]
    let picked = log_p.gather(1, labels.reshape([rays, 1])); // [rays, 1]
    picked.mean().neg()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    #[test]
    fn mse_matches_hand_computation() {
        let device = Device::flex();
        let a = Tensor::<2>::from_floats([[1.0, 2.0], [3.0, 4.0]], &device);
        let b = Tensor::<2>::from_floats([[1.0, 0.0], [0.0, 4.5]], &device);
        let got: f32 = mse(a, b).into_scalar();
        let want = (0.0 + 4.0 + 9.0 + 0.25) / 4.0;
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }

    #[test]
    fn cross_entropy_matches_hand_computation() {
        let device = Device::flex();
        let logits = [
            [0.5f64, -1.0, 2.0, 0.0, 0.25],
            [3.0, 1.0, -2.0, 0.5, 0.0],
            [-0.5, -0.5, -0.5, -0.5, 4.0],
        ];
        let labels = [2i64, 4, 0];
        let mut want = 0.0;
        for (row, &l) in logits.iter().zip(&labels) {
            let z: f64 = row.iter().map(|v| v.exp()).sum();
            want -= (row[l as usize].exp() / z).ln();
        }
        want /= 3.0;
        let flat: Vec<f32> = logits.iter().flatten().map(|&v| v as f32).collect();
        let t = Tensor::<2>::from_data(TensorData::new(flat, [3, 5]), &device);
        let y = Tensor::<1, Int>::from_data(TensorData::new(labels.to_vec(), [3]), &device);
        let got: f32 = seg_cross_entropy(t, y).into_scalar();
        assert!((got as f64 - want).abs() < 1e-5, "{got} vs {want}");
    }

    #[test]
    fn cross_entropy_is_finite_for_huge_logits() {
        let device = Device::flex();
        let t = Tensor::<2>::from_floats([[1e4, -1e4, 0.0, 0.0, 0.0]], &device);
        let y = Tensor::<1, Int>::from_data(TensorData::new(vec![1i64], [1]), &device);
        let got: f32 = seg_cross_entropy(t, y).into_scalar();
        assert!((got - 2e4).abs() < 1.0, "{got}");
    }
}
