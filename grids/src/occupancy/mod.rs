//! Occupancy grid over canonical space (nerfacc's `OccGridEstimator`, one level).
//!
//! A bitfield answers the hot-path question "may this canonical point hold density?";
//! f32 occupancy values behind it follow the field by an EMA of its density. The grid
//! only ever sees a density callback: it knows nothing of networks.

//!
//! This file holds the grid's storage and queries; `marks` sets cells from points and
//! capsules and combines grids; `update` follows the field's density.

use glam::{UVec3, Vec3};
use serde::{Deserialize, Serialize};

use crate::GridError;

mod marks;
mod update;

pub use update::{OccUpdateOpts, OccUpdateReport};

/// Occupancy given to cells set by [`OccupancyGrid::mark`] and
/// [`OccupancyGrid::mark_capsules`]: a prior well above any sensible `occ_thre`, which
/// the EMA lets decay only if the field keeps reporting no density there (with decay
/// 0.95 and threshold 0.01, about 90 evaluations).
pub const MARKED_OCCUPANCY: f32 = 1.0;

/// Sixteenths of optical depth in a unit of [`OccupancyGrid::depth_code`]: an occupancy
/// (density times the smallest cell side, what an update stores) of 1 is code 16.
pub const DEPTH_CODES_PER_UNIT: f32 = 16.0;

/// An evaluated optical depth (density times the smallest cell side) as a depth code.
pub(crate) fn depth_code_of(value: f32) -> u8 {
    if value > 0.0 {
        (value * DEPTH_CODES_PER_UNIT).floor().min(255.0) as u8
    } else {
        0
    }
}

/// Occupancy of a cell outside the grid's support (see
/// [`OccupancyGrid::restrict_to_marked`]): never evaluated, never occupied.
pub const OUTSIDE_SUPPORT: f32 = -1.0;

/// A dense grid over a canonical-space box. Cell `(x, y, z)` has index
/// `(x * res_y + y) * res_z + z`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    aabb_min: Vec3,
    aabb_max: Vec3,
    resolution: [u32; 3],
    occupancy: Vec<f32>,
    bitfield: Vec<u64>,
    /// Per cell, the field's optical depth at the cell's last evaluation, coded
    /// ([`OccupancyGrid::depth_code`]); empty in a grid saved without it.
    #[serde(default)]
    depth: Vec<u8>,
}

impl OccupancyGrid {
    /// An empty grid (nothing occupied) over `[aabb_min, aabb_max]` in canonical space.
    pub fn new(
        aabb_min: Vec3,
        aabb_max: Vec3,
        resolution: [u32; 3],
    ) -> Result<OccupancyGrid, GridError> {
        if !(aabb_min.is_finite() && aabb_max.is_finite() && aabb_min.cmplt(aabb_max).all()) {
            return Err(GridError::BadBox {
                min: aabb_min,
                max: aabb_max,
            });
        }
        if resolution.iter().any(|&r| r == 0 || r > 1024) {
            return Err(GridError::BadResolution(resolution));
        }
        let cells = resolution.iter().map(|&r| r as usize).product::<usize>();
        Ok(OccupancyGrid {
            aabb_min,
            aabb_max,
            resolution,
            occupancy: vec![0.0; cells],
            bitfield: vec![0; cells.div_ceil(64)],
            depth: vec![0; cells],
        })
    }

    /// A grid from saved parts ([`OccupancyGrid::aabb`], [`OccupancyGrid::resolution`],
    /// [`OccupancyGrid::occupancy`], [`OccupancyGrid::bitfield`]), checked for consistent
    /// sizes and finite values.
    pub fn from_parts(
        aabb_min: Vec3,
        aabb_max: Vec3,
        resolution: [u32; 3],
        occupancy: Vec<f32>,
        bitfield: Vec<u64>,
    ) -> Result<OccupancyGrid, GridError> {
        let mut grid = OccupancyGrid::new(aabb_min, aabb_max, resolution)?;
        if occupancy.len() != grid.occupancy.len() {
            return Err(GridError::LengthMismatch {
                what: "occupancy",
                expected: grid.occupancy.len(),
                got: occupancy.len(),
            });
        }
        if bitfield.len() != grid.bitfield.len() {
            return Err(GridError::LengthMismatch {
                what: "bitfield",
                expected: grid.bitfield.len(),
                got: bitfield.len(),
            });
        }
        if let Some(index) = occupancy.iter().position(|v| !v.is_finite()) {
            return Err(GridError::NonFiniteValue {
                what: "occupancy",
                index,
            });
        }
        grid.occupancy = occupancy;
        grid.bitfield = bitfield;
        // Bits past the last cell stay clear.
        let tail = grid.occupancy.len() % 64;
        if tail != 0
            && let Some(last) = grid.bitfield.last_mut()
        {
            *last &= (1u64 << tail) - 1;
        }
        Ok(grid)
    }

    /// The occupied bits, 64 cells per word (cell `i` is bit `i % 64` of word `i / 64`).
    pub fn bitfield(&self) -> &[u64] {
        &self.bitfield
    }

    /// The canonical box `(min, max)`.
    pub fn aabb(&self) -> (Vec3, Vec3) {
        (self.aabb_min, self.aabb_max)
    }

    pub fn resolution(&self) -> [u32; 3] {
        self.resolution
    }

    pub fn num_cells(&self) -> usize {
        self.occupancy.len()
    }

