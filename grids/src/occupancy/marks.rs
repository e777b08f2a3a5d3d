//! Setting cells: from canonical points and capsules, by union and intersection with
//! another grid, by dilation, and restricting the grid's support to what is marked.

use glam::{UVec3, Vec3};

use super::{OUTSIDE_SUPPORT, OccupancyGrid};
use crate::intersect::{distance_to_segment, validate_capsules};
use crate::{Capsule, GridError};

impl OccupancyGrid {
    /// Marks the cells containing these canonical points occupied (points outside the
    /// box or non-finite are skipped): how the union over expressions and hand poses
    /// seen is accumulated.
    pub fn mark(&mut self, p_canonical: &[Vec3]) {
        for &p in p_canonical {
            if let Some(i) = self.cell_of(p) {
                self.set_cell(i);
            }
        }
    }

    /// Marks every cell that may overlap a capsule inflated by `margin` (capsules in
    /// canonical space, e.g. the rest pose): cells whose centre is within radius +
    /// margin + half a cell diagonal of the segment.
    pub fn mark_capsules(&mut self, capsules: &[Capsule], margin: f32) -> Result<(), GridError> {
        validate_capsules(capsules)?;
        if !(margin.is_finite() && margin >= 0.0) {
            return Err(GridError::BadOption {
                field: "margin",
                value: margin,
                expected: "finite and >= 0",
            });
        }
        let half_diag = 0.5 * self.cell_size().length();
        let cell = self.cell_size();
        let res = UVec3::from(self.resolution);
        for c in capsules {
            let reach = c.radius + margin + half_diag;
            let lo = ((c.a.min(c.b) - reach - self.aabb_min) / cell).floor();
            let hi = ((c.a.max(c.b) + reach - self.aabb_min) / cell).floor();
            let lo = lo.max(Vec3::ZERO).as_uvec3();
            let hi = hi.min((res - 1).as_vec3());
            if hi.cmplt(Vec3::ZERO).any() {
                continue;
            }
            let hi = hi.as_uvec3();
            for x in lo.x..=hi.x {
                for y in lo.y..=hi.y {
                    for z in lo.z..=hi.z {
                        let i = self.index(UVec3::new(x, y, z));
                        let centre = self.cell_point(i, Vec3::splat(0.5));
                        if distance_to_segment(centre, c.a, c.b) <= reach {
                            self.set_cell(i);
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn check_same_layout(&self, other: &OccupancyGrid) -> Result<(), GridError> {
        if self.aabb_min != other.aabb_min
            || self.aabb_max != other.aabb_max
            || self.resolution != other.resolution
        {
            return Err(GridError::GridMismatch);
        }
        Ok(())
    }

    /// Cell-wise union with a grid over the same box and resolution: bits OR-ed,
    /// occupancy max-ed.
    pub fn union(&mut self, other: &OccupancyGrid) -> Result<(), GridError> {
        self.check_same_layout(other)?;
        for (a, b) in self.bitfield.iter_mut().zip(&other.bitfield) {
            *a |= b;
        }
        for (a, b) in self.occupancy.iter_mut().zip(&other.occupancy) {
            *a = a.max(*b);
        }
        Ok(())
    }

    /// Cell-wise intersection with a grid over the same box and resolution: a cell stays
    /// occupied only if occupied in both; cells it clears get occupancy 0 (outside the
    /// support they stay [`OUTSIDE_SUPPORT`]).
    pub fn intersect(&mut self, other: &OccupancyGrid) -> Result<(), GridError> {
        self.check_same_layout(other)?;
        for (a, b) in self.bitfield.iter_mut().zip(&other.bitfield) {
            *a &= b;
        }
        for i in 0..self.occupancy.len() {
            if !self.is_cell_occupied(i) && self.occupancy[i] > 0.0 {
                self.occupancy[i] = 0.0;
            }
        }
        Ok(())
    }

    /// Makes the cells occupied now the grid's support and every other cell
    /// [`OUTSIDE_SUPPORT`]: updates never evaluate nor occupy them. For a grid marked from
    /// capsules that bound every sample the sampler can produce, this saves evaluating
    /// the field where no sample can ever land (an update otherwise evaluates every cell
    /// the field's untrained density happens to fill). [`OccupancyGrid::mark`] and
    /// [`OccupancyGrid::mark_capsules`] bring cells back into the support.
    pub fn restrict_to_marked(&mut self) {
        for i in 0..self.num_cells() {
            if !self.is_cell_occupied(i) {
                self.occupancy[i] = OUTSIDE_SUPPORT;
            }
        }
    }

    /// Cells in the support (every cell unless [`OccupancyGrid::restrict_to_marked`]).
    pub fn num_supported(&self) -> usize {
        self.occupancy.iter().filter(|&&o| o >= 0.0).count()
    }

    /// Grows the occupied set by `k` cells along every axis (a (2k+1)^3 box), by three
    /// separable passes.
    pub fn dilate(&mut self, k: u32) {
        let cells = self.num_cells();
        let mut on: Vec<bool> = (0..cells).map(|i| self.is_cell_occupied(i)).collect();
        let [rx, ry, rz] = self.resolution.map(|r| r as usize);
        let strides = [ry * rz, rz, 1];
        let lens = [rx, ry, rz];
        let k = k as usize;
        let mut next = vec![false; cells];
        for axis in 0..3 {
            let (stride, len) = (strides[axis], lens[axis]);
            for i in 0..cells {
                let pos = i / stride % len;
                let lo = pos.saturating_sub(k);
                let hi = (pos + k).min(len - 1);
                next[i] = (lo..=hi).any(|p| on[i - pos * stride + p * stride]);
            }
            std::mem::swap(&mut on, &mut next);
        }
        for (i, &o) in on.iter().enumerate() {
            if o {
                self.bitfield[i / 64] |= 1 << (i % 64);
            }
        }
    }
}
