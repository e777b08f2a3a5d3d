//! The capsules a chunk of rays sharing one origin may meet, prepared for that origin:
//! what lets the accelerated sampler run the exact capsule test on only the few capsules
//! a ray may cross.
//!
//! Built once per chunk: the capsules whose bounding spheres lie outside the cone of the
//! chunk's directions are dropped, the rest are prepared for the origin
//! ([`CapsuleFromOrigin`]) with their bounding spheres laid out eight at a time, so a ray
//! rejects most of them in one branch-free loop per eight. Cores ride on a capsule that
//! contains them (a ray misses the core of a capsule it misses), so the ray tests them
//! only after their capsule's exact test hits; a core no capsule contains is tested on
//! its own.

use glam::Vec3;

use crate::intersect::{CapsuleFromOrigin, DirectionF64, distance_to_segment};
use crate::{Capsule, Ray};

/// Bounding spheres per block: one SSE pair, or one AVX register.
const LANES: usize = 8;

/// Bounding spheres relative to the origin, [`LANES`] at a time; a padding lane never
/// passes (negative squared reach).
#[derive(Clone, Copy)]
struct SphereBlock {
    x: [f32; LANES],
    y: [f32; LANES],
    z: [f32; LANES],
    reach2: [f32; LANES],
}

impl SphereBlock {
    const EMPTY: SphereBlock = SphereBlock {
        x: [0.0; LANES],
        y: [0.0; LANES],
        z: [0.0; LANES],
        reach2: [-1.0; LANES],
    };

    /// Bit `j` set if the line through the origin along unit `d` passes within the reach
    /// of sphere `j`.
    #[inline]
    fn near(&self, d: Vec3) -> u32 {
        let mut mask = 0u32;
        for j in 0..LANES {
            let s = self.x[j] * d.x + self.y[j] * d.y + self.z[j] * d.z;
            let (px, py, pz) = (
                self.x[j] - s * d.x,
                self.y[j] - s * d.y,
                self.z[j] - s * d.z,
            );
            mask |= ((px * px + py * py + pz * pz <= self.reach2[j]) as u32) << j;
        }
        mask
    }
}

/// A capsule prepared for the chunk's origin, with the cores it contains.
struct Candidate {
    exact: CapsuleFromOrigin,
    index: u32,
    /// Its contained cores' range in [`ChunkView::nested_cores`].
    cores: std::ops::Range<u32>,
}

/// A core prepared for the chunk's origin: its bounding sphere (centre relative to the
/// origin, padded squared reach) first, then the exact test.
struct PreparedCore {
    centre: Vec3,
    reach2: f32,
    exact: CapsuleFromOrigin,
}

/// See the module docs.
pub(crate) struct ChunkView {
    spheres: Vec<SphereBlock>,
    capsules: Vec<Candidate>,
    nested_cores: Vec<PreparedCore>,
    loose_cores: Vec<PreparedCore>,
}

/// For every capsule the cores it contains, and the cores no capsule contains: what a
/// sampler works out once from its capsules and cores.
pub(crate) struct CoreNesting {
    nested: Vec<Vec<u32>>,
    loose: Vec<u32>,
}

impl CoreNesting {
    pub(crate) fn new(capsules: &[Capsule], cores: &[Capsule]) -> CoreNesting {
        let mut nested = vec![Vec::new(); capsules.len()];
        let mut loose = Vec::new();
        for (k, core) in cores.iter().enumerate() {
            // The smallest container: the one the fewest rays cross without meeting it.
            let container = capsules
                .iter()
                .enumerate()
                .filter(|(_, c)| contains(c, core))
                .min_by(|(_, x), (_, y)| volume(x).total_cmp(&volume(y)));
            match container {
                Some((c, _)) => nested[c].push(k as u32),
                None => loose.push(k as u32),
            }
        }
        CoreNesting { nested, loose }
    }

    /// The cores no capsule contains.
    #[cfg(test)]
    pub(crate) fn loose(&self) -> &[u32] {
        &self.loose
    }
}

fn volume(c: &Capsule) -> f32 {
    let r = c.radius;
    std::f32::consts::PI * r * r * ((c.b - c.a).length() + 4.0 / 3.0 * r)
}