    /// Size of one cell in canonical units.
    pub fn cell_size(&self) -> Vec3 {
        (self.aabb_max - self.aabb_min) / UVec3::from(self.resolution).as_vec3()
    }

    /// Occupancy value per cell.
    pub fn occupancy(&self) -> &[f32] {
        &self.occupancy
    }

    /// The optical depth the field gave cell `index` across its smallest side when the
    /// cell was last evaluated by an update, as the accelerated sampler reads it to stop
    /// a ray whose light is spent: in sixteenths ([`DEPTH_CODES_PER_UNIT`]), rounded down
    /// and capped at 255 (15.9, a transmittance of 1e-7); 0 for an unoccupied cell or one
    /// no update has evaluated. Marks ([`OccupancyGrid::mark`]) are a prior on where the
    /// person may be, not a density, and set no depth.
    #[inline]
    pub fn depth_code(&self, index: usize) -> u8 {
        if !self.is_cell_occupied(index) {
            return 0;
        }
        self.depth.get(index).copied().unwrap_or(0)
    }

    /// Every cell's stored depth code, as saved (see [`OccupancyGrid::depth_code`]).
    pub fn depth_codes(&self) -> &[u8] {
        &self.depth
    }

    /// Restores the depth codes saved with [`OccupancyGrid::depth_codes`]: one per cell.
    pub fn set_depth_codes(&mut self, depth: Vec<u8>) -> Result<(), GridError> {
        if depth.len() != self.occupancy.len() {
            return Err(GridError::LengthMismatch {
                what: "depth codes",
                expected: self.occupancy.len(),
                got: depth.len(),
            });
        }
        self.depth = depth;
        Ok(())
    }

    /// A 64-bit hash of the box, resolution, occupied bits and the occupied cells'
    /// [`OccupancyGrid::depth_code`]s: equal grids have equal fingerprints, so per-frame
    /// structures derived from them can be cached by it (the grid changes only at
    /// occupancy updates).
    pub fn fingerprint(&self) -> u64 {
        let mut h = crate::rng::mix64(0x6F63_6367_7269_6431);
        let head = self
            .aabb_min
            .to_array()
            .into_iter()
            .chain(self.aabb_max.to_array());
        for v in head
            .map(|v| v.to_bits() as u64)
            .chain(self.resolution.map(u64::from))
        {
            h = crate::rng::mix64(h ^ v);
        }
        for (k, &w) in self.bitfield.iter().enumerate() {
            h = crate::rng::mix64(h ^ w);
            // The depth codes of the word's occupied cells, eight to a hash.
            let (mut bits, mut packed, mut n) = (w, 0u64, 0);
            while bits != 0 {
                let i = k * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                packed = packed << 8 | u64::from(self.depth_code(i));
                n += 1;
                if n == 8 {
                    h = crate::rng::mix64(h ^ packed);
                    (packed, n) = (0, 0);
                }
            }
            if n > 0 {
                h = crate::rng::mix64(h ^ packed);
            }
        }
        h
    }

    /// Number of occupied cells.
    pub fn num_occupied(&self) -> usize {
        self.bitfield.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Integer coordinates of the cell containing `p_canonical`, `None` outside the box
    /// (the max faces belong to the last cells) or for NaN.
    pub fn cell_coords(&self, p_canonical: Vec3) -> Option<UVec3> {
        let res = UVec3::from(self.resolution);
        let f = (p_canonical - self.aabb_min) / (self.aabb_max - self.aabb_min) * res.as_vec3();
        // Written so NaN fails the test.
        if !(f.cmpge(Vec3::ZERO).all() && f.cmple(res.as_vec3()).all()) {
            return None;
        }
        Some(f.as_uvec3().min(res - 1))
    }

    /// Index of the cell containing `p_canonical`, `None` outside the box.
    pub fn cell_of(&self, p_canonical: Vec3) -> Option<usize> {
        self.cell_coords(p_canonical).map(|c| self.index(c))
    }

    fn index(&self, c: UVec3) -> usize {
        let [_, ry, rz] = self.resolution.map(|r| r as usize);
        (c.x as usize * ry + c.y as usize) * rz + c.z as usize
    }

    fn coords(&self, index: usize) -> UVec3 {
        let [_, ry, rz] = self.resolution.map(|r| r as usize);
        UVec3::new(
            (index / (ry * rz)) as u32,
            (index / rz % ry) as u32,
            (index % rz) as u32,
        )
    }

    /// Canonical position of a point inside a cell: `frac` in [0, 1)^3 (0.5 = centre).
    pub fn cell_point(&self, index: usize, frac: Vec3) -> Vec3 {
        let c = self.coords(index).as_vec3();
        self.aabb_min + (c + frac) * self.cell_size()
    }

    /// Whether `p_canonical` lies in an occupied cell; false outside the box.
    #[inline]
    pub fn is_occupied(&self, p_canonical: Vec3) -> bool {
        self.cell_of(p_canonical)
            .is_some_and(|i| self.is_cell_occupied(i))
    }

    /// Whether cell `index` is occupied.
    #[inline]
    pub fn is_cell_occupied(&self, index: usize) -> bool {
        self.bitfield[index / 64] >> (index % 64) & 1 == 1
    }

    fn set_cell(&mut self, index: usize) {
        self.bitfield[index / 64] |= 1 << (index % 64);
        self.occupancy[index] = self.occupancy[index].max(MARKED_OCCUPANCY);
    }
}

#[cfg(test)]
mod tests;
