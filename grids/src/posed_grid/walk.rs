//! Sampling a [`PosedGrid`]: per ray, one 3D-DDA walk (f32, cell units) records the
//! cells of the stretches worth sampling and where the ray leaves each; the stretches are
//! cut into bins, and every bin reads its cell from that record (no position lookup).

use std::sync::atomic::Ordering;

use glam::{IVec3, Vec3};

use super::{CORE_NEAR, INSIDE, NEAR, OCCUPIED, PosedGrid, SOLID};
use crate::packing::par_pack_samples;
use crate::ray::{clip_to_box, validate_rays};
use crate::rng::SplitMix;
use crate::samples::{PackedSamples, Sample};
use crate::{AcceleratedOpts, GridError, Ray};

/// A cell the walk crossed inside a stretch: where the ray leaves it, and its entries
/// (read during the walk, where the loads overlap with the stepping, rather than by
/// every bin).
#[derive(Clone, Copy)]
struct Crossed {
    t_exit: f32,
    flags: u8,
    parts: u8,
    bones: u64,
}

/// A stretch `[t_a, t_b]` of consecutive cells worth sampling; its cells are the
/// `crossed` entries from the previous stretch's `end` (0 for the first) to its own.
#[derive(Clone, Copy)]
struct Stretch {
    t_a: f32,
    t_b: f32,
    end: u32,
}

/// One worker's per-ray scratch.
#[derive(Default)]
pub(super) struct Walk {
    stretches: Vec<Stretch>,
    crossed: Vec<Crossed>,
}

impl PosedGrid {
    /// Per ray, the stretches inside cells that some grown capsule comes near and that
    /// the canonical grid may keep or that hold a core (a bin there may end the ray), up
    /// to the first solid cell, with the cells they cross. The walk runs in cell units
    /// and recomputes each boundary crossing from the ray (no accumulated error).
    fn walk(&self, ray: &Ray, w: &mut Walk) {
        w.stretches.clear();
        w.crossed.clear();
        let max = self.min + self.res.as_vec3() * self.cell;
        let Some((t0, t1)) = clip_to_box(ray, self.min, max) else {
            return;
        };
        let inv_cell = 1.0 / self.cell;
        let o = (ray.origin - self.min) * inv_cell;
        let d = ray.direction * inv_cell;
        let res = self.res.as_ivec3();
        let mut c = (o + d * t0).floor().as_ivec3().clamp(IVec3::ZERO, res - 1);
        let stride = [res.y * res.z, res.z, 1];
        let mut step = [0i32; 3];
        let mut inv_d = [0.0f32; 3];
        let mut t_next = [f32::INFINITY; 3];
        for k in 0..3 {
            if d[k] > 0.0 {
                step[k] = 1;
            } else if d[k] < 0.0 {
                step[k] = -1;
            }
            if step[k] != 0 {
                inv_d[k] = 1.0 / d[k];
                t_next[k] = crossing(c[k], step[k], o[k], inv_d[k]);
            }
        }
        let mut cell = c.x * stride[0] + c.y * stride[1] + c.z;
        let mut t = t0;
        let mut start: Option<f32> = None;
        let mut t_last = t0;
        loop {
            let axis = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            let t_exit = t_next[axis].min(t1);
            let f = self.resolve(
                cell as usize,
                self.flags[cell as usize].load(Ordering::Relaxed),
                c.as_uvec3(),
            );
            if f & NEAR != 0 && f & (OCCUPIED | SOLID | CORE_NEAR) != 0 {
                start.get_or_insert(t);
                w.crossed.push(Crossed {
                    t_exit,
                    flags: f,
                    parts: self.parts[cell as usize],
                    bones: self.bones[cell as usize],
                });
                t_last = t_exit;
            } else if let Some(a) = start.take() {
                w.stretches.push(Stretch {
                    t_a: a,
                    t_b: t_last,
                    end: w.crossed.len() as u32,
                });
            }
            // Sampling ends in a solid cell at the latest: nothing behind it is kept.
            if t_next[axis] >= t1 || f & SOLID != 0 {
                break;
            }
            t = t_exit;
            c[axis] += step[axis];
            if c[axis] < 0 || c[axis] >= res[axis] {
                break;
            }
            cell += step[axis] * stride[axis];
            t_next[axis] = crossing(c[axis], step[axis], o[axis], inv_d[axis]);
        }
        if let Some(a) = start {
            w.stretches.push(Stretch {
                t_a: a,
                t_b: t_last,
                end: w.crossed.len() as u32,
            });
        }
    }

