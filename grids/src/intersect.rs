//! Exact ray-capsule intersection and point/ray distances to capsules.
//!
//! All arithmetic runs in f64 on coordinates taken relative to the ray's origin, so rays
//! far from the world origin (1e6 m) or tiny scenes (1e-6 m) keep their precision and
//! squares of f32 coordinates cannot overflow. A capsule is the union of a finite
//! cylinder and two end spheres; it is convex, so a line meets it in one interval, which
//! is the union of the three pieces' intervals.

use glam::{DVec3, Vec3};

use crate::{Capsule, GridError, Ray};

/// One capsule crossed by a ray: the ray is inside capsule `capsule` for `t_in..=t_out`
/// (clipped to the ray's `[t_min, t_max]`). `t_in == t_out` for a tangent ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CapsuleHit {
    pub t_in: f32,
    pub t_out: f32,
    /// Index into the capsule slice the query was made with.
    pub capsule: u32,
}

/// Sorts hits by entry, then capsule index, so results do not depend on BVH layout.
pub fn sort_hits(hits: &mut [CapsuleHit]) {
    hits.sort_unstable_by(|x, y| x.t_in.total_cmp(&y.t_in).then(x.capsule.cmp(&y.capsule)));
}

/// Checks that a capsule is finite, has a non-negative radius and a bone below 64.
pub fn validate_capsule(capsule: &Capsule, index: usize) -> Result<(), GridError> {
    for (field, ok) in [
        ("a", capsule.a.is_finite()),
        ("b", capsule.b.is_finite()),
        ("radius", capsule.radius.is_finite()),
    ] {
        if !ok {
            return Err(GridError::NonFiniteCapsule { index, field });
        }
    }
    if capsule.radius < 0.0 {
        return Err(GridError::NegativeRadius {
            index,
            radius: capsule.radius,
        });
    }
    if capsule.bone >= 64 {
        return Err(GridError::BoneOutOfRange {
            index,
            bone: capsule.bone,
        });
    }
    Ok(())
}

/// Validates every capsule of a slice, reporting the first bad one.
pub fn validate_capsules(capsules: &[Capsule]) -> Result<(), GridError> {
    capsules
        .iter()
        .enumerate()
        .try_for_each(|(i, c)| validate_capsule(c, i))
}

/// The closed interval `[t_in, t_out]` of the ray inside the capsule, clipped to
/// `[ray.t_min, ray.t_max]`, or `None` if they do not meet. A ray starting inside the
/// capsule gets `t_in == ray.t_min`; a tangent ray gets `t_in == t_out`.
///
/// Inputs are assumed validated ([`Ray::validate`], [`validate_capsule`]); non-finite
/// values give `None`, never a panic.
pub fn ray_capsule(ray: &Ray, capsule: &Capsule) -> Option<(f32, f32)> {
    CapsuleFromOrigin::new(capsule, ray.origin).hit(
        &DirectionF64::new(ray.direction),
        ray.t_min,
        ray.t_max,
    )
}

/// A capsule seen from one ray origin: the parts of [`ray_capsule`] that do not depend
/// on the direction, in f64, so the many rays that share an origin (a frame's pixel rays
/// share the camera centre) each pay only the rest.
///
/// The infinite cylinder first: a ray that misses it misses the capsule. Where it enters
/// (leaves) the cylinder beyond an end, it enters (leaves) the capsule through that end's
/// sphere, or not at all: to reach the segment's slab from beyond an end while inside the
/// cylinder, it crosses the end's disc, which lies in the sphere. So a ray crossing a
/// limb sideways pays one square root. Each sphere is solved by its closest approach and
/// the discriminant from the perpendicular distance (which avoids the cancellation of
/// the textbook `b^2 - 4ac` for far-away origins).
#[derive(Clone, Copy, Debug)]
pub struct CapsuleFromOrigin {
    /// End centres relative to the origin.
    a: DVec3,
    b: DVec3,
    r2: f64,
    /// Zero for a sphere.
    axis: DVec3,
    inv_l2: f64,
    /// The origin's axial coordinate (segment units) and its offset from the axis.
    s0: f64,
    o_perp: DVec3,
}

