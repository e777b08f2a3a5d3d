//! SplitMix64, the workspace's one generator: seeded, no global state, the same numbers
//! on every platform. The samplers seed one stream per (seed, index) pair
//! ([`SplitMix64::for_stream`]) so that results do not depend on thread count or
//! scheduling; training, the synthetic scene and the tests' fixtures run one stream from a
//! seed ([`SplitMix64::new`]).

/// SplitMix64's increment (the golden ratio in 64 bits).
const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// SplitMix64's output function: a good 64-bit mix of a state.
const fn finalise(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// One SplitMix64 step from state `x`: a good 64-bit hash of `x`.
pub const fn mix64(x: u64) -> u64 {
    finalise(x.wrapping_add(GOLDEN))
}

/// Sebastiano Vigna's SplitMix64.
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// The stream that starts from state `seed` (the reference implementation's seeding).
    pub const fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    /// Stream `stream` of `seed`: independent streams for parallel work. Its first draw is
    /// `mix64(mix64(seed ^ mix64(stream)))`: the state starts one step past the hash.
    pub const fn for_stream(seed: u64, stream: u64) -> Self {
        SplitMix64 {
            state: mix64(seed ^ mix64(stream)).wrapping_add(GOLDEN),
        }
    }

    /// The generator's whole state (for checkpoints).
    pub fn state(&self) -> u64 {
        self.state
    }

    /// A generator continuing from a saved [`SplitMix64::state`].
    pub fn from_state(state: u64) -> Self {
        SplitMix64 { state }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN);
        finalise(self.state)
    }

    /// Uniform in `[0, 1)` with 24 bits.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in `[0, 1)` with 53 bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)` with 53 bits.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }

    /// Uniform in `0..n` (`n > 0`) by the remainder; the bias is below 2^-32 for any
    /// n < 2^32.
    pub fn below(&mut self, n: u64) -> u64 {
        debug_assert!(n > 0);
        self.next_u64() % n
    }

    /// Uniform in `0..n` (`n > 0`, n < 2^32) by multiply-shift of the high 32 bits: a
    /// different draw from [`SplitMix64::below`] for the same state, kept where seeded
    /// results were made with it (the occupancy update's cell picks).
    pub fn below_by_shift(&mut self, n: u64) -> u64 {
        ((self.next_u64() >> 32) * n) >> 32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_values() {
        // First outputs of SplitMix64 seeded with 0 (the reference implementation).
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn a_stream_draws_the_hash_of_its_state() {
        let mut a = SplitMix64::for_stream(7, 3);
        let s0 = mix64(7 ^ mix64(3));
        assert_eq!(a.next_u64(), mix64(s0.wrapping_add(GOLDEN)));
        assert_eq!(a.next_u64(), mix64(s0.wrapping_add(GOLDEN.wrapping_mul(2))));
        assert_ne!(
            SplitMix64::for_stream(7, 0).next_u64(),
            SplitMix64::for_stream(7, 1).next_u64()
        );
    }

    #[test]
    fn draws_stay_in_range() {
        let mut r = SplitMix64::new(7);
        let xs: Vec<f32> = (0..1000).map(|_| r.next_f32()).collect();
        assert!(xs.iter().all(|x| (0.0..1.0).contains(x)));
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.05, "mean {mean}");
        for _ in 0..1000 {
            assert!((0.0..1.0).contains(&r.next_f64()));
            assert!((2.0..3.0).contains(&r.uniform(2.0, 3.0)));
            assert!(r.below(5) < 5);
            assert!(r.below_by_shift(10) < 10);
        }
    }
}
