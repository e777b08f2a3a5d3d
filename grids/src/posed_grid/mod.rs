//! A per-frame grid over posed space that answers, once per cell (the occupancy part the
//! first time a ray reaches the cell), what the capsule BVH, the solid cores and the
//! canonical occupancy grid would answer per sample:
//! may a capsule be here (and which parts and bones), is the cell solid (behind a
//! surface), and may the canonical grid hold density here. Sampling (`walk.rs`) is then a
//! 3D-DDA walk over the cells that records the ones worth sampling, and bins that read
//! their cell from that record; only samples in cells that straddle a capsule or core
//! surface run exact point tests.
//!
//! Everything is conservative: a sample is dropped only if it provably lies outside every
//! grown capsule, behind a core, or (through every candidate bone's map) in no occupied
//! canonical cell, so it never loses a point the exact pipeline
//! ([`crate::sample_in_front_of_cores`] then [`crate::cull_with_grid`]) keeps.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use glam::{Affine3A, UVec3, Vec3};
use rayon::prelude::*;

use crate::intersect::validate_capsules;
use crate::{Capsule, GridError, OccupancyGrid};

mod walk;

/// Some grown capsule comes within `radius + half cell diagonal + half the longest bin`.
const NEAR: u8 = 1;
/// The whole cell lies inside a grown capsule.
const INSIDE: u8 = 2;
/// Some candidate bone maps the cell (with its reach) near an occupied canonical cell.
/// Worked out for a NEAR cell the first time a ray or query reaches it (see
/// [`PosedGrid::resolve`]), then marked [`KNOWN`].
const OCCUPIED: u8 = 4;
/// The cell's [`OCCUPIED`] bit has been worked out.
const KNOWN: u8 = 32;
/// The whole cell lies inside a core.
const SOLID: u8 = 8;
/// Some core comes within its radius + half a cell diagonal.
const CORE_NEAR: u8 = 16;

/// Most cells a posed grid may have (the cell size grows to stay below it).
pub const MAX_POSED_CELLS: usize = 1 << 22;

/// The canonical side of a [`PosedGrid`]: the subject's occupancy grid, dilated once
/// (see [`DilatedOccupancy::new`]) and shared by the subject's frames, and per bone the
/// posed-to-canonical transform.
pub struct CanonicalCull {
    pub grid: Arc<DilatedOccupancy>,
    /// Indexed by bone; must be rigid (rotation + translation) and cover every bone of
    /// the capsules.
    pub canonical_from_posed: Vec<Affine3A>,
}

/// An occupancy grid's bitfield grown by `cells` cells along every axis, one byte per
/// cell for a fast lookup; points up to `cells` cells outside the box clamp to the
/// border cell.
pub struct DilatedOccupancy {
    min: Vec3,
    inv_cell: Vec3,
    res: UVec3,
    cells: u32,
    occupied: Vec<u8>,
    source_fingerprint: u64,
}

impl DilatedOccupancy {
    /// Dilates `grid` by enough cells that every canonical point within `reach` of an
    /// occupied cell lands in an occupied cell.
    pub fn new(grid: &OccupancyGrid, reach: f32) -> Result<DilatedOccupancy, GridError> {
        if !(reach.is_finite() && reach >= 0.0) {
            return Err(GridError::BadOption {
                field: "reach",
                value: reach,
                expected: "finite and >= 0",
            });
        }
        let size = grid.cell_size();
        let cells = (reach / size.min_element()).ceil() as u32;
        let res = UVec3::from(grid.resolution());
        let (rx, ry, rz) = (res.x as usize, res.y as usize, res.z as usize);
        let mut a: Vec<u8> = (0..grid.num_cells())
            .map(|i| grid.is_cell_occupied(i) as u8)
            .collect();
        let mut b = a.clone();
        for _ in 0..cells {
            // z: within rows.
            for (dst, src) in b.chunks_mut(rz).zip(a.chunks(rz)) {
                for z in 0..rz {
                    dst[z] = src[z] | src[z.saturating_sub(1)] | src[(z + 1).min(rz - 1)];
                }
            }
            std::mem::swap(&mut a, &mut b);
            // y and x: whole rows / slabs at once.
            for (stride, len) in [(rz, ry), (ry * rz, rx)] {
                b.copy_from_slice(&a);
                let block = stride * len;
                for (dst, src) in b.chunks_mut(block).zip(a.chunks(block)) {
                    for k in 0..len {
                        let here = &mut dst[k * stride..(k + 1) * stride];
                        for n in [k.wrapping_sub(1), k + 1] {
                            if n < len {
                                let other = &src[n * stride..(n + 1) * stride];
                                here.iter_mut().zip(other).for_each(|(h, o)| *h |= o);
                            }
                        }
                    }
                }
                std::mem::swap(&mut a, &mut b);
            }
        }
        let (min, max) = grid.aabb();
        Ok(DilatedOccupancy {
            min,
            inv_cell: res.as_vec3() / (max - min),
            res,
            cells,
            occupied: a,
            source_fingerprint: grid.fingerprint(),
        })
    }