/// A ray direction as [`CapsuleFromOrigin::hit`] takes it: `d` with `|d|^2` and its
/// inverse, worked out once per ray.
#[derive(Clone, Copy, Debug)]
pub struct DirectionF64 {
    pub d: DVec3,
    pub dd: f64,
    pub inv_dd: f64,
}

impl DirectionF64 {
    pub fn new(direction: Vec3) -> DirectionF64 {
        let d = direction.as_dvec3();
        let dd = d.length_squared();
        DirectionF64 {
            d,
            dd,
            inv_dd: 1.0 / dd,
        }
    }
}

impl CapsuleFromOrigin {
    pub fn new(capsule: &Capsule, origin: Vec3) -> CapsuleFromOrigin {
        let o = origin.as_dvec3();
        let a = capsule.a.as_dvec3() - o;
        let b = capsule.b.as_dvec3() - o;
        let axis = capsule.b.as_dvec3() - capsule.a.as_dvec3();
        let l2 = axis.length_squared();
        let w = -a;
        let (inv_l2, s0) = if l2 > 0.0 {
            (1.0 / l2, w.dot(axis) / l2)
        } else {
            (0.0, 0.0)
        };
        let r = capsule.radius as f64;
        CapsuleFromOrigin {
            a,
            b,
            r2: r * r,
            axis,
            inv_l2,
            s0,
            o_perp: w - s0 * axis,
        }
    }

    /// [`ray_capsule`] for a ray from this origin along `dir`, clipped to
    /// `[t_min, t_max]`.
    #[inline]
    pub fn hit(&self, dir: &DirectionF64, t_min: f32, t_max: f32) -> Option<(f32, f32)> {
        let (lo, hi) = if self.inv_l2 == 0.0 {
            self.sphere(self.a, dir)?
        } else {
            self.capsule(dir)?
        };
        let t_in = lo.max(t_min as f64);
        let t_out = hi.min(t_max as f64);
        if !(t_in <= t_out) {
            return None;
        }
        Some((t_in as f32, t_out as f32))
    }

    /// The ray's interval in the sphere of radius `r` around `c`, unclipped.
    #[inline]
    fn sphere(&self, c: DVec3, dir: &DirectionF64) -> Option<(f64, f64)> {
        let t_mid = c.dot(dir.d) * dir.inv_dd;
        let perp = t_mid * dir.d - c;
        let disc = self.r2 - perp.length_squared();
        if !(disc >= 0.0) {
            return None;
        }
        let half = (disc * dir.inv_dd).sqrt();
        Some((t_mid - half, t_mid + half))
    }

    /// The end sphere on the side of axial coordinate `s` (segment units) if `s` lies
    /// beyond an end, else `None`.
    #[inline]
    fn end_beyond(&self, s: f64) -> Option<DVec3> {
        if s < 0.0 {
            Some(self.a)
        } else if s > 1.0 {
            Some(self.b)
        } else {
            None
        }
    }

    /// A capsule of positive length: the cylinder, and end spheres where needed (see the
    /// type's docs), unclipped.
    #[inline]
    fn capsule(&self, dir: &DirectionF64) -> Option<(f64, f64)> {
        let d = dir.d;
        let s1 = d.dot(self.axis) * self.inv_l2;
        let d_perp = d - s1 * self.axis;
        let a = d_perp.length_squared();
        if a <= 1e-20 * dir.dd {
            // Parallel to the axis (within ~1e-10 rad): inside the cylinder for all `t`
            // or never; across the segment's slab, and the end spheres (which a ray
            // grazing the cylinder may miss by rounding).
            if !(self.o_perp.length_squared() <= self.r2 && s1 != 0.0) {
                return None;
            }
            let inv_s1 = 1.0 / s1;
            let (t0, t1) = (-self.s0 * inv_s1, (1.0 - self.s0) * inv_s1);
            let (mut lo, mut hi) = (t0.min(t1), t0.max(t1));
            for end in [self.a, self.b] {
                if let Some((e0, e1)) = self.sphere(end, dir) {
                    (lo, hi) = (lo.min(e0), hi.max(e1));
                }
            }
            return Some((lo, hi));
        }
        let inv_a = 1.0 / a;
        let t_mid = -self.o_perp.dot(d_perp) * inv_a;
        let perp = self.o_perp + t_mid * d_perp;
        let disc = self.r2 - perp.length_squared();
        if !(disc >= 0.0) {
            return None;
        }
        let half = (disc * inv_a).sqrt();
        let (mut lo, mut hi) = (t_mid - half, t_mid + half);
        if let Some(end) = self.end_beyond(self.s0 + lo * s1) {
            lo = self.sphere(end, dir)?.0;
        }
        if let Some(end) = self.end_beyond(self.s0 + hi * s1) {
            hi = self.sphere(end, dir)?.1;
        }
        Some((lo, hi))
    }
}