/// Whether `outer` holds `inner` with 10 micrometres to spare. A capsule is its segment
/// grown by its radius, so it holds the ball of radius `r` around `p` iff `p` lies
/// within `outer.radius - r` of its segment; that distance is convex along the inner
/// segment, so checking the two ends is enough. The 10 micrometres are far above the
/// rounding of this f32 check and of the exact tests' f64: a ray that meets `inner` by
/// their arithmetic meets `outer` too.
fn contains(outer: &Capsule, inner: &Capsule) -> bool {
    let room = outer.radius - inner.radius - 1e-5;
    room >= 0.0
        && [inner.a, inner.b]
            .iter()
            .all(|&p| distance_to_segment(p, outer.a, outer.b) <= room)
}

/// A capsule's bounding sphere relative to `origin`: centre, radius.
fn bounding_sphere(c: &Capsule, origin: Vec3) -> (Vec3, f32) {
    (
        0.5 * (c.a + c.b) - origin,
        0.5 * (c.b - c.a).length() + c.radius,
    )
}

/// The squared reach of a bounding sphere (`centre` relative to the origin), padded
/// against f32 rounding: it only decides which capsules reach the exact test.
fn padded_reach2(centre: Vec3, radius: f32) -> f32 {
    let reach = radius + 1e-5 * centre.length() + 1e-6;
    reach * reach
}

impl ChunkView {
    /// The view of a chunk whose rays share an origin and start at `t_min >= 0`: the
    /// capsules whose bounding sphere meets the cone around the chunk's mean direction
    /// that holds all its directions. `None` for chunks that do not qualify.
    pub(crate) fn new(
        rays: &[Ray],
        capsules: &[Capsule],
        cores: &[Capsule],
        nesting: &CoreNesting,
    ) -> Option<ChunkView> {
        let origin = rays.first()?.origin;
        if rays.iter().any(|r| r.origin != origin || r.t_min < 0.0) {
            return None;
        }
        let sum: Vec3 = rays.iter().map(|r| r.direction).sum();
        let axis = sum.try_normalize()?;
        let cos_min = rays
            .iter()
            .map(|r| r.direction.normalize().dot(axis))
            .fold(1.0f32, f32::min);
        let (cos_s, sin_s) = (
            cos_min.clamp(-1.0, 1.0),
            (1.0 - cos_min * cos_min).max(0.0).sqrt(),
        );
        // The padded squared reach of a bounding sphere that meets the cone, or `None`.
        let seen = |centre: Vec3, radius: f32| -> Option<f32> {
            let dist = centre.length();
            // The sphere seen from the origin is a cone of half-angle h around its
            // centre; it meets the chunk's cone (half-angle s) if the axes are at most
            // s + h apart: cos(apart) >= cos(s + h), with 1e-4 of slack against f32
            // rounding.
            let sin_h = radius / dist;
            let meets = !(sin_h < 1.0 - 1e-5) || {
                let cos_h = (1.0 - sin_h * sin_h).sqrt();
                let cos_both = cos_s * cos_h - sin_s * sin_h;
                // s + h >= pi: the cones cover every direction between them.
                cos_s <= -cos_h || centre.dot(axis) / dist >= cos_both - 1e-4
            };
            meets.then(|| padded_reach2(centre, radius))
        };
        let mut view = ChunkView {
            spheres: Vec::new(),
            capsules: Vec::new(),
            nested_cores: Vec::new(),
            loose_cores: Vec::new(),
        };
        for (k, c) in capsules.iter().enumerate() {
            let (centre, radius) = bounding_sphere(c, origin);
            let Some(reach2) = seen(centre, radius) else {
                continue;
            };
            let lane = view.capsules.len() % LANES;
            if lane == 0 {
                view.spheres.push(SphereBlock::EMPTY);
            }
            let block = view.spheres.last_mut().expect("pushed above");
            (block.x[lane], block.y[lane], block.z[lane]) = (centre.x, centre.y, centre.z);
            block.reach2[lane] = reach2;
            let first = view.nested_cores.len() as u32;
            for &i in &nesting.nested[k] {
                let core = &cores[i as usize];
                let (centre, radius) = bounding_sphere(core, origin);
                // Inside a capsule the cone meets, the core may meet it too: no cone test.
                view.nested_cores.push(PreparedCore {
                    centre,
                    reach2: padded_reach2(centre, radius),
                    exact: CapsuleFromOrigin::new(core, origin),
                });
            }
            view.capsules.push(Candidate {
                exact: CapsuleFromOrigin::new(c, origin),
                index: k as u32,
                cores: first..view.nested_cores.len() as u32,
            });
        }
        for &i in &nesting.loose {
            let core = &cores[i as usize];
            let (centre, radius) = bounding_sphere(core, origin);
            if let Some(reach2) = seen(centre, radius) {
                view.loose_cores.push(PreparedCore {
                    centre,
                    reach2,
                    exact: CapsuleFromOrigin::new(core, origin),
                });
            }
        }
        Some(view)
    }

