//! Signed distance functions of the mannequin's primitives (Inigo Quilez's exact round
//! cone and capped cone, the usual ellipsoid bound) and the polynomial smooth minimum.
//!
//! All in f32: the scene is a couple of metres across and the tracer stops at 0.3 mm.

use glam::Vec3;

/// One primitive's shape, in the rest (T-pose) space of the joint that carries it.
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// A cone with spherical caps: radius `ra` at `a`, `rb` at `b`.
    RoundCone { a: Vec3, b: Vec3, ra: f32, rb: f32 },
    /// A cone frustum with flat caps (skirts, hems, cuffs).
    CappedCone { a: Vec3, b: Vec3, ra: f32, rb: f32 },
    /// An axis-aligned ellipsoid (axes of the rest space).
    Ellipsoid { c: Vec3, r: Vec3 },
    /// An ellipsoid minus the half-space `dot(p, n) > d` (hair caps, eyelids).
    CutEllipsoid { c: Vec3, r: Vec3, n: Vec3, d: f32 },
}

impl Shape {
    /// Signed distance (a lower bound for the ellipsoids) from `p`, in rest space.
    #[inline]
    pub fn distance(&self, p: Vec3) -> f32 {
        match *self {
            Shape::RoundCone { a, b, ra, rb } => round_cone(p, a, b, ra, rb),
            Shape::CappedCone { a, b, ra, rb } => capped_cone(p, a, b, ra, rb),
            Shape::Ellipsoid { c, r } => ellipsoid(p - c, r),
            Shape::CutEllipsoid { c, r, n, d } => ellipsoid(p - c, r).max(p.dot(n) - d),
        }
    }

    /// A sphere (centre, radius) enclosing the shape, in rest space.
    pub fn bounding_sphere(&self) -> (Vec3, f32) {
        match *self {
            Shape::RoundCone { a, b, ra, rb } => {
                ((a + b) * 0.5, (b - a).length() * 0.5 + ra.max(rb))
            }
            Shape::CappedCone { a, b, ra, rb } => {
                let half = (b - a).length() * 0.5;
                ((a + b) * 0.5, (half * half + ra.max(rb).powi(2)).sqrt())
            }
            Shape::Ellipsoid { c, r } | Shape::CutEllipsoid { c, r, .. } => (c, r.max_element()),
        }
    }
}

/// Polynomial smooth minimum with blend radius `k` (0 = hard union).
#[inline]
pub fn smin(a: f32, b: f32, k: f32) -> f32 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// Exact distance to a round cone with arbitrary end points (needs |ra - rb| < |b - a|).
pub fn round_cone(p: Vec3, a: Vec3, b: Vec3, ra: f32, rb: f32) -> f32 {
    let ba = b - a;
    let l2 = ba.dot(ba);
    let rr = ra - rb;
    let a2 = l2 - rr * rr;
    let il2 = 1.0 / l2;
    let pa = p - a;
    let y = pa.dot(ba);
    let z = y - l2;
    let x2 = (pa * l2 - ba * y).length_squared();
    let y2 = y * y * l2;
    let z2 = z * z * l2;
    let k = rr.signum() * rr * rr * x2;
    if z.signum() * a2 * z2 > k {
        return (x2 + z2).sqrt() * il2 - rb;
    }
    if y.signum() * a2 * y2 < k {
        return (x2 + y2).sqrt() * il2 - ra;
    }
    ((x2 * a2 * il2).sqrt() + y * rr) * il2 - ra
}

/// Exact distance to a capped cone with arbitrary end points.
pub fn capped_cone(p: Vec3, a: Vec3, b: Vec3, ra: f32, rb: f32) -> f32 {
    let rba = rb - ra;
    let baba = (b - a).length_squared();
    let papa = (p - a).length_squared();
    let paba = (p - a).dot(b - a) / baba;
    let x = (papa - paba * paba * baba).max(0.0).sqrt();
    let cax = (x - if paba < 0.5 { ra } else { rb }).max(0.0);
    let cay = (paba - 0.5).abs() - 0.5;
    let k = rba * rba + baba;
    let f = ((rba * (x - ra) + paba * baba) / k).clamp(0.0, 1.0);
    let cbx = x - ra - f * rba;
    let cby = paba - f;
    let s = if cbx < 0.0 && cay < 0.0 { -1.0 } else { 1.0 };
    s * (cax * cax + cay * cay * baba)
        .min(cbx * cbx + cby * cby * baba)
        .sqrt()
}

/// Distance bound to an axis-aligned ellipsoid centred at the origin.
pub fn ellipsoid(p: Vec3, r: Vec3) -> f32 {
    let k0 = (p / r).length();
    let k1 = (p / (r * r)).length();
    if k1 < 1e-12 {
        return -r.min_element();
    }
    k0 * (k0 - 1.0) / k1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_match_closed_forms() {
        // A round cone with equal radii is a capsule.
        let (a, b) = (Vec3::ZERO, Vec3::new(0.0, 1.0, 0.0));
        let d = round_cone(Vec3::new(0.5, 0.5, 0.0), a, b, 0.1, 0.1);
        assert!((d - 0.4).abs() < 1e-5, "{d}");
        let d = round_cone(Vec3::new(0.0, 1.5, 0.0), a, b, 0.2, 0.1);
        assert!((d - 0.4).abs() < 1e-5, "{d}");
        // A capped cone with equal radii is a cylinder.
        let d = capped_cone(Vec3::new(0.0, 1.5, 0.0), a, b, 0.1, 0.1);
        assert!((d - 0.5).abs() < 1e-5, "{d}");
        let d = capped_cone(Vec3::new(0.3, 0.5, 0.0), a, b, 0.1, 0.1);
        assert!((d - 0.2).abs() < 1e-5, "{d}");
        assert!(capped_cone(Vec3::new(0.0, 0.5, 0.0), a, b, 0.1, 0.1) < 0.0);
        // An ellipsoid with equal radii is a sphere.
        let d = ellipsoid(Vec3::new(2.0, 0.0, 0.0), Vec3::splat(0.5));
        assert!((d - 1.5).abs() < 1e-5, "{d}");
        assert_eq!(smin(1.0, 2.0, 0.0), 1.0);
        assert!(smin(1.0, 1.0, 0.2) < 1.0);
    }
}
