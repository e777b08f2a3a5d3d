//! The per-frame BVH over posed capsules.

use std::ops::ControlFlow;
use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::{Boundable, BvhBuildParams, aabb::Aabb, bvh2::Bvh2, bvh2::builder::build_bvh2};

use crate::intersect::{CapsuleHit, ray_capsule, sort_hits, validate_capsules};
use crate::intervals::{RayIntervals, merge_hits};
use crate::packing::par_pack;
use crate::ray::validate_rays;
use crate::{Capsule, GridError, Ray};

/// Capsule bounds, padded by a relative epsilon so that f32 rounding in the box test
/// can never cull a ray that the exact (f64) capsule test would accept, tangent rays
/// included.
struct Bounds(Aabb);

impl Boundable for Bounds {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

fn capsule_bounds(c: &Capsule) -> Bounds {
    let scale = c.a.abs().max(c.b.abs()).max_element() + c.radius;
    let pad = Vec3A::splat(c.radius + 1e-5 * scale + f32::MIN_POSITIVE);
    let (a, b) = (Vec3A::from(c.a), Vec3A::from(c.b));
    Bounds(Aabb::new(a.min(b) - pad, a.max(b) + pad))
}

/// A BVH over one frame's posed capsules (world space), built with obvhs' PLOC builder.
/// ~70 capsules build in microseconds, so build one per frame rather than refitting.
///
/// Traversal is this crate's own exact slab test over obvhs' nodes: obvhs' `Ray` clamps
/// `1/d` at `1/f32::EPSILON`, which can cull boxes far along axis-aligned rays.
///
/// ```
/// use glam::{Vec3, vec3};
/// use talkin_grids::{Capsule, CapsuleBvh, Part, Ray};
///
/// let arm = Capsule { a: vec3(0.2, 1.4, 0.0), b: vec3(0.5, 1.4, 0.0), radius: 0.05,
///                     part: Part::Arms, bone: 16 };
/// let head = Capsule { a: vec3(0.0, 1.6, 0.0), b: vec3(0.0, 1.6, 0.0), radius: 0.1,
///                      part: Part::Head, bone: 15 };
/// let bvh = CapsuleBvh::build(&[arm, head])?;
///
/// // Unit direction, t in metres from the origin, t_max may be infinite.
/// let ray = Ray::new(vec3(0.3, 1.4, -2.0), Vec3::Z, 0.0, f32::INFINITY)?;
/// let intervals = bvh.intervals(&[ray])?;
/// let hit = intervals.of_ray(0)[0];
/// assert!((hit.t_in - 1.95).abs() < 1e-5 && (hit.t_out - 2.05).abs() < 1e-5);
/// assert_eq!(hit.part_mask, Part::Arms.bit());
/// assert_eq!(hit.bone_mask, 1 << 16);
/// # Ok::<(), talkin_grids::GridError>(())
/// ```
pub struct CapsuleBvh {
    capsules: Vec<Capsule>,
    bvh: Bvh2,
}

impl CapsuleBvh {
    /// Builds the BVH; fails on a non-finite capsule, a negative radius or a bone >= 64.
    pub fn build(capsules: &[Capsule]) -> Result<CapsuleBvh, GridError> {
        validate_capsules(capsules)?;
        let bounds: Vec<Bounds> = capsules.iter().map(capsule_bounds).collect();
        let bvh = if capsules.is_empty() {
            Bvh2::default()
        } else {
            build_bvh2(
                &bounds,
                BvhBuildParams {
                    max_prims_per_leaf: 1,
                    ..BvhBuildParams::fast_build()
                },
                &mut Duration::default(),
            )
        };
        Ok(CapsuleBvh {
            capsules: capsules.to_vec(),
            bvh,
        })
    }

    /// The capsules, in the order given to [`CapsuleBvh::build`] (hit indices refer to it).
    pub fn capsules(&self) -> &[Capsule] {
        &self.capsules
    }

    /// Calls `f` for every capsule the ray crosses, in traversal order (not sorted).
    /// The ray must be valid ([`Ray::validate`]); an invalid one may report nothing.
    pub fn for_each_hit(&self, ray: &Ray, mut f: impl FnMut(CapsuleHit)) {
        let _ = self.try_for_each_hit(ray, |h| {
            f(h);
            ControlFlow::Continue(())
        });
    }