    /// Samples every ray: stretches in cells near a grown capsule are cut into bins of at
    /// most `opts.step` (stratified jitter as [`crate::sample_in_capsules`]); a bin is
    /// kept if it may hold a point of a grown capsule the canonical grid keeps
    /// ([`PosedGrid::keeps`]), with its cell's candidate parts and bones; the ray ends
    /// after the first bin whose midpoint is inside a core. `opts.step` must not exceed
    /// the `max_step` the grid was built for.
    pub fn sample(&self, rays: &[Ray], opts: &AcceleratedOpts) -> Result<PackedSamples, GridError> {
        validate_rays(rays)?;
        if !(opts.step.is_finite() && opts.step > 0.0 && opts.step <= self.max_step) {
            return Err(GridError::BadOption {
                field: "step",
                value: opts.step,
                expected: "finite, > 0 and <= the posed grid's max_step",
            });
        }
        Ok(par_pack_samples(rays.len(), Walk::default, |w, i, out| {
            let ray = &rays[i];
            self.walk(ray, w);
            let mut rng = SplitMix::new(opts.seed, i as u64);
            let mut first = 0usize;
            'ray: for s in &w.stretches {
                let end = s.end as usize;
                let cells = &w.crossed[first..end];
                first = end;
                let (t_a, t_b) = (s.t_a, s.t_b);
                let length = t_b - t_a;
                if !(length > 0.0) {
                    continue;
                }
                let n = (length / opts.step * (1.0 - 1e-5)).ceil().max(1.0) as u32;
                let width = length / n as f32;
                let mut prev = t_a;
                let mut k = 0usize;
                for j in 1..=n {
                    let b = if j == n {
                        t_b
                    } else {
                        let shift = if opts.jitter {
                            0.9 * (rng.next_f32() - 0.5)
                        } else {
                            0.0
                        };
                        (t_a + (j as f32 + shift) * width).clamp(prev, t_b)
                    };
                    let (a, mid, half) = (prev, 0.5 * (prev + b), 0.5 * (b - prev));
                    prev = b;
                    while k + 1 < cells.len() && cells[k].t_exit < mid {
                        k += 1;
                    }
                    let Crossed {
                        flags: f,
                        parts,
                        bones,
                        ..
                    } = cells[k];
                    let mut p: Option<Vec3> = None;
                    let mut at = || *p.get_or_insert_with(|| ray.at(mid));
                    let keep = f & OCCUPIED != 0
                        && half > 0.0
                        && (f & INSIDE != 0 || self.near_capsule(at(), half, bones));
                    if keep {
                        out.push(Sample {
                            t_start: a,
                            t_end: b,
                            part_mask: parts,
                            bone_mask: bones,
                        });
                    }
                    if f & SOLID != 0 || (f & CORE_NEAR != 0 && self.in_core(at(), bones)) {
                        break 'ray;
                    }
                }
            }
        }))
    }
}

/// Where a ray leaves cell `c` along one axis (origin `o` in cell units, `inv_d` the
/// reciprocal of its direction in cells per metre, `step` its sign).
#[inline]
fn crossing(c: i32, step: i32, o: f32, inv_d: f32) -> f32 {
    let plane = if step > 0 { c + 1 } else { c } as f32;
    (plane - o) * inv_d
}
