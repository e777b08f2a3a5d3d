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

/// The weights of the pixel loss's terms (see [`pixel_loss`]).
#[derive(Clone, Copy, Debug)]
pub struct PixelWeights {
    /// Of the colour's MSE over the background.
    pub mse: f32,
    /// Of the labels' cross-entropy.
    pub seg: f32,
}

/// The pixel loss of a batch and its parts (see [`pixel_loss`]).
#[derive(Clone, Debug)]
pub struct PixelLoss {
    /// The weighted sum of the terms. `[1]`
    pub loss: Tensor<1>,
    /// The colour's MSE over the background, for the log. `[1]`
    pub mse: Tensor<1>,
    /// The colour over the background `[r, 3]` where the terms were composed from it
    /// (`None` from the device op, which never forms it).
    pub rgb: Option<Tensor<2>>,
}

/// What the pixel loss scores (see [`pixel_loss`]).
///
/// # Shapes
/// - `target`: `[r, 3]`, `labels`: `[r]`, a silhouette's `sure`: `[r]`
#[derive(Clone, Copy)]
pub struct PixelInputs<'a> {
    pub rendered: &'a crate::volume::RenderedRays,
    pub background: [f32; 3],
    pub target: &'a Tensor<2>,
    pub labels: &'a Tensor<1, Int>,
    /// `Some((sure, weight))`: the silhouette term, weighted per ray by `sure`.
    pub silhouette: Option<(&'a Tensor<1>, f32)>,
    pub weights: PixelWeights,
}

/// The weighted pixel loss: `weights.mse` times the MSE of the colour over the
/// background against `target`, plus `weights.seg` times the labels' cross-entropy, plus,
/// with `silhouette = Some((sure, weight))`, `weight` times `MSE(opacity * sure,
/// person * sure)` (`person` 1 where the label is not the background). One device op on
/// a CubeCL device (`kernels::cube::pixel_loss`), tensor ops elsewhere.
pub fn pixel_loss(inputs: PixelInputs) -> PixelLoss {
    match pixel_loss_on_device(inputs) {
        Some((loss, mse)) => PixelLoss {
            loss,
            mse,
            rgb: None,
        },
        None => pixel_loss_composed(inputs),
    }
}

/// [`pixel_loss`] as tensor ops (the CPU's, and the device op's reference).
fn pixel_loss_composed(inputs: PixelInputs) -> PixelLoss {
    let PixelInputs {
        rendered,
        background,
        target,
        labels,
        silhouette,
        weights,
    } = inputs;
    let rgb = rendered.rgb_over(background); // [r, 3]
    let l_mse = mse(rgb.clone(), target.clone());
    let l_seg = seg_cross_entropy(rendered.seg_logits.clone(), labels.clone());
    let mut loss = l_seg.mul_scalar(weights.seg) + l_mse.clone().mul_scalar(weights.mse);
    if let Some((sure, weight)) = silhouette {
        // Label 0 is the background; every other label is the person.
        let person = labels.clone().greater_elem(0).float();
        let l_mask = mse(
            rendered.opacity.clone() * sure.clone(),
            person * sure.clone(),
        );
        loss = loss + l_mask.mul_scalar(weight);
    }
    PixelLoss {
        loss,
        mse: l_mse,
        rgb: Some(rgb),
    }
}

