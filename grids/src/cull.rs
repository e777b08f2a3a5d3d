//! The canonical occupancy grid as the accelerated sampler reads it: dilated by the reach
//! of a bin (and the pose slack the engine asks for), stored as bits, and reached through
//! each bone's rigid posed-to-canonical map. Conservative by construction: a bin is
//! dropped only if every candidate bone maps its midpoint farther than the dilation
//! from every occupied cell.
//!
//! Beside the bits, the optical depth the field gave each cell
//! ([`OccupancyGrid::depth_code`]), undilated: the sampler adds it up along a ray and
//! stops the ray the dilation's reach past the point where its light is spent.

use std::sync::Arc;

use glam::{Affine3A, UVec3, Vec3};

use crate::occupancy::DEPTH_CODES_PER_UNIT;
use crate::{Capsule, GridError, OccupancyGrid};

/// The canonical side of the accelerated sampler's cull: the subject's occupancy grid,
/// dilated once (see [`DilatedOccupancy::new`]) and shared by the subject's frames, and
/// per bone the frame's posed-to-canonical transform.
pub struct CanonicalCull {
    pub grid: Arc<DilatedOccupancy>,
    /// Indexed by bone; must be rigid (rotation + translation) and cover every bone of
    /// the capsules.
    pub canonical_from_posed: Vec<Affine3A>,
    /// Whether rays also stop where the grid's densities spend them (see
    /// [`crate::sampler_accelerated`]); the grid's bits cull either way.
    pub stop_where_spent: bool,
}

/// An occupancy grid's bitfield grown by `cells` cells along every axis; points up to
/// `cells` cells outside the box clamp to the border cell.
pub struct DilatedOccupancy {
    min: Vec3,
    inv_cell: Vec3,
    res: UVec3,
    cells: u32,
    /// One bit per cell (cell `i` is bit `i % 64` of word `i / 64`): a 128^3 grid is
    /// 256 KiB, small enough to stay in a core's cache while rays look it up.
    occupied: Vec<u64>,
    /// Per cell, [`OccupancyGrid::depth_code`] (same indexing as the grid's cells).
    depth: Vec<u8>,
    /// Optical depth per metre of one depth code: 1 / (16 x the smallest cell side).
    depth_per_code_m: f32,
    /// Whether any cell has a depth code above 0.
    any_depth: bool,
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
        let mut occupied = vec![0u64; a.len().div_ceil(64)];
        for (i, &o) in a.iter().enumerate() {
            occupied[i / 64] |= ((o != 0) as u64) << (i % 64);
        }
        let depth: Vec<u8> = (0..grid.num_cells()).map(|i| grid.depth_code(i)).collect();
        let any_depth = depth.iter().any(|&d| d > 0);
        Ok(DilatedOccupancy {
            min,
            inv_cell: res.as_vec3() / (max - min),
            res,
            cells,
            occupied,
            depth,
            depth_per_code_m: 1.0 / (DEPTH_CODES_PER_UNIT * size.min_element()),
            any_depth,
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
        self.is_occupied_cell((p_canonical - self.min) * self.inv_cell)
    }

    /// The canonical ray `p(t) = p0 + t dp` in cell units (the box's minimum at zero, one
    /// cell per unit), as [`DilatedOccupancy::is_occupied_cell`] takes points.
    pub fn cell_ray(&self, p0_canonical: Vec3, dp_canonical: Vec3) -> (Vec3, Vec3) {
        (
            (p0_canonical - self.min) * self.inv_cell,
            dp_canonical * self.inv_cell,
        )
    }

    /// [`DilatedOccupancy::is_occupied`] for a point in cell units: what a sampler
    /// stepping along a [`DilatedOccupancy::cell_ray`] asks.
    #[inline]
    pub fn is_occupied_cell(&self, f: Vec3) -> bool {
        let lo = -(self.cells as f32);
        let hi = self.res.as_vec3() + self.cells as f32;
        if !(f.cmpge(Vec3::splat(lo)).all() && f.cmplt(hi).all()) {
            return false;
        }
        let c = f.max(Vec3::ZERO).as_uvec3().min(self.res - 1);
        let i = (c.x as usize * self.res.y as usize + c.y as usize) * self.res.z as usize
            + c.z as usize;
        self.occupied[i / 64] >> (i % 64) & 1 != 0
    }

    /// The field's density (optical depth per metre, rounded down to a code) in the
    /// undilated cell holding `f` (cell units, as [`DilatedOccupancy::is_occupied_cell`]);
    /// 0 outside the box, in an unoccupied cell, or where the grid holds only marks.
    #[inline]
    pub fn density_cell(&self, f: Vec3) -> f32 {
        if !(f.cmpge(Vec3::ZERO).all() && f.cmplt(self.res.as_vec3()).all()) {
            return 0.0;
        }
        let c = f.as_uvec3().min(self.res - 1);
        let i = (c.x as usize * self.res.y as usize + c.y as usize) * self.res.z as usize
            + c.z as usize;
        f32::from(self.depth[i]) * self.depth_per_code_m
    }

    /// Whether any cell holds a density ([`DilatedOccupancy::density_cell`] can be > 0).
    pub fn has_density(&self) -> bool {
        self.any_depth
    }
}

/// Checks that `cull` dilates by at least `need` metres and has a finite rigid map for
/// every bone of `capsules`.
pub(crate) fn check_cull(
    cull: &CanonicalCull,
    capsules: &[Capsule],
    need: f32,
) -> Result<(), GridError> {
    let have = cull.grid.reach();
    if have < need * (1.0 - 1e-4) {
        return Err(GridError::BadOption {
            field: "cull dilation (metres)",
            value: have,
            expected: "at least the sampler's cull reach",
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use glam::vec3;

    use super::*;
    use crate::rng::SplitMix64;

    /// A reproducible point stream in a box.
    fn points(n: usize, lo: Vec3, hi: Vec3) -> Vec<Vec3> {
        let mut rng = SplitMix64::for_stream(5, 0);
        (0..n)
            .map(|_| lo + (hi - lo) * vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()))
            .collect()
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