    /// How far (metres) the dilation reaches past the occupied cells: whole cells, at
    /// least the `reach` asked for.
    pub fn reach(&self) -> f32 {
        self.cells as f32 / self.inv_cell.max_element()
    }

    /// [`OccupancyGrid::fingerprint`] of the grid this was made from.
    pub fn source_fingerprint(&self) -> u64 {
        self.source_fingerprint
    }

    /// Whether `p_canonical` lies in a cell of the dilated set (points within the
    /// dilation outside the box count as their border cell).
    #[inline]
    pub fn is_occupied(&self, p_canonical: Vec3) -> bool {
        let f = (p_canonical - self.min) * self.inv_cell;
        let lo = -(self.cells as f32);
        let hi = self.res.as_vec3() + self.cells as f32;
        if !(f.cmpge(Vec3::splat(lo)).all() && f.cmplt(hi).all()) {
            return false;
        }
        let c = f.max(Vec3::ZERO).as_uvec3().min(self.res - 1);
        let i = (c.x as usize * self.res.y as usize + c.y as usize) * self.res.z as usize
            + c.z as usize;
        self.occupied[i] != 0
    }
}

/// A capsule's segment prepared for repeated squared-distance queries.
#[derive(Clone, Copy)]
struct Seg {
    a: Vec3,
    ab: Vec3,
    inv_len2: f32,
    radius: f32,
}

impl Seg {
    fn new(c: &Capsule) -> Seg {
        let ab = c.b - c.a;
        let l2 = ab.length_squared();
        Seg {
            a: c.a,
            ab,
            inv_len2: if l2 > 0.0 { 1.0 / l2 } else { 0.0 },
            radius: c.radius,
        }
    }

    #[inline]
    fn dist2(&self, p: Vec3) -> f32 {
        let ap = p - self.a;
        let s = (ap.dot(self.ab) * self.inv_len2).clamp(0.0, 1.0);
        (ap - s * self.ab).length_squared()
    }
}

/// Radius padding of [`Columns::z_span`] for sets that must cover every cell the exact
/// centre test holds (NEAR, CORE_NEAR: dropping one could lose a surface point), and for
/// sets that must hold no cell it rejects (INSIDE, SOLID: a wrong SOLID cell would end a ray
/// early). 0.1 mm against float rounding in the interval's solve; cells are ~1 cm.
const COVER: f64 = 1e-4;
const SHRINK: f64 = -1e-4;

/// A capsule's segment prepared (f64) for [`Columns::z_span`], solved for many columns.
struct Columns {
    a: glam::DVec3,
    b: glam::DVec3,
    /// Unit axis and length (`len == 0`: a sphere).
    u: glam::DVec3,
    len: f64,
}

impl Columns {
    fn new(c: &Capsule) -> Columns {
        let (a, b) = (c.a.as_dvec3(), c.b.as_dvec3());
        let len = (b - a).length();
        let u = if len > 0.0 {
            (b - a) / len
        } else {
            glam::DVec3::ZERO
        };
        Columns { a, b, u, len }
    }

    /// The `z` range of the line `(x, y, z)` within `radius + pad` of the segment
    /// (`None` if it never comes that close): a capsule is convex, so the line meets it
    /// in one interval, the union of its meetings with the two end spheres and the
    /// cylinder between them. Solved in f64.
    fn z_span(&self, x: f32, y: f32, radius: f32, pad: f64) -> Option<(f64, f64)> {
        let r = radius as f64 + pad;
        if !(r > 0.0) {
            return None;
        }
        let (a, u, len) = (self.a, self.u, self.len);
        let (x, y) = (x as f64, y as f64);
        let mut span: Option<(f64, f64)> = None;
        let mut add = |lo: f64, hi: f64| {
            span = Some(match span {
                None => (lo, hi),
                Some((l, h)) => (l.min(lo), h.max(hi)),
            });
        };
        for end in [a, self.b] {
            let q = r * r - (x - end.x).powi(2) - (y - end.y).powi(2);
            if q >= 0.0 {
                add(end.z - q.sqrt(), end.z + q.sqrt());
            }
        }
        if len > 0.0 {
            // w(z) = P(z) - a = w0 + z e_z; along the axis p + z uz, across it f(z).
            let w0 = glam::DVec3::new(x - a.x, y - a.y, -a.z);
            let p = w0.dot(u);
            let qa = 1.0 - u.z * u.z;
            let qb = 2.0 * (w0.z - p * u.z);
            let qc = w0.length_squared() - p * p - r * r;
            // Where the line is within r of the infinite axis.
            let across = if qa < 1e-12 {
                // Parallel to the axis: the distance to it does not change along z.
                (qc <= 0.0).then_some((f64::NEG_INFINITY, f64::INFINITY))
            } else {
                let disc = qb * qb - 4.0 * qa * qc;
                (disc >= 0.0).then(|| {
                    let root = disc.sqrt();
                    ((-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa))
                })
            };
            // Where its projection falls between the ends.
            let along = if u.z.abs() < 1e-12 {
                (0.0..=len)
                    .contains(&p)
                    .then_some((f64::NEG_INFINITY, f64::INFINITY))
            } else {
                let (z0, z1) = (-p / u.z, (len - p) / u.z);
                Some((z0.min(z1), z0.max(z1)))
            };
            if let (Some((a0, a1)), Some((b0, b1))) = (across, along) {
                let (lo, hi) = (a0.max(b0), a1.min(b1));
                if lo <= hi {
                    add(lo, hi);
                }
            }
        }
        span
    }
}