/// Every capsule the ray crosses, by testing all of them: the plain reference the BVH
/// is checked against. Appends to `out` in capsule order.
pub fn brute_force_hits(capsules: &[Capsule], ray: &Ray, out: &mut Vec<CapsuleHit>) {
    for (i, capsule) in capsules.iter().enumerate() {
        if let Some((t_in, t_out)) = ray_capsule(ray, capsule) {
            out.push(CapsuleHit {
                t_in,
                t_out,
                capsule: i as u32,
            });
        }
    }
}

/// Distance from `p` to the capsule's segment `a`-`b` (not its surface).
pub fn distance_to_segment(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let f64s = |v: Vec3| v.as_dvec3().to_array();
    talkin_geometry::segment_distance2(f64s(p), f64s(a), f64s(b)).sqrt() as f32
}

/// Signed distance from `p` to the capsule surface (negative inside).
pub fn signed_distance(p: Vec3, capsule: &Capsule) -> f32 {
    distance_to_segment(p, capsule.a, capsule.b) - capsule.radius
}

/// How much the capsule's radius must grow for the ray (over `[t_min, t_max]`) to touch
/// it: distance between the ray and the capsule segment minus the radius, at least 0.
/// Ray and segment closest points as in Ericson, Real-Time Collision Detection 5.1.9.
pub fn margin_to_hit(ray: &Ray, capsule: &Capsule) -> f32 {
    let a = capsule.a.as_dvec3();
    let o = ray.origin.as_dvec3() - a;
    let d = ray.direction.as_dvec3();
    let seg = capsule.b.as_dvec3() - a;
    let dd = d.length_squared();
    // The closest point of the ray to the segment is never past the last point where
    // the ray still approaches one of the segment's ends.
    let t_last = ((-o).dot(d) / dd).max((seg - o).dot(d) / dd);
    let t_min = ray.t_min as f64;
    let t_max = (ray.t_max as f64).min(t_last.max(t_min));
    let p1 = o + t_min * d;
    let d1 = (t_max - t_min) * d;
    let (p2, d2) = (DVec3::ZERO, seg);
    let r = p1 - p2;
    let (aa, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    let (s, t);
    if aa == 0.0 && e == 0.0 {
        (s, t) = (0.0, 0.0);
    } else if aa == 0.0 {
        (s, t) = (0.0, (f / e).clamp(0.0, 1.0));
    } else {
        let c = d1.dot(r);
        if e == 0.0 {
            (s, t) = ((-c / aa).clamp(0.0, 1.0), 0.0);
        } else {
            let b = d1.dot(d2);
            let denom = aa * e - b * b;
            let s0 = if denom > 1e-12 * aa * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                (s, t) = ((-c / aa).clamp(0.0, 1.0), 0.0);
            } else if t0 > 1.0 {
                (s, t) = (((b - c) / aa).clamp(0.0, 1.0), 1.0);
            } else {
                (s, t) = (s0, t0);
            }
        }
    }
    let gap = ((p1 + s * d1) - (p2 + t * d2)).length() - capsule.radius as f64;
    gap.max(0.0) as f32
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::Part;
    use glam::vec3;

    /// A body capsule of bone 0 (shared by the crate's geometry tests).
    pub(crate) fn capsule(a: Vec3, b: Vec3, radius: f32) -> Capsule {
        Capsule {
            a,
            b,
            radius,
            part: Part::Body,
            bone: 0,
        }
    }

    fn ray(o: Vec3, d: Vec3) -> Ray {
        Ray::new(o, d, 0.0, f32::INFINITY).unwrap()
    }

    #[test]
    fn straight_through_the_middle() {
        let c = capsule(vec3(-1.0, 0.0, 0.0), vec3(1.0, 0.0, 0.0), 0.5);
        let (t0, t1) = ray_capsule(&ray(vec3(0.0, 0.0, -3.0), Vec3::Z), &c).unwrap();
        assert!(
            (t0 - 2.5).abs() < 1e-6 && (t1 - 3.5).abs() < 1e-6,
            "{t0} {t1}"
        );
    }

    #[test]
    fn along_the_axis_goes_cap_to_cap() {
        let c = capsule(vec3(-1.0, 0.0, 0.0), vec3(1.0, 0.0, 0.0), 0.5);
        let (t0, t1) = ray_capsule(&ray(vec3(-4.0, 0.0, 0.0), Vec3::X), &c).unwrap();
        assert!(
            (t0 - 2.5).abs() < 1e-6 && (t1 - 5.5).abs() < 1e-6,
            "{t0} {t1}"
        );
    }

    #[test]
    fn tangent_ray_touches_in_one_point() {
        let c = capsule(vec3(-1.0, 0.0, 0.0), vec3(1.0, 0.0, 0.0), 0.5);
        let (t0, t1) = ray_capsule(&ray(vec3(0.25, 0.5, -2.0), Vec3::Z), &c).unwrap();
        assert_eq!((t0, t1), (2.0, 2.0));
        assert!(ray_capsule(&ray(vec3(0.25, 0.5001, -2.0), Vec3::Z), &c).is_none());
    }

    #[test]
    fn margin_to_hit_is_the_gap() {
        let c = capsule(vec3(-1.0, 0.0, 0.0), vec3(1.0, 0.0, 0.0), 0.5);
        let m = margin_to_hit(&ray(vec3(3.0, 0.8, -2.0), Vec3::Z), &c);
        let expected = (2.0f32 * 2.0 + 0.8 * 0.8).sqrt() - 0.5;
        assert!((m - expected).abs() < 1e-6, "{m} vs {expected}");
        assert_eq!(margin_to_hit(&ray(vec3(0.0, 0.2, -2.0), Vec3::Z), &c), 0.0);
        // Behind the origin does not count.
        let m = margin_to_hit(&ray(vec3(0.0, 0.0, 2.0), Vec3::Z), &c);
        assert!((m - 1.5).abs() < 1e-6, "{m}");
    }

    /// Against a plain reference, the sampled signed distance: every point along the ray
    /// inside the capsule lies in the interval, every point well inside the interval lies
    /// in the capsule. Random capsules (spheres among them), origins and directions, rays
    /// aimed at the ends, at the middle and along the axis.
    #[test]
    fn intervals_match_the_sampled_distance() {
        let mut rng = crate::rng::SplitMix64::for_stream(41, 0);
        let mut p = || vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
        let (mut inside, mut hits) = (0, 0);
        for k in 0..200 {
            let a = p();
            let b = if k % 5 == 0 { a } else { a + p() };
            let c = capsule(a, b, 0.02 + 0.2 * p().x.abs());
            let origin = 3.0 * p();
            let mut dirs: Vec<Vec3> = (0..8).map(|_| p()).collect();
            dirs.extend([
                c.a - origin,
                c.b - origin,
                c.b - c.a,
                0.5 * (c.a + c.b) - origin,
            ]);
            for d in dirs {
                let Ok(r) = Ray::new(origin, d, 0.0, f32::INFINITY) else {
                    continue;
                };
                let hit = ray_capsule(&r, &c);
                hits += hit.is_some() as usize;
                for j in 0..800 {
                    let t = j as f32 * 0.01;
                    let sd = signed_distance(r.at(t), &c);
                    let within =
                        |pad: f32| hit.is_some_and(|(t0, t1)| t0 - pad <= t && t <= t1 + pad);
                    if sd < -1e-4 {
                        inside += 1;
                        assert!(within(1e-4), "{c:?} {r:?}: t {t} (sd {sd}) not in {hit:?}");
                    }
                    if hit.is_some_and(|(t0, t1)| t0 + 1e-3 < t && t < t1 - 1e-3) {
                        assert!(sd < 1e-4, "{c:?} {r:?}: t {t} in {hit:?} but sd {sd}");
                    }
                }
            }
        }
        assert!(hits > 500 && inside > 10_000, "{hits} {inside}");
    }

    /// The capsule as the union of its three pieces (both end spheres and the cylinder
    /// clipped to the segment's slab), each solved in full: the plain reference for the
    /// cylinder-first shortcut of [`CapsuleFromOrigin::hit`].
    fn hit_by_pieces(c: &Capsule, r: &Ray) -> Option<(f64, f64)> {
        let (o, d) = (r.origin.as_dvec3(), r.direction.as_dvec3());
        let (a, b) = (c.a.as_dvec3() - o, c.b.as_dvec3() - o);
        let r2 = (c.radius as f64).powi(2);
        let dd = d.length_squared();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for centre in [a, b] {
            let t_mid = centre.dot(d) / dd;
            let disc = r2 - (t_mid * d - centre).length_squared();
            if disc >= 0.0 {
                let half = (disc / dd).sqrt();
                (lo, hi) = (lo.min(t_mid - half), hi.max(t_mid + half));
            }
        }
        let axis = b - a;
        let (s1, s0) = (
            d.dot(axis) / axis.length_squared(),
            -a.dot(axis) / axis.length_squared(),
        );
        let (d_perp, o_perp) = (d - s1 * axis, -a - s0 * axis);
        let qa = d_perp.length_squared();
        let t_mid = -o_perp.dot(d_perp) / qa;
        let disc = r2 - (o_perp + t_mid * d_perp).length_squared();
        if disc >= 0.0 {
            let half = (disc / qa).sqrt();
            let (t0, t1) = (-s0 / s1, (1.0 - s0) / s1);
            let (c0, c1) = (
                (t_mid - half).max(t0.min(t1)),
                (t_mid + half).min(t0.max(t1)),
            );
            if c0 <= c1 {
                (lo, hi) = (lo.min(c0), hi.max(c1));
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// The cylinder-first shortcut agrees with the union of the pieces, on random rays
    /// and on rays through the rims where the cylinder meets the end spheres (where it
    /// picks one piece over the other).
    #[test]
    fn cylinder_first_matches_the_union_of_pieces() {
        let mut rng = crate::rng::SplitMix64::for_stream(43, 0);
        let mut p = || vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
        let mut compared = 0;
        for _ in 0..300 {
            let a = p();
            let c = capsule(a, a + p(), 0.02 + 0.2 * p().x.abs());
            let origin = 3.0 * p();
            // A point on each rim: an end plus the radius perpendicular to the axis.
            let side = (c.b - c.a).any_orthonormal_vector() * c.radius;
            let mut targets: Vec<Vec3> = (0..6).map(|_| p()).collect();
            targets.extend([
                c.a + side,
                c.b - side,
                c.a + 0.999 * side,
                c.b + 1.001 * side,
            ]);
            for target in targets {
                let Ok(r) = Ray::new(origin, target - origin, 0.0, f32::INFINITY) else {
                    continue;
                };
                let got = ray_capsule(&r, &c);
                let want = hit_by_pieces(&c, &r);
                match (got, want) {
                    (Some((t0, t1)), Some((w0, w1))) => {
                        compared += 1;
                        assert!((t0 as f64 - w0).abs() < 1e-5, "{c:?} {r:?}: {t0} vs {w0}");
                        assert!((t1 as f64 - w1).abs() < 1e-5, "{c:?} {r:?}: {t1} vs {w1}");
                    }
                    (None, None) => {}
                    // Only a ray touching the surface may go either way.
                    (got, Some((w0, w1))) => assert!(w1 - w0 < 1e-4, "{c:?} {r:?}: {got:?}"),
                    (Some((t0, t1)), None) => assert!(t1 - t0 < 1e-4, "{c:?} {r:?}"),
                }
            }
        }
        assert!(compared > 600, "{compared}");
    }
}
