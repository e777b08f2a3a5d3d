//! Merged, packed ray intervals inside capsules.

use std::ops::Range;

use crate::{Capsule, CapsuleHit};

/// A stretch `[t_in, t_out]` of a ray inside at least one capsule, with the union of the
/// parts (4-bit, [`crate::Part::bit`]) and bones (bit `bone`) of the capsules in it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    pub t_in: f32,
    pub t_out: f32,
    pub part_mask: u8,
    pub bone_mask: u64,
}

/// Intervals of a batch of rays, packed: ray `i` owns
/// `intervals[ray_offsets[i]..ray_offsets[i + 1]]`, sorted and disjoint.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayIntervals {
    pub ray_offsets: Vec<u32>,
    pub intervals: Vec<Interval>,
}

impl RayIntervals {
    pub fn num_rays(&self) -> usize {
        self.ray_offsets.len().saturating_sub(1)
    }

    /// Index range of ray `i` in `intervals`.
    pub fn range(&self, i: usize) -> Range<usize> {
        self.ray_offsets[i] as usize..self.ray_offsets[i + 1] as usize
    }

    /// The intervals of ray `i`.
    pub fn of_ray(&self, i: usize) -> &[Interval] {
        &self.intervals[self.range(i)]
    }
}

/// Sorts `hits` by entry and appends their union to `out` as disjoint intervals;
/// overlapping or touching hits merge. `capsules` gives each hit's part and bone.
pub fn merge_hits(hits: &mut [CapsuleHit], capsules: &[Capsule], out: &mut Vec<Interval>) {
    crate::intersect::sort_hits(hits);
    let mut current: Option<Interval> = None;
    for h in hits.iter() {
        let c = &capsules[h.capsule as usize];
        let (part, bone) = (c.part.bit(), 1u64 << c.bone);
        match &mut current {
            Some(cur) if h.t_in <= cur.t_out => {
                cur.t_out = cur.t_out.max(h.t_out);
                cur.part_mask |= part;
                cur.bone_mask |= bone;
            }
            _ => {
                out.extend(current.take());
                current = Some(Interval {
                    t_in: h.t_in,
                    t_out: h.t_out,
                    part_mask: part,
                    bone_mask: bone,
                });
            }
        }
    }
    out.extend(current);
}

/// Parts and bones of the capsules (among `hits`) whose interval contains `t`: the
/// candidates of a sample at `t`. Capsules are convex, so "the ray is inside the capsule
/// at t" is exactly "t is in its hit interval".
pub fn candidates_at(t: f32, hits: &[CapsuleHit], capsules: &[Capsule]) -> (u8, u64) {
    let mut parts = 0u8;
    let mut bones = 0u64;
    for h in hits {
        if h.t_in <= t && t <= h.t_out {
            let c = &capsules[h.capsule as usize];
            parts |= c.part.bit();
            bones |= 1u64 << c.bone;
        }
    }
    (parts, bones)
}
