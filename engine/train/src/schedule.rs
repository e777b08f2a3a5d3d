//! The paper's schedule, scaled to the run: a run of any length is mapped onto the
//! paper's 400k iterations ("virtual steps"), and everything step-indexed (learning-rate
//! decay, the part-aware ray schedule, D_nr's start, the Hann windows) reads the virtual
//! step. A 10-minute run thus passes through every phase the paper's 400k-iteration run
//! does, in the same proportions.

/// The paper's single-identity run length (iterations).
pub const PAPER_ITERATIONS: usize = 400_000;
/// The paper's learning-rate decay: x0.1 every 500k iterations.
pub const LR_DECAY_ITERATIONS: f64 = 500_000.0;

/// The virtual step at run progress `progress` in [0, 1].
pub fn virtual_step(progress: f64) -> usize {
    (progress.clamp(0.0, 1.0) * PAPER_ITERATIONS as f64).round() as usize
}

/// Adam's learning rate at a virtual step: `lr0 * 0.1^(step / 500k)`.
pub fn learning_rate(lr0: f64, virtual_step: usize) -> f64 {
    lr0 * 0.1f64.powf(virtual_step as f64 / LR_DECAY_ITERATIONS)
}

/// Fractions of the in-box rays drawn from hand and arm pixels (supplementary,
/// "Sampling"): 20% hands for the first 20k iterations; 20% hands + 60% arms for the
/// next 20k; 40/40; 80% hands + 20% arms; then 20% hands.
pub fn part_fractions(virtual_step: usize) -> PartFractions {
    let (hands, arms) = match virtual_step {
        s if s < 20_000 => (0.2, 0.0),
        s if s < 40_000 => (0.2, 0.6),
        s if s < 60_000 => (0.4, 0.4),
        s if s < 80_000 => (0.8, 0.2),
        _ => (0.2, 0.0),
    };
    PartFractions { hands, arms }
}

/// See [`part_fractions`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartFractions {
    pub hands: f32,
    pub arms: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_matches_the_paper() {
        assert_eq!(virtual_step(0.0), 0);
        assert_eq!(virtual_step(0.5), 200_000);
        assert_eq!(virtual_step(2.0), PAPER_ITERATIONS);
        assert_eq!(virtual_step(f64::NAN.max(0.0)), 0);
        assert!((learning_rate(5e-4, 500_000) - 5e-5).abs() < 1e-12);
        assert!((learning_rate(5e-4, 0) - 5e-4).abs() < 1e-15);
        let f = |s| {
            let p = part_fractions(s);
            (p.hands, p.arms)
        };
        assert_eq!(f(0), (0.2, 0.0));
        assert_eq!(f(20_000), (0.2, 0.6));
        assert_eq!(f(59_999), (0.4, 0.4));
        assert_eq!(f(60_000), (0.8, 0.2));
        assert_eq!(f(80_000), (0.2, 0.0));
        assert_eq!(f(399_999), (0.2, 0.0));
    }
}