    /// [`CapsuleBvh::for_each_hit`] until `f` breaks: what is still to visit is not
    /// visited.
    pub fn try_for_each_hit(
        &self,
        ray: &Ray,
        mut f: impl FnMut(CapsuleHit) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        if self.bvh.nodes.is_empty() {
            return ControlFlow::Continue(());
        }
        let slab = Slab::new(ray);
        let mut stack = NodeStack::default();
        let mut visit = |node: u32, stack: &mut NodeStack| {
            let node = &self.bvh.nodes[node as usize];
            if !slab.hits(node.aabb()) {
                return ControlFlow::Continue(());
            }
            if node.is_leaf() {
                let prims = node.first_index..node.first_index + node.prim_count;
                for &prim in &self.bvh.primitive_indices[prims.start as usize..prims.end as usize] {
                    if let Some((t_in, t_out)) = ray_capsule(ray, &self.capsules[prim as usize]) {
                        f(CapsuleHit {
                            t_in,
                            t_out,
                            capsule: prim,
                        })?;
                    }
                }
            } else {
                stack.push(node.first_index);
                stack.push(node.first_index + 1);
            }
            ControlFlow::Continue(())
        };
        visit(0, &mut stack)?;
        while let Some(node) = stack.pop() {
            visit(node, &mut stack)?;
        }
        ControlFlow::Continue(())
    }

    /// All capsules the ray crosses, sorted by `t_in` (then capsule index), into `out`
    /// (cleared first).
    pub fn hits(&self, ray: &Ray, out: &mut Vec<CapsuleHit>) -> Result<(), GridError> {
        ray.validate(0)?;
        out.clear();
        self.for_each_hit(ray, |h| out.push(h));
        sort_hits(out);
        Ok(())
    }

    /// Per ray, the sorted, merged intervals inside the capsules with the parts and bones
    /// of the capsules that make up each interval. Rays run in parallel.
    pub fn intervals(&self, rays: &[Ray]) -> Result<RayIntervals, GridError> {
        validate_rays(rays)?;
        let (ray_offsets, intervals) = par_pack(rays.len(), Vec::new, |hits, i, out| {
            hits.clear();
            self.for_each_hit(&rays[i], |h| hits.push(h));
            merge_hits(hits, &self.capsules, out);
        });
        Ok(RayIntervals {
            ray_offsets,
            intervals,
        })
    }
}

/// Ray-box slab test that treats zero direction components exactly.
struct Slab {
    origin: Vec3,
    inv: Vec3,
    t_min: f32,
    t_max: f32,
}

impl Slab {
    fn new(ray: &Ray) -> Slab {
        Slab {
            origin: ray.origin,
            inv: ray.direction.recip(),
            t_min: ray.t_min,
            t_max: ray.t_max,
        }
    }

    #[inline]
    fn hits(&self, aabb: &Aabb) -> bool {
        let (mut t0, mut t1) = (self.t_min, self.t_max);
        for axis in 0..3 {
            let o = self.origin[axis];
            let (lo, hi) = (aabb.min[axis], aabb.max[axis]);
            let inv = self.inv[axis];
            if inv.is_infinite() {
                if o < lo || o > hi {
                    return false;
                }
                continue;
            }
            let (a, b) = ((lo - o) * inv, (hi - o) * inv);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        // Relative slack for the f32 rounding of the divisions above.
        t0 - t1 <= 1e-6 * t0.abs().max(t1.abs())
    }
}

/// Traversal stack on the stack: a BVH over a skeleton is a few levels deep; deeper
/// ones spill to the heap instead of failing.
struct NodeStack {
    inline: [u32; 64],
    len: usize,
    spill: Vec<u32>,
}

impl Default for NodeStack {
    fn default() -> Self {
        NodeStack {
            inline: [0; 64],
            len: 0,
            spill: Vec::new(),
        }
    }
}

impl NodeStack {
    #[inline]
    fn push(&mut self, node: u32) {
        if self.len < self.inline.len() {
            self.inline[self.len] = node;
            self.len += 1;
        } else {
            self.spill.push(node);
        }
    }

    #[inline]
    fn pop(&mut self) -> Option<u32> {
        if let Some(node) = self.spill.pop() {
            return Some(node);
        }
        self.len = self.len.checked_sub(1)?;
        Some(self.inline[self.len])
    }
}