/// On a CubeCL device, [`pixel_loss`]'s loss `[1]` from one device op over the rays and
/// their sum, and the MSE alone `[1]`, detached, for the log. `None` elsewhere and for no
/// rays (then [`pixel_loss`] composes the same terms as tensor ops).
fn pixel_loss_on_device(inputs: PixelInputs) -> Option<(Tensor<1>, Tensor<1>)> {
    #[cfg(feature = "wgpu")]
    {
        let PixelInputs {
            rendered, weights, ..
        } = inputs;
        let device = rendered.opacity.device();
        let rays = rendered.opacity.dims()[0];
        if rays == 0 || crate::device::is_cpu(&device) {
            return None;
        }
        use crate::util::floats;
        // Without the term its weights are zeros, and so is its every ray's value.
        let (sure, mask_weight) = match inputs.silhouette {
            Some((sure, weight)) => (sure.clone(), weight),
            None => (Tensor::zeros([rays], &device), 0.0),
        };
        let terms = crate::kernels::cube::pixel_loss::pixel_terms(
            rendered.rgb.clone(),
            rendered.opacity.clone(),
            rendered.seg_logits.clone(),
            inputs.target.clone(),
            inputs.labels.clone(),
            sure,
            floats(inputs.background.to_vec(), [3], &device),
        ); // [r, 3]
        let r = rays as f32;
        let scale = floats(
            vec![weights.mse / (3.0 * r), weights.seg / r, mask_weight / r],
            [1, 3],
            &device,
        );
        let sums = terms.sum_dim(0); // [1, 3]
        let mse = sums
            .clone()
            .detach()
            .narrow(1, 0, 1)
            .reshape([1])
            .div_scalar(3.0 * r);
        Some(((sums * scale).sum(), mse))
    }
    #[cfg(not(feature = "wgpu"))]
    {
        let _ = inputs;
        None
    }
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
    /// The device op's pixel loss (`kernels::cube::pixel_loss`) against the CPU's
    /// composition of the same terms, both on the device: labels of the background and
    /// the person, silhouette weights of 0, 1/2 and 1, opacities of 0 and 1, logits of
    /// 1e4; the loss, its MSE and the colour's, opacity's and logits' gradients.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_pixel_loss_matches_the_composed_ops() {
        use crate::util::{floats, host};
        use crate::volume::RenderedRays;
        let device = crate::device::test_wgpu().autodiff();
        let r = 23;
        let wave = |i: usize, k: f32| (i as f32 * k).sin() * 0.5 + 0.5;
        let rgb: Vec<f32> = (0..r * 3).map(|i| wave(i, 0.7)).collect();
        let target: Vec<f32> = (0..r * 3).map(|i| wave(i, 1.3)).collect();
        let mut opacity: Vec<f32> = (0..r).map(|i| wave(i, 2.1)).collect();
        opacity[3] = 0.0;
        opacity[4] = 1.0;
        let mut seg: Vec<f32> = (0..r * 5).map(|i| (wave(i, 0.9) - 0.5) * 8.0).collect();
        seg[5 * 6 + 2] = 1e4;
        let labels: Vec<i64> = (0..r).map(|i| (i % 5) as i64).collect();
        let sure: Vec<f32> = (0..r).map(|i| [0.0, 0.5, 1.0][i % 3]).collect();
        let background = [0.2, 0.5, 0.9];
        let weights = PixelWeights {
            mse: 0.2,
            seg: 0.05,
        };
        let mask_weight = 0.3;
        let run = |device_op: bool| {
            let rendered = RenderedRays {
                rgb: floats(rgb.clone(), [r, 3], &device).require_grad(),
                seg_logits: floats(seg.clone(), [r, 5], &device).require_grad(),
                opacity: floats(opacity.clone(), [r], &device).require_grad(),
                depth: Tensor::zeros([r], &device),
            };
            let target = floats(target.clone(), [r, 3], &device);
            let labels = Tensor::<1, Int>::from_data(TensorData::new(labels.clone(), [r]), &device);
            let sure = floats(sure.clone(), [r], &device);
            let inputs = PixelInputs {
                rendered: &rendered,
                background,
                target: &target,
                labels: &labels,
                silhouette: Some((&sure, mask_weight)),
                weights,
            };
            let (loss, l_mse) = if device_op {
                pixel_loss_on_device(inputs).expect("a CubeCL device takes it")
            } else {
                let composed = pixel_loss_composed(inputs);
                (composed.loss, composed.mse)
            };
            let grads = loss.backward();
            [
                host(&loss),
                host(&l_mse),
                host(&rendered.rgb.grad(&grads).unwrap()),
                host(&rendered.opacity.grad(&grads).unwrap()),
                host(&rendered.seg_logits.grad(&grads).unwrap()),
            ]
        };
        let (dev, composed) = (run(true), run(false));
        let names = [
            "loss",
            "mse",
            "colour gradient",
            "opacity gradient",
            "logits gradient",
        ];
        for (what, (a, b)) in names.into_iter().zip(dev.iter().zip(&composed)) {
            crate::util::assert_close_to(what, a, b, 1e-5);
        }
    }
}