    /// Calls `hit(slot, capsule index, t_in, t_out)` for every capsule `ray` (from the
    /// view's origin, along `dir`) crosses; `slot` names it to [`ChunkView::core_entry`].
    /// `d` is the ray's direction normalised: the rays' directions are unit only within
    /// a tolerance, and the bounding-sphere rejects need it exactly.
    #[inline]
    pub(crate) fn crossings(
        &self,
        ray: &Ray,
        dir: &DirectionF64,
        d: Vec3,
        mut hit: impl FnMut(u32, u32, f32, f32),
    ) {
        for (b, block) in self.spheres.iter().enumerate() {
            let mut near = block.near(d);
            while near != 0 {
                let slot = b * LANES + near.trailing_zeros() as usize;
                near &= near - 1;
                let c = &self.capsules[slot];
                if let Some((t_in, t_out)) = c.exact.hit(dir, ray.t_min, ray.t_max) {
                    hit(slot as u32, c.index, t_in, t_out);
                }
            }
        }
    }

    /// Where `ray` first enters a core (infinity if never), given the `(slot, t_in)` of
    /// every capsule it crosses in order of `t_in`: a core inside a capsule is entered no
    /// sooner than the capsule, so the capsules entered after the best core entry so far
    /// need no test.
    /// `d` as in [`ChunkView::crossings`].
    #[inline]
    pub(crate) fn core_entry(
        &self,
        ray: &Ray,
        dir: &DirectionF64,
        d: Vec3,
        by_entry: impl Iterator<Item = (u32, f32)>,
    ) -> f32 {
        let entry = |c: &PreparedCore| -> Option<f32> {
            let s = c.centre.dot(d);
            if !((c.centre - s * d).length_squared() <= c.reach2) {
                return None;
            }
            c.exact.hit(dir, ray.t_min, ray.t_max).map(|(t, _)| t)
        };
        let mut t_core = f32::INFINITY;
        for (slot, t_in) in by_entry {
            if t_in >= t_core {
                break;
            }
            let cores = &self.capsules[slot as usize].cores;
            for c in &self.nested_cores[cores.start as usize..cores.end as usize] {
                if let Some(t) = entry(c) {
                    t_core = t_core.min(t);
                }
            }
        }
        for c in &self.loose_cores {
            if let Some(t) = entry(c) {
                t_core = t_core.min(t);
            }
        }
        t_core
    }
}

#[cfg(test)]
mod tests {
    use glam::vec3;

    use super::*;
    use crate::intersect::tests::capsule;

    #[test]
    fn cores_nest_in_the_capsules_that_hold_them() {
        let limb = capsule(Vec3::ZERO, vec3(0.0, 1.0, 0.0), 0.1);
        let cores = [
            // Shrunk ends and radius: inside.
            capsule(vec3(0.0, 0.1, 0.0), vec3(0.0, 0.9, 0.0), 0.05),
            // The limb itself: no room to spare, so loose.
            limb,
            // Off the axis by more than the radii allow.
            capsule(vec3(0.06, 0.5, 0.0), vec3(0.06, 0.6, 0.0), 0.05),
            // A sphere at the cap, inside.
            capsule(vec3(0.0, 1.05, 0.0), vec3(0.0, 1.05, 0.0), 0.04),
        ];
        let nesting = CoreNesting::new(&[limb], &cores);
        assert_eq!(nesting.nested, vec![vec![0, 3]]);
        assert_eq!(nesting.loose, vec![1, 2]);
    }
}
