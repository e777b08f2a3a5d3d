//! InstantAvatar's hard-surface term on packed samples: `b(x) = -ln(e^-x + e^(x-1))`,
//! offset to 0 at `x = 0` and `x = 1` and largest (0.12) at one half, averaged over every
//! sample's compositing weight and over every ray's opacity. A ray whose weight one
//! sample takes (a surface) or none (empty space) costs nothing; weight shared by many
//! samples (a cloud) costs, and so does a half-opaque ray.

use burn::prelude::*;

use super::RenderWeights;

/// `-b(0)`: `ln(1 + 1/e)`, so that `b(0) + OFFSET = b(1) + OFFSET = 0`.
const OFFSET: f32 = 0.313_261_7;

/// The term's value on `x` in [0, 1] (element-wise).
fn binary<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    (x.clone().neg().exp() + x.sub_scalar(1.0).exp())
        .log()
        .neg()
        .add_scalar(OFFSET)
}

/// The mean of the term over the batch's samples' weights plus its mean over the rays'
/// opacities (InstantAvatar's `reg_density + reg_alpha`). `[1]`; zero for an empty batch.
pub fn hard_surface(weights: &RenderWeights) -> Tensor<1> {
    let w = weights.weights.clone();
    let device = w.device();
    let mut total = Tensor::<1>::zeros([1], &device);
    if w.dims()[0] > 0 {
        total = total + binary(w.clamp(0.0, 1.0)).mean();
    }
    let opacity = weights.opacity();
    if opacity.dims()[0] > 0 {
        total = total + binary(opacity.clamp(0.0, 1.0)).mean();
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::floats;
    use crate::volume::RaySamples;

    fn term(sigma: Vec<f32>, offsets: &[usize], lengths: &[f32]) -> f32 {
        let device = Device::flex();
        let t_start: Vec<f32> = lengths
            .iter()
            .scan(0.0, |t, l| {
                let s = *t;
                *t += l;
                Some(s)
            })
            .collect();
        let t_end: Vec<f32> = t_start.iter().zip(lengths).map(|(s, l)| s + l).collect();
        let samples = RaySamples {
            offsets,
            t_start: &t_start,
            t_end: &t_end,
        };
        let n = sigma.len();
        let weights = RenderWeights::new(floats(sigma, [n], &device), &samples).unwrap();
        hard_surface(&weights).try_to_vec_as::<f32>().unwrap()[0]
    }

    #[test]
    fn a_surface_and_empty_space_cost_nothing_a_cloud_does() {
        // One opaque sample among empty ones: every weight and the opacity 0 or 1.
        let surface = term(vec![0.0, 1e6, 0.0, 0.0], &[0, 4], &[0.01; 4]);
        assert!(surface.abs() < 1e-5, "{surface}");
        let empty = term(vec![0.0; 4], &[0, 4], &[0.01; 4]);
        assert!(empty.abs() < 1e-6, "{empty}");
        // The same opacity spread over four samples.
        let cloud = term(vec![100.0; 4], &[0, 4], &[0.01; 4]);
        assert!(cloud > 0.05, "{cloud}");
        // Half opaque: the opacity's term alone is at its largest.
        let half = term(vec![2f32.ln() / 0.01], &[0, 1], &[0.01]);
        let b_half = 0.5 - 2f32.ln() + OFFSET;
        assert!(
            (half - 2.0 * b_half).abs() < 1e-5,
            "{half} against {}",
            2.0 * b_half
        );
    }

    #[test]
    fn an_empty_batch_costs_nothing() {
        // An empty ray's opacity is 0, where the term is 0 up to the offset's rounding.
        assert!(term(vec![], &[0, 0], &[]).abs() < 1e-6);
    }
}