#[allow(clippy::reversed_empty_ranges)]
/// The cells `lo..=hi` along z whose centres (`z_min + (k + 0.5) cell`) lie in `span`.
fn cells_in(
    span: (f64, f64),
    z_min: f32,
    cell: f32,
    lo: u32,
    hi: u32,
) -> std::ops::RangeInclusive<u32> {
    let (z_min, cell) = (z_min as f64, cell as f64);
    let first = ((span.0 - z_min) / cell - 0.5).ceil().max(lo as f64);
    let last = ((span.1 - z_min) / cell - 0.5).floor().min(hi as f64);
    if first > last {
        return 1..=0;
    }
    first as u32..=last as u32
}

/// One frame's posed sampling grid. See the module docs.
pub struct PosedGrid {
    min: Vec3,
    cell: f32,
    res: UVec3,
    /// Per cell the bits above; [`OCCUPIED`] and [`KNOWN`] are set lazily, from any
    /// thread (a pure function of the cell, so the order does not matter).
    flags: Vec<AtomicU8>,
    parts: Vec<u8>,
    bones: Vec<u64>,
    /// Per bone: its grown capsules and cores.
    capsules_of_bone: Vec<Vec<Seg>>,
    cores_of_bone: Vec<Vec<Seg>>,
    /// Longest bin the grid is valid for (see [`PosedGrid::build`]).
    max_step: f32,
    cull: Option<CanonicalCull>,
}

