//! Shared helpers for the integration tests: seeded random scenes and plain references.
#![allow(dead_code)]

use glam::{Vec3, vec3};
use talkin_grids::intersect::distance_to_segment;
use talkin_grids::{Capsule, Part, Ray};

/// Tiny deterministic generator (xorshift64*), independent of the crate's own.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    pub fn f32(&mut self) -> f32 {
        (self.u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
    pub fn vec(&mut self, lo: f32, hi: f32) -> Vec3 {
        vec3(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }
    pub fn unit(&mut self) -> Vec3 {
        loop {
            let v = self.vec(-1.0, 1.0);
            if let Some(u) = v.try_normalize()
                && v.length() <= 1.0
            {
                return u;
            }
        }
    }
}

/// `n` capsules in a 2 m box around the origin: limbs, spheres (a == b), thin fingers.
pub fn random_scene(seed: u64, n: usize) -> Vec<Capsule> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let a = rng.vec(-1.0, 1.0);
            let b = match i % 4 {
                0 => a, // sphere
                1 => a + rng.unit() * rng.range(0.01, 0.08),
                _ => a + rng.unit() * rng.range(0.1, 0.6),
            };
            Capsule {
                a,
                b,
                radius: rng.range(0.005, 0.15),
                part: Part::ALL[i % 4],
                bone: (i % 55) as u16,
            }
        })
        .collect()
}

/// Rays at the scene: from outside aimed at a random capsule point, axis-aligned ones,
/// and rays starting inside capsules (with t_min > 0 for some).
pub fn random_rays(seed: u64, n: usize, scene: &[Capsule]) -> Vec<Ray> {
    let mut rng = Rng::new(seed ^ 0xABCD);
    (0..n)
        .map(|i| {
            let c = &scene[(rng.u64() % scene.len() as u64) as usize];
            let target = c.a.lerp(c.b, rng.f32()) + rng.unit() * c.radius * rng.range(0.0, 1.3);
            let (origin, dir) = match i % 5 {
                0 | 1 => {
                    let o = rng.unit() * 3.0;
                    (o, target - o)
                }
                2 => {
                    let axis = [Vec3::X, Vec3::Y, Vec3::Z][i % 3];
                    let sign = if rng.f32() < 0.5 { -1.0 } else { 1.0 };
                    (target - axis * sign * 3.0, axis * sign)
                }
                3 => (target, rng.unit()),
                _ => (rng.vec(-1.5, 1.5), rng.unit()),
            };
            let t_min = if i % 7 == 0 { rng.range(0.0, 0.5) } else { 0.0 };
            let t_max = if i % 3 == 0 {
                f32::INFINITY
            } else {
                rng.range(2.0, 6.0)
            };
            Ray::new(origin, dir, t_min, t_max).unwrap()
        })
        .collect()
}

/// Sampled reference: marches the ray in steps of `h` and returns the first and last
/// `t` whose point is within the radius of the segment. Only the stretch of the ray
/// within the capsule's bounding sphere is marched (a capsule lies inside the sphere
/// around its midpoint of radius half-length + radius).
pub fn marched_interval(ray: &Ray, c: &Capsule, h: f32) -> Option<(f32, f32)> {
    let mid = (c.a + c.b) * 0.5;
    let reach = (c.b - c.a).length() * 0.5 + c.radius;
    let t_mid = (mid - ray.origin).dot(ray.direction);
    let start = ray.t_min.max(t_mid - reach - h);
    let end = ray.t_max.min(t_mid + reach + h);
    if start > end {
        return None;
    }
    let steps = ((end - start) / h).ceil() as usize;
    let mut first = None;
    let mut last = None;
    for k in 0..=steps {
        let t = (start + k as f32 * h).min(end);
        let p = ray.origin + t * ray.direction;
        if distance_to_segment(p, c.a, c.b) <= c.radius {
            first.get_or_insert(t);
            last = Some(t);
        }
    }
    Some((first?, last?))
}

/// Plain union of closed intervals: sort, then fold.
pub fn union_of(mut spans: Vec<(f32, f32)>) -> Vec<(f32, f32)> {
    spans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out: Vec<(f32, f32)> = Vec::new();
    for (a, b) in spans {
        match out.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}
