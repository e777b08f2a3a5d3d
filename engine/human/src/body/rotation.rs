//! Axis-angle <-> rotation matrix (Rodrigues and its inverse), exact near 0 and near pi.
//!
//! Computed in f64. Near 0 the sin/cos ratios use Taylor series; near pi the axis comes
//! from the symmetric part of R (the antisymmetric part vanishes there), and the angle from
//! `atan2`, which stays accurate at both ends where `acos` does not.

use glam::{DMat3, DVec3};

/// Below this angle the ratios sin(t)/t and (1-cos t)/t^2 use their Taylor series.
const SMALL_ANGLE: f64 = 1e-4;

/// Rotation matrix of an axis-angle vector (direction = axis, length = angle in radians).
pub fn rotation_from_axis_angle(r: DVec3) -> DMat3 {
    let t2 = r.length_squared();
    let t = t2.sqrt();
    // a = sin(t)/t, b = (1 - cos t)/t^2
    let (a, b) = if t < SMALL_ANGLE {
        (
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
        )
    } else {
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = skew(r);
    DMat3::IDENTITY + k * a + (k * k) * b
}

/// Axis-angle vector of a rotation matrix, with angle in [0, pi]. At exactly pi the sign
/// of the axis is ambiguous (r and -r are the same rotation); either is returned.
pub fn axis_angle_from_rotation(m: DMat3) -> DVec3 {
    let cos_t = ((m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0) * 0.5).clamp(-1.0, 1.0);
    // w = sin(t) * axis, from the antisymmetric part.
    let w = 0.5
        * DVec3::new(
            m.y_axis.z - m.z_axis.y,
            m.z_axis.x - m.x_axis.z,
            m.x_axis.y - m.y_axis.x,
        );
    let sin_t = w.length();
    let t = sin_t.atan2(cos_t);
    if cos_t > -0.5 {
        // t < 2pi/3: the antisymmetric part is well conditioned.
        let scale = if t < SMALL_ANGLE {
            1.0 + t * t / 6.0
        } else {
            t / sin_t
        };
        return w * scale;
    }
    // Near pi: (R + R^T)/2 - cos(t) I = (1 - cos t) a a^T. Take the best-conditioned column.
    let sym = DMat3::from_cols(
        0.5 * (m.x_axis + m.row(0)),
        0.5 * (m.y_axis + m.row(1)),
        0.5 * (m.z_axis + m.row(2)),
    ) - DMat3::IDENTITY * cos_t;
    let diag = DVec3::new(sym.x_axis.x, sym.y_axis.y, sym.z_axis.z);
    let col = if diag.x >= diag.y && diag.x >= diag.z {
        sym.x_axis
    } else if diag.y >= diag.z {
        sym.y_axis
    } else {
        sym.z_axis
    };
    let mut axis = col.normalize_or_zero();
    if axis == DVec3::ZERO {
        return DVec3::ZERO;
    }
    if axis.dot(w) < 0.0 {
        axis = -axis;
    }
    axis * t
}

/// The cross-product matrix: `skew(a) * b == a.cross(b)`.
pub fn skew(a: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, a.z, -a.y),
        DVec3::new(-a.z, 0.0, a.x),
        DVec3::new(a.y, -a.x, 0.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    /// Independent formulation: through a unit quaternion.
    fn reference_rotation(r: DVec3) -> DMat3 {
        let t = r.length();
        if t == 0.0 {
            return DMat3::IDENTITY;
        }
        DMat3::from_quat(DQuat::from_axis_angle(r / t, t))
    }

    fn max_abs_diff(a: DMat3, b: DMat3) -> f64 {
        (a - b)
            .to_cols_array()
            .iter()
            .fold(0.0, |m, x| m.max(x.abs()))
    }

    /// Rotation distance that does not care about the r / -r ambiguity at pi.
    fn assert_same_rotation(r: DVec3, back: DVec3, tol: f64) {
        let d = max_abs_diff(rotation_from_axis_angle(r), rotation_from_axis_angle(back));
        assert!(d < tol, "r={r:?} back={back:?} diff={d}");
    }

    fn hard_vectors() -> Vec<DVec3> {
        let axes = [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, 2.0, -3.0).normalize(),
            DVec3::new(-0.3, 0.1, 0.9).normalize(),
        ];
        let angles = [
            0.0,
            1e-12,
            1e-8,
            1e-5,
            0.5,
            2.0,
            std::f64::consts::PI - 1e-4,
            std::f64::consts::PI - 1e-7,
            std::f64::consts::PI,
        ];
        let mut v = Vec::new();
        for a in axes {
            for t in angles {
                v.push(a * t);
            }
        }
        v
    }

    #[test]
    fn rodrigues_matches_quaternion_formulation() {
        for r in hard_vectors() {
            let d = max_abs_diff(rotation_from_axis_angle(r), reference_rotation(r));
            assert!(d < 1e-14, "r={r:?} diff={d}");
        }
    }

    #[test]
    fn rodrigues_is_a_rotation() {
        for r in hard_vectors() {
            let m = rotation_from_axis_angle(r);
            assert!(max_abs_diff(m * m.transpose(), DMat3::IDENTITY) < 1e-14);
            assert!((m.determinant() - 1.0).abs() < 1e-14);
        }
    }

    #[test]
    fn inverse_round_trips_near_zero_and_pi() {
        for r in hard_vectors() {
            let back = axis_angle_from_rotation(rotation_from_axis_angle(r));
            assert_same_rotation(r, back, 1e-12);
            // Below pi the vector itself comes back, not just the rotation.
            if r.length() < std::f64::consts::PI - 1e-3 {
                assert!(
                    (back - r).length() < 1e-12 * (1.0 + r.length()),
                    "{r:?} -> {back:?}"
                );
            }
            // Near (not at) pi the angle is resolved to ~1e-8 relative to what acos could.
            assert!(
                (back.length() - r.length()).abs() < 1e-9,
                "{r:?} -> {back:?}"
            );
        }
    }

    #[test]
    fn inverse_tiny_angle_keeps_precision() {
        let r = DVec3::new(1e-8, -2e-8, 3e-9);
        let back = axis_angle_from_rotation(rotation_from_axis_angle(r));
        assert!((back - r).length() < 1e-20, "{back:?}");
    }

    #[test]
    fn random_rotations_agree_with_glam() {
        // Seeded LCG: the same vectors every run.
        let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..1000 {
            let r = DVec3::new(next(), next(), next()) * 3.0;
            let m = rotation_from_axis_angle(r);
            assert!(max_abs_diff(m, reference_rotation(r)) < 1e-13);
            let (axis, angle) = DQuat::from_mat3(&m).to_axis_angle();
            assert_same_rotation(axis * angle, axis_angle_from_rotation(m), 1e-10);
        }
    }
}
