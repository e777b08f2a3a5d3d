//! talkin-geometry: the one geometric primitive the acceleration structures (`grids`) and
//! the skinning prior (`nets`) both measure, the distance from a point to a segment, so
//! that a capsule's surface is the same place to both.
//!
//! Knows nothing else: plain `f64` arrays in, no vector library, no body, no network.

/// Squared distance from `p` to the segment `a`-`b` (a point where `a == b`), in `f64`:
/// `|(p - a) - t (b - a)|^2` at the clamped closest parameter `t`.
#[inline(always)]
pub fn segment_distance2(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab: [f64; 3] = std::array::from_fn(|i| b[i] - a[i]);
    let ap: [f64; 3] = std::array::from_fn(|i| p[i] - a[i]);
    let len2: f64 = ab.iter().map(|v| v * v).sum();
    let t = if len2 > 0.0 {
        (ap.iter().zip(&ab).map(|(u, v)| u * v).sum::<f64>() / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (0..3).map(|i| (ap[i] - t * ab[i]).powi(2)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beside_beyond_and_on_a_degenerate_segment() {
        let (a, b) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        // Beside the middle, beyond either end, on the segment.
        assert_eq!(segment_distance2([1.0, 3.0, 0.0], a, b), 9.0);
        assert_eq!(segment_distance2([-1.0, 0.0, 0.0], a, b), 1.0);
        assert_eq!(segment_distance2([4.0, 0.0, 2.0], a, b), 8.0);
        assert_eq!(segment_distance2([0.5, 0.0, 0.0], a, b), 0.0);
        // A segment of no length is its point.
        assert_eq!(segment_distance2([0.0, 0.0, 5.0], b, b), 29.0);
        // Far from the origin the clamped parameter stays exact.
        let far = [1e6, 1e6, 1e6];
        let d2 = segment_distance2([1e6, 1e6 + 1.0, 1e6], far, [1e6 + 1.0, 1e6, 1e6]);
        assert!((d2 - 1.0).abs() < 1e-9, "{d2}");
    }
}