impl PosedGrid {
    /// Builds the grid over the grown `capsules` (plus the cells' reach), with `cores`,
    /// for samplers whose step is at most `max_step` (jittered bins are at most 1.9
    /// steps long). `cell` is the cell edge in metres (grown if the grid would exceed
    /// [`MAX_POSED_CELLS`]). Without `cull`, no cell is culled by occupancy. The cull's
    /// dilation must cover half a cell diagonal plus 0.95 `max_step`
    /// ([`PosedGrid::cull_reach`]).
    pub fn build(
        capsules: &[Capsule],
        cores: &[Capsule],
        cull: Option<CanonicalCull>,
        cell: f32,
        max_step: f32,
    ) -> Result<PosedGrid, GridError> {
        validate_capsules(capsules)?;
        validate_capsules(cores)?;
        for (field, v) in [("cell", cell), ("max_step", max_step)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(GridError::BadOption {
                    field,
                    value: v,
                    expected: "finite and > 0",
                });
            }
        }
        let half_bin = 0.95 * max_step;
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for c in capsules {
            lo = lo.min(c.a.min(c.b) - c.radius);
            hi = hi.max(c.a.max(c.b) + c.radius);
        }
        if capsules.is_empty() {
            (lo, hi) = (Vec3::ZERO, Vec3::ONE);
        }
        let extent = hi - lo + 2.0 * half_bin;
        let mut cell = cell;
        let cells_for = |cell: f32| (extent / cell).ceil().max(Vec3::ONE);
        while cells_for(cell).x as f64 * cells_for(cell).y as f64 * cells_for(cell).z as f64
            > MAX_POSED_CELLS as f64
        {
            cell *= 1.25;
        }
        let res = cells_for(cell).as_uvec3();
        let min = lo - half_bin;
        let h = 0.5 * cell * 3f32.sqrt();
        if let Some(cull) = &cull {
            let need = Self::cull_reach(cell, max_step);
            let have = cull.grid.reach();
            if have < need * (1.0 - 1e-4) {
                return Err(GridError::BadOption {
                    field: "cull dilation (metres)",
                    value: have,
                    expected: "at least half a posed cell diagonal + 0.95 max_step",
                });
            }
            let max_bone = capsules.iter().map(|c| c.bone as usize).max().unwrap_or(0);
            if cull.canonical_from_posed.len() <= max_bone {
                return Err(GridError::LengthMismatch {
                    what: "canonical_from_posed (one per bone)",
                    expected: max_bone + 1,
                    got: cull.canonical_from_posed.len(),
                });
            }
            for (i, m) in cull.canonical_from_posed.iter().enumerate() {
                let m3 = glam::Mat3::from(m.matrix3);
                let rigid = (m3.transpose() * m3 - glam::Mat3::IDENTITY)
                    .to_cols_array()
                    .iter()
                    .all(|e| e.abs() < 1e-3);
                if !(m.is_finite() && rigid) {
                    return Err(GridError::NonFiniteValue {
                        what: "rigid canonical_from_posed of bone",
                        index: i,
                    });
                }
            }
        }
        let mut capsules_of_bone = vec![Vec::new(); 64];
        for c in capsules {
            capsules_of_bone[c.bone as usize].push(Seg::new(c));
        }
        let mut cores_of_bone = vec![Vec::new(); 64];
        for c in cores {
            cores_of_bone[c.bone as usize].push(Seg::new(c));
        }
        let n = (res.x * res.y * res.z) as usize;
        let slab = (res.y * res.z) as usize;
        let mut flags: Vec<AtomicU8> = (0..n).map(|_| AtomicU8::new(0)).collect();
        let mut parts = vec![0u8; n];
        let mut bones = vec![0u64; n];
        // The cell range of a capsule grown by `reach`.
        let range = |c: &Capsule, reach: f32| {
            let a = ((c.a.min(c.b) - c.radius - reach - min) / cell).floor();
            let b = ((c.a.max(c.b) + c.radius + reach - min) / cell).floor();
            (
                a.max(Vec3::ZERO).as_uvec3(),
                b.min((res - 1).as_vec3()).max(Vec3::ZERO).as_uvec3(),
            )
        };
        // Per capsule (and core): its column solver and cell range, once per build.
        let prepared = |list: &[Capsule], reach: f32| -> Vec<(Capsule, Columns, UVec3, UVec3)> {
            list.iter()
                .map(|c| {
                    let (lo, hi) = range(c, reach);
                    (*c, Columns::new(c), lo, hi)
                })
                .collect()
        };
        let capsule_columns = prepared(capsules, h + half_bin);
        let core_columns = prepared(cores, h);
        flags
            .par_chunks_mut(slab)
            .zip(parts.par_chunks_mut(slab))
            .zip(bones.par_chunks_mut(slab))
            .enumerate()
            .for_each(|(x, ((flags, parts), bones))| {
                let x = x as u32;
                // Per capsule and (x, y) column, the cells whose centres lie within a
                // radius are a z-range (a line meets a capsule in one interval): solved
                // once per column instead of testing every cell of the capsule's box.
                let cx = min.x + (x as f32 + 0.5) * cell;
                for (c, columns, lo, hi) in &capsule_columns {
                    let (lo, hi) = (*lo, *hi);
                    if x < lo.x || x > hi.x {
                        continue;
                    }
                    let near = c.radius + h + half_bin;
                    let inside = c.radius - h;
                    for y in lo.y..=hi.y {
                        let cy = min.y + (y as f32 + 0.5) * cell;
                        let Some(span) = columns.z_span(cx, cy, near, COVER) else {
                            continue;
                        };
                        let row = (y * res.z) as usize;
                        let cells = cells_in(span, min.z, cell, lo.z, hi.z);
                        let zs = row + *cells.start() as usize..row + *cells.end() as usize + 1;
                        if !cells.is_empty() {
                            let (part, bone) = (c.part.bit(), 1u64 << c.bone);
                            flags[zs.clone()]
                                .iter_mut()
                                .for_each(|f| *f.get_mut() |= NEAR);
                            parts[zs.clone()].iter_mut().for_each(|p| *p |= part);
                            bones[zs].iter_mut().for_each(|b| *b |= bone);
                        }
                        if inside > 0.0
                            && let Some(span) = columns.z_span(cx, cy, inside, SHRINK)
                        {
                            for z in cells_in(span, min.z, cell, lo.z, hi.z) {
                                *flags[row + z as usize].get_mut() |= INSIDE;
                            }
                        }
                    }
                }
                for (c, columns, lo, hi) in &core_columns {
                    let (lo, hi) = (*lo, *hi);
                    if x < lo.x || x > hi.x {
                        continue;
                    }
                    let solid = c.radius - h;
                    for y in lo.y..=hi.y {
                        let cy = min.y + (y as f32 + 0.5) * cell;
                        let Some(span) = columns.z_span(cx, cy, c.radius + h, COVER) else {
                            continue;
                        };
                        let row = (y * res.z) as usize;
                        let solid_span = if solid > 0.0 {
                            columns.z_span(cx, cy, solid, SHRINK)
                        } else {
                            None
                        };
                        for z in cells_in(span, min.z, cell, lo.z, hi.z) {
                            *flags[row + z as usize].get_mut() |= CORE_NEAR;
                        }
                        if let Some(span) = solid_span {
                            for z in cells_in(span, min.z, cell, lo.z, hi.z) {
                                *flags[row + z as usize].get_mut() |= SOLID;
                            }
                        }
                    }
                }
            });
        Ok(PosedGrid {
            min,
            cell,
            res,
            flags,
            parts,
            bones,
            capsules_of_bone,
            cores_of_bone,
            max_step,
            cull,
        })
    }

    /// `f`, the flags of `cell` (at grid coordinates `c`), with [`OCCUPIED`] worked out
    /// if it is a NEAR cell whose bit is not yet known: whether some candidate bone maps
    /// the cell's centre into the dilated canonical grid (always, without a cull).
    /// Done on first use, not in [`PosedGrid::build`]: a frame's rays reach a fraction
    /// of its cells (they stop at the first solid cell), and a training step's 512 rays
    /// a small one.
    #[inline]
    pub(super) fn resolve(&self, cell: usize, f: u8, c: UVec3) -> u8 {
        if f & (NEAR | KNOWN) != NEAR {
            return f;
        }
        let occupied = match &self.cull {
            None => true,
            Some(cull) => {
                let p = self.min + (c.as_vec3() + 0.5) * self.cell;
                let mut bits = self.bones[cell];
                let mut hit = false;
                while bits != 0 && !hit {
                    let b = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    hit = cull
                        .grid
                        .is_occupied(cull.canonical_from_posed[b].transform_point3(p));
                }
                hit
            }
        };
        let add = KNOWN | if occupied { OCCUPIED } else { 0 };
        self.flags[cell].fetch_or(add, Ordering::Relaxed);
        f | add
    }

    /// The canonical dilation (metres) a [`CanonicalCull`] needs for cells of edge `cell`
    /// and steps up to `max_step`: a sample's points lie within half a cell diagonal +
    /// half the longest bin of its cell's centre, and rigid maps keep distances.
    pub fn cull_reach(cell: f32, max_step: f32) -> f32 {
        0.5 * cell * 3f32.sqrt() + 0.95 * max_step
    }

    /// The cell edge in metres.
    pub fn cell(&self) -> f32 {
        self.cell
    }

    /// The index of the cell holding `p` and its flags (resolved), if `p` is in the grid.
    fn cell_at(&self, p: Vec3) -> Option<(usize, u8)> {
        let f = (p - self.min) / self.cell;
        let res = self.res.as_vec3();
        if !(f.cmpge(Vec3::ZERO).all() && f.cmplt(res).all()) {
            return None;
        }
        let c = f.as_uvec3().min(self.res - 1);
        let i = ((c.x * self.res.y + c.y) * self.res.z + c.z) as usize;
        Some((i, self.resolve(i, self.flags[i].load(Ordering::Relaxed), c)))
    }

    /// Whether a sample around `p` reaching `half` metres either side could hold a point
    /// of a grown capsule that the canonical grid keeps: what decides if it is emitted.
    pub fn keeps(&self, p: Vec3, half: f32) -> bool {
        self.cell_at(p).is_some_and(|(i, f)| {
            f & NEAR != 0
                && f & OCCUPIED != 0
                && (f & INSIDE != 0 || self.near_capsule(p, half, self.bones[i]))
        })
    }

    /// Whether `p` is provably inside a core (behind a surface).
    pub fn is_solid(&self, p: Vec3) -> bool {
        self.cell_at(p).is_some_and(|(i, f)| {
            f & SOLID != 0 || (f & CORE_NEAR != 0 && self.in_core(p, self.bones[i]))
        })
    }

    #[inline]
    fn near_capsule(&self, p: Vec3, half: f32, mut bones: u64) -> bool {
        while bones != 0 {
            let b = bones.trailing_zeros() as usize;
            bones &= bones - 1;
            for s in &self.capsules_of_bone[b] {
                let r = s.radius + half;
                if s.dist2(p) <= r * r * (1.0 + 1e-5) {
                    return true;
                }
            }
        }
        false
    }

    #[inline]
    fn in_core(&self, p: Vec3, mut bones: u64) -> bool {
        while bones != 0 {
            let b = bones.trailing_zeros() as usize;
            bones &= bones - 1;
            for s in &self.cores_of_bone[b] {
                if s.dist2(p) <= s.radius * s.radius * (1.0 - 1e-5) {
                    return true;
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use glam::{Quat, vec3};

    use super::*;
    use crate::rng::SplitMix;
    use crate::{AcceleratedOpts, PackedSamples, Part, Ray, ray_capsule, sample_in_front_of_cores};

    /// Three limbs of different bones, their cores, and per bone a rigid map.
    fn scene() -> (Vec<Capsule>, Vec<Capsule>, Vec<Affine3A>) {
        let limb = |a: Vec3, b: Vec3, radius: f32, part: Part, bone: u16| Capsule {
            a,
            b,
            radius,
            part,
            bone,
        };
        let capsules = vec![
            limb(
                vec3(0.0, 0.0, 0.0),
                vec3(0.0, 0.5, 0.0),
                0.15,
                Part::Body,
                3,
            ),
            limb(
                vec3(0.0, 0.5, 0.0),
                vec3(0.3, 0.6, 0.0),
                0.06,
                Part::Arms,
                16,
            ),
            limb(
                vec3(0.3, 0.6, 0.0),
                vec3(0.4, 0.6, 0.02),
                0.02,
                Part::Hands,
                20,
            ),
        ];
        let cores = capsules
            .iter()
            .map(|c| Capsule {
                radius: 0.6 * c.radius,
                ..*c
            })
            .collect();
        let maps = (0..64)
            .map(|b| {
                let angle = 0.1 * b as f32;
                Affine3A::from_rotation_translation(
                    Quat::from_axis_angle(vec3(0.3, 1.0, 0.2).normalize(), angle),
                    vec3(0.01 * b as f32, -0.02, 0.05),
                )
            })
            .collect();
        (capsules, cores, maps)
    }

    /// A reproducible point stream in a box.
    fn points(n: usize, lo: Vec3, hi: Vec3) -> Vec<Vec3> {
        let mut rng = SplitMix::new(5, 0);
        (0..n)
            .map(|_| lo + (hi - lo) * vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect()
    }

    /// A canonical grid of a few random blobs, so some of posed space is culled, and a
    /// builder of [`scene`]'s posed grid culled by it (cells 2 cm, steps 6 mm).
    fn culled_scene() -> (OccupancyGrid, impl Fn() -> PosedGrid) {
        let (capsules, cores, maps) = scene();
        let mut canonical =
            OccupancyGrid::new(vec3(-0.6, -0.4, -0.6), vec3(0.8, 1.0, 0.6), [40; 3]).unwrap();
        canonical.mark(&points(4000, vec3(-0.6, -0.4, -0.6), vec3(0.8, 1.0, 0.6)));
        let (cell, step) = (0.02, 0.006);
        let dilated =
            Arc::new(DilatedOccupancy::new(&canonical, PosedGrid::cull_reach(cell, step)).unwrap());
        let build = move || {
            let cull = CanonicalCull {
                grid: dilated.clone(),
                canonical_from_posed: maps.clone(),
            };
            PosedGrid::build(&capsules, &cores, Some(cull), cell, step).unwrap()
        };
        (canonical, build)
    }

    #[test]
    fn never_culls_a_point_the_exact_map_keeps() {
        let (capsules, _, maps) = scene();
        let (canonical, build) = culled_scene();
        let grid = build();
        let (mut kept, mut culled) = (0, 0);
        for p in points(200_000, vec3(-0.3, -0.2, -0.2), vec3(0.5, 0.8, 0.2)) {
            // The exact map: any bone whose capsule holds p (the nearest-bone map picks
            // one of them).
            let exact = capsules.iter().any(|c| {
                crate::intersect::signed_distance(p, c) <= 0.0
                    && canonical.is_occupied(maps[c.bone as usize].transform_point3(p))
            });
            let inside = capsules
                .iter()
                .any(|c| crate::intersect::signed_distance(p, c) <= 0.0);
            if exact {
                assert!(grid.keeps(p, 0.0), "culled {p}, which the exact map keeps");
                kept += 1;
            } else if inside && !grid.keeps(p, 0.0) {
                culled += 1;
            }
        }
        assert!(kept > 1000 && culled > 1000, "kept {kept}, culled {culled}");
    }

    /// The cull is worked out per cell on first use, from whichever thread gets there:
    /// a grid queried in another order first samples exactly the same.
    #[test]
    fn lazy_cull_does_not_depend_on_query_order() {
        let (_, build) = culled_scene();
        let (fresh, queried) = (build(), build());
        let kept = points(50_000, vec3(-0.3, -0.2, -0.2), vec3(0.5, 0.8, 0.2))
            .iter()
            .rev()
            .filter(|&&p| queried.keeps(p, 0.0))
            .count();
        assert!(kept > 100);
        let mut rng = SplitMix::new(31, 0);
        let rays: Vec<Ray> = (0..300)
            .map(|_| {
                let target = vec3(rng.next_f32() * 0.6 - 0.2, rng.next_f32() * 0.8, 0.0);
                let origin = vec3(0.0, 0.3, -2.0);
                Ray::new(origin, target - origin, 0.0, f32::INFINITY).unwrap()
            })
            .collect();
        let opts = AcceleratedOpts {
            step: 0.006,
            jitter: true,
            seed: 1,
        };
        let a = fresh.sample(&rays, &opts).unwrap();
        assert!(a.num_samples() > 1000);
        assert_eq!(a, queried.sample(&rays, &opts).unwrap());
        assert_eq!(a, fresh.sample(&rays, &opts).unwrap());
    }

    #[test]
    fn samples_hold_every_capsule_point_in_front_of_the_cores() {
        let (capsules, cores, _) = scene();
        let step = 0.005;
        let grid = PosedGrid::build(&capsules, &cores, None, 0.0125, step).unwrap();
        let mut rays = Vec::new();
        let mut rng = SplitMix::new(11, 1);
        for _ in 0..400 {
            let target = vec3(
                -0.2 + 0.7 * rng.next_f32(),
                -0.1 + 0.8 * rng.next_f32(),
                -0.1 + 0.2 * rng.next_f32(),
            );
            let origin = vec3(0.5 * rng.next_f32() - 0.25, 0.3, -2.0);
            rays.push(Ray::new(origin, target - origin, 0.0, f32::INFINITY).unwrap());
        }
        let opts = AcceleratedOpts {
            step,
            jitter: true,
            seed: 3,
        };
        let samples = grid.sample(&rays, &opts).unwrap();
        assert_covers(&samples, &rays, &capsules, &cores, 1.0..3.0);
        // No more samples than the exact BVH pipeline, give or take a bin per stretch.
        let bvh = crate::CapsuleBvh::build(&capsules).unwrap();
        let core_bvh = crate::CapsuleBvh::build(&cores).unwrap();
        let exact = sample_in_front_of_cores(&bvh, &core_bvh, &rays, 0.0, &opts).unwrap();
        assert!(
            samples.num_samples() as f64 <= 1.1 * exact.num_samples() as f64 + 2.0 * 400.0,
            "{} vs {}",
            samples.num_samples(),
            exact.num_samples()
        );
        // Bad input is an error.
        let too_long = AcceleratedOpts { step: 0.01, ..opts };
        assert!(grid.sample(&rays, &too_long).is_err());
        let bad = Ray {
            origin: Vec3::NAN,
            ..rays[0]
        };
        assert!(grid.sample(&[bad], &opts).is_err());
        assert!(PosedGrid::build(&capsules, &cores, None, f32::NAN, step).is_err());
    }

    /// Every point of `t_range` along each ray that lies inside a capsule and in front of
    /// every core is inside one of the ray's samples.
    fn assert_covers(
        samples: &PackedSamples,
        rays: &[Ray],
        capsules: &[Capsule],
        cores: &[Capsule],
        t_range: std::ops::Range<f32>,
    ) {
        samples.check_layout().unwrap();
        for (i, ray) in rays.iter().enumerate() {
            let core_entry = cores
                .iter()
                .filter_map(|c| ray_capsule(ray, c))
                .map(|(t, _)| t)
                .fold(f32::INFINITY, f32::min);
            for k in 0..4000 {
                let t = t_range.start + (t_range.end - t_range.start) * k as f32 / 4000.0;
                let p = ray.at(t);
                let in_capsule = capsules
                    .iter()
                    .any(|c| crate::intersect::signed_distance(p, c) < -1e-5);
                if in_capsule && t < core_entry {
                    assert!(
                        samples
                            .range(i)
                            .any(|s| samples.t_start[s] <= t && t <= samples.t_end[s]),
                        "ray {i} ({ray:?}): t {t} in a capsule before the cores is in no sample"
                    );
                }
            }
        }
    }

    /// The walk's hard cases: rays parallel to the grid's axes (zero direction
    /// components), rays starting inside a grown capsule, rays through cell corners.
    #[test]
    fn walk_covers_axis_parallel_inside_and_corner_rays() {
        let (capsules, cores, _) = scene();
        let (cell, step) = (0.0125, 0.005);
        let grid = PosedGrid::build(&capsules, &cores, None, cell, step).unwrap();
        let mut rays = Vec::new();
        let ray = |o: Vec3, d: Vec3| Ray::new(o, d, 0.0, f32::INFINITY).unwrap();
        for a in 0..12 {
            for b in 0..12 {
                let (u, v) = (-0.2 + 0.06 * a as f32, -0.05 + 0.06 * b as f32);
                rays.push(ray(vec3(u, v, -1.0), Vec3::Z));
                rays.push(ray(vec3(-1.0, v, 0.02 * b as f32 - 0.1), Vec3::X));
                rays.push(ray(vec3(u, 1.5, 0.02 * a as f32 - 0.1), -Vec3::Y));
            }
        }
        // Inside the grown body capsule, outside its core, in every direction.
        let mut rng = SplitMix::new(23, 4);
        for _ in 0..60 {
            let d = vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            rays.push(ray(vec3(0.12, 0.25, 0.0), d));
        }
        // Along cell diagonals, starting on a cell corner.
        let corner = grid.min + Vec3::splat(4.0 * grid.cell);
        for d in [
            vec3(1.0, 1.0, 1.0),
            vec3(1.0, 1.0, 0.0),
            vec3(1.0, 0.0, 1.0),
        ] {
            rays.push(ray(corner, d));
        }
        let opts = AcceleratedOpts {
            step,
            jitter: true,
            seed: 9,
        };
        let samples = grid.sample(&rays, &opts).unwrap();
        assert_covers(&samples, &rays, &capsules, &cores, 0.0..2.5);
        assert!(samples.num_samples() > 1000);
    }

    /// The column solve against the per-point distance test, for capsules in every
    /// orientation (along z, across it, oblique, spheres), on lines through and past
    /// them: a z in the span is within the radius (up to the padding) and a z within the
    /// radius is in the span.
    #[test]
    fn z_spans_match_the_distance_test() {
        let mut rng = SplitMix::new(17, 2);
        let mut capsules = vec![
            // Along z, across it, a sphere.
            Capsule {
                a: vec3(0.0, 0.0, -0.2),
                b: vec3(0.0, 0.0, 0.3),
                radius: 0.1,
                part: crate::Part::Body,
                bone: 0,
            },
            Capsule {
                a: vec3(-0.3, 0.1, 0.05),
                b: vec3(0.3, 0.1, 0.05),
                radius: 0.05,
                part: crate::Part::Arms,
                bone: 1,
            },
            Capsule {
                a: vec3(0.1, 0.1, 0.1),
                b: vec3(0.1, 0.1, 0.1),
                radius: 0.07,
                part: crate::Part::Hands,
                bone: 2,
            },
        ];
        for _ in 0..40 {
            let p = |rng: &mut SplitMix| {
                vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.6 - 0.3
            };
            let (a, b) = (p(&mut rng), p(&mut rng));
            capsules.push(Capsule {
                a,
                b,
                radius: 0.02 + 0.1 * rng.next_f32(),
                part: crate::Part::Body,
                bone: 3,
            });
        }
        let mut inside = 0;
        for c in &capsules {
            let seg = Seg::new(c);
            for _ in 0..60 {
                let (x, y) = (0.8 * rng.next_f32() - 0.4, 0.8 * rng.next_f32() - 0.4);
                let columns = Columns::new(c);
                let cover = columns.z_span(x, y, c.radius, COVER);
                let shrink = columns.z_span(x, y, c.radius, SHRINK);
                for k in 0..400 {
                    let z = -0.5 + k as f32 / 400.0;
                    let d = seg.dist2(vec3(x, y, z)).sqrt();
                    let within = |s: Option<(f64, f64)>| {
                        s.is_some_and(|(lo, hi)| lo <= z as f64 && z as f64 <= hi)
                    };
                    if d <= c.radius {
                        inside += 1;
                        assert!(within(cover), "{c:?} ({x}, {y}, {z}) at {d} not covered");
                    }
                    if within(shrink) {
                        assert!(
                            d <= c.radius,
                            "{c:?} ({x}, {y}, {z}) at {d} in the shrunk span"
                        );
                    }
                    if within(cover) {
                        assert!(d <= c.radius + 2e-4, "{c:?} ({x}, {y}, {z}) at {d} covered");
                    }
                }
            }
        }
        assert!(inside > 10_000, "only {inside} points inside");
        // Cell ranges: centres inside the span, clamped to the asked cells.
        assert_eq!(cells_in((0.0, 1.0), 0.0, 0.1, 0, 100), 0..=9);
        assert_eq!(cells_in((0.04, 0.26), 0.0, 0.1, 0, 100), 0..=2);
        assert!(cells_in((0.06, 0.14), 0.0, 0.1, 0, 100).is_empty());
        assert_eq!(cells_in((-5.0, 5.0), 0.0, 0.1, 3, 7), 3..=7);
        assert!(cells_in((2.0, 3.0), 0.0, 0.1, 0, 5).is_empty());
    }

    #[test]
    fn dilation_matches_the_reference() {
        let mut g = OccupancyGrid::new(Vec3::ZERO, vec3(1.0, 0.8, 0.6), [10, 8, 6]).unwrap();
        g.mark(&points(12, Vec3::ZERO, vec3(1.0, 0.8, 0.6)));
        for reach in [0.0, 0.1, 0.25] {
            let d = DilatedOccupancy::new(&g, reach).unwrap();
            let mut reference = g.clone();
            reference.dilate(d.cells);
            for i in 0..g.num_cells() {
                let p = g.cell_point(i, Vec3::splat(0.5));
                assert_eq!(
                    d.is_occupied(p),
                    reference.is_cell_occupied(i),
                    "{reach} {p}"
                );
            }
            assert!(d.reach() >= reach);
        }
        assert!(DilatedOccupancy::new(&g, f32::NAN).is_err());
    }
}
