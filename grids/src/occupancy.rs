//! Occupancy grid over canonical space (nerfacc's `OccGridEstimator`, one level).
//!
//! A bitfield answers the hot-path question "may this canonical point hold density?";
//! f32 occupancy values behind it follow the field by an EMA of its density. The grid
//! only ever sees a density callback: it knows nothing of networks.

use glam::{UVec3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::intersect::{distance_to_segment, validate_capsules};
use crate::rng::SplitMix;
use crate::{Capsule, GridError};

/// Occupancy given to cells set by [`OccupancyGrid::mark`] and
/// [`OccupancyGrid::mark_capsules`]: a prior well above any sensible `occ_thre`, which
/// the EMA lets decay only if the field keeps reporting no density there (with decay
/// 0.95 and threshold 0.01, about 90 evaluations).
pub const MARKED_OCCUPANCY: f32 = 1.0;

/// Occupancy of a cell outside the grid's support (see
/// [`OccupancyGrid::restrict_to_marked`]): never evaluated, never occupied.
pub const OUTSIDE_SUPPORT: f32 = -1.0;

/// Options of [`OccupancyGrid::update_every_n_steps`], nerfacc's defaults.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OccUpdateOpts {
    /// Update when `step % n == 0`.
    pub n: u32,
    /// Occupancy of evaluated cells becomes `max(occ * ema_decay, density)`.
    pub ema_decay: f32,
    /// Cells are occupied when `occ > min(mean occupancy, occ_thre)`.
    pub occ_thre: f32,
    /// Before this step every cell is evaluated; after it a random quarter plus all
    /// occupied cells.
    pub warmup_steps: u32,
    /// Grow the occupied bitfield by this many cells in every direction (0 = off).
    pub dilation: u32,
    /// Seed of the cell subset and of the jitter inside cells (mixed with the step).
    pub seed: u64,
    /// Most points handed to the density callback at once.
    pub chunk: usize,
}

impl Default for OccUpdateOpts {
    fn default() -> Self {
        OccUpdateOpts {
            n: 16,
            ema_decay: 0.95,
            occ_thre: 0.01,
            warmup_steps: 256,
            dilation: 0,
            seed: 0,
            chunk: 1 << 16,
        }
    }
}

/// What an update did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OccUpdateReport {
    /// Cells whose density was evaluated.
    pub evaluated: usize,
    /// Threshold used: `min(mean occupancy, occ_thre)`.
    pub threshold: f32,
    /// Occupied cells after the update (dilation included).
    pub occupied: usize,
}

/// A dense grid over a canonical-space box. Cell `(x, y, z)` has index
/// `(x * res_y + y) * res_z + z`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGrid {
    aabb_min: Vec3,
    aabb_max: Vec3,
    resolution: [u32; 3],
    occupancy: Vec<f32>,
    bitfield: Vec<u64>,
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

    /// A 64-bit hash of the box, resolution and occupied bits: equal grids have equal
    /// fingerprints, so per-frame structures derived from the bits can be cached by it
    /// (the grid changes only at occupancy updates).
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
        for &w in &self.bitfield {
            h = crate::rng::mix64(h ^ w);
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

    /// nerfacc's `update_every_n_steps`: updates when `step % opts.n == 0` and returns
    /// what it did, `None` on other steps. `density_fn` maps canonical points to
    /// densities (same length, finite), in chunks of at most `opts.chunk` points, several
    /// chunks at once on rayon threads.
    pub fn update_every_n_steps(
        &mut self,
        step: u32,
        density_fn: impl Fn(&[Vec3]) -> Vec<f32> + Sync,
        opts: &OccUpdateOpts,
    ) -> Result<Option<OccUpdateReport>, GridError> {
        if opts.n == 0 || !step.is_multiple_of(opts.n) {
            return Ok(None);
        }
        self.update(step, density_fn, opts).map(Some)
    }

    /// One update, whatever the step: evaluate cells (all during warm-up, else a seeded
    /// random quarter plus every occupied cell) at a jittered point inside each, EMA
    /// their occupancy, re-threshold, dilate. A cell whose evaluated density exceeds the
    /// threshold is always occupied afterwards.
    pub fn update(
        &mut self,
        step: u32,
        density_fn: impl Fn(&[Vec3]) -> Vec<f32> + Sync,
        opts: &OccUpdateOpts,
    ) -> Result<OccUpdateReport, GridError> {
        check_opts(opts)?;
        let cells = self.num_cells();
        let in_support = |occupancy: &[f32], i: usize| occupancy[i] >= 0.0;
        let selected: Vec<usize> = if step < opts.warmup_steps {
            (0..cells)
                .filter(|&i| in_support(&self.occupancy, i))
                .collect()
        } else {
            let mut chosen = self.bitfield.clone();
            let mut rng = SplitMix::new(opts.seed, u64::from(step) << 32);
            for _ in 0..cells / 4 {
                let i = rng.below(cells as u64) as usize;
                chosen[i / 64] |= 1 << (i % 64);
            }
            ones(&chosen, cells)
                .into_iter()
                .filter(|&i| in_support(&self.occupancy, i))
                .collect()
        };
        let jitter_seed = opts.seed ^ 0x6A09_E667_F3BC_C908 ^ u64::from(step);
        // Chunks are evaluated in parallel (each chunk's points and densities depend on
        // nothing but its cells, so the result is the same on any number of threads):
        // network inference runs mostly on one core, and training waits for the update
        // (chunks in turn: ~0.55 s an update in the demo, in parallel ~0.36 s).
        let batches: Vec<&[usize]> = selected.chunks(opts.chunk).collect();
        let densities: Vec<Vec<f32>> = batches
            .par_iter()
            .map(|batch| {
                let points: Vec<Vec3> = batch
                    .iter()
                    .map(|&i| {
                        let mut rng = SplitMix::new(jitter_seed, i as u64);
                        let frac = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                        self.cell_point(i, frac)
                    })
                    .collect();
                density_fn(&points)
            })
            .collect();
        // Every chunk is checked before any cell changes: a bad chunk leaves the grid as it
        // was.
        for (batch, density) in batches.iter().zip(&densities) {
            if density.len() != batch.len() {
                return Err(GridError::LengthMismatch {
                    what: "density_fn output",
                    expected: batch.len(),
                    got: density.len(),
                });
            }
            if let Some(bad) = density.iter().position(|d| !d.is_finite()) {
                return Err(GridError::NonFiniteValue {
                    what: "density of cell",
                    index: batch[bad],
                });
            }
        }
        for (batch, density) in batches.iter().zip(&densities) {
            for (&i, &d) in batch.iter().zip(density) {
                self.occupancy[i] = (self.occupancy[i] * opts.ema_decay).max(d);
            }
        }
        let (sum, supported) = self
            .occupancy
            .iter()
            .filter(|&&o| o >= 0.0)
            .fold((0.0f64, 0usize), |(s, n), &o| (s + f64::from(o), n + 1));
        let mean = sum / supported.max(1) as f64;
        let threshold = (mean as f32).min(opts.occ_thre);
        self.bitfield.iter_mut().for_each(|w| *w = 0);
        for i in 0..cells {
            if self.occupancy[i] >= 0.0 && self.occupancy[i] > threshold {
                self.bitfield[i / 64] |= 1 << (i % 64);
            }
        }
        if opts.dilation > 0 {
            self.dilate(opts.dilation);
        }
        Ok(OccUpdateReport {
            evaluated: selected.len(),
            threshold,
            occupied: self.num_occupied(),
        })
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

fn ones(bits: &[u64], cells: usize) -> Vec<usize> {
    (0..cells)
        .filter(|&i| bits[i / 64] >> (i % 64) & 1 == 1)
        .collect()
}

fn check_opts(opts: &OccUpdateOpts) -> Result<(), GridError> {
    let bad = |field, value, expected| {
        Err(GridError::BadOption {
            field,
            value,
            expected,
        })
    };
    if !(0.0..=1.0).contains(&opts.ema_decay) {
        return bad("ema_decay", opts.ema_decay, "in [0, 1]");
    }
    if !opts.occ_thre.is_finite() {
        return bad("occ_thre", opts.occ_thre, "finite");
    }
    if opts.chunk == 0 {
        return bad("chunk", 0.0, ">= 1");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Part;
    use glam::vec3;

    fn grid(res: u32) -> OccupancyGrid {
        OccupancyGrid::new(Vec3::splat(-1.0), Vec3::splat(1.0), [res; 3]).unwrap()
    }

    /// A field: a ball of density 5 around (0.3, 0, 0), a faint haze elsewhere.
    fn ball(points: &[Vec3]) -> Vec<f32> {
        points
            .iter()
            .map(|p| {
                if p.distance(vec3(0.3, 0.0, 0.0)) < 0.4 {
                    5.0
                } else {
                    0.001
                }
            })
            .collect()
    }

    #[test]
    fn cells_and_box_edges() {
        let g = grid(4);
        assert_eq!(g.cell_of(Vec3::splat(-1.0)), Some(0));
        assert_eq!(g.cell_of(Vec3::splat(1.0)), Some(63));
        assert_eq!(g.cell_of(vec3(1.0001, 0.0, 0.0)), None);
        assert_eq!(g.cell_of(vec3(f32::NAN, 0.0, 0.0)), None);
        assert_eq!(
            g.cell_coords(vec3(-0.9, 0.1, 0.6)),
            Some(UVec3::new(0, 2, 3))
        );
        for i in 0..g.num_cells() {
            assert_eq!(g.cell_of(g.cell_point(i, Vec3::splat(0.5))), Some(i));
        }
        assert!(!g.is_occupied(Vec3::ZERO));
        assert!(!g.is_occupied(Vec3::splat(7.0)));
    }

    #[test]
    fn bad_construction_is_an_error() {
        assert!(OccupancyGrid::new(Vec3::ONE, Vec3::ZERO, [4; 3]).is_err());
        assert!(OccupancyGrid::new(Vec3::ZERO, Vec3::splat(f32::NAN), [4; 3]).is_err());
        assert!(OccupancyGrid::new(Vec3::ZERO, Vec3::ONE, [0, 4, 4]).is_err());
    }

    #[test]
    fn warmup_finds_the_ball_and_never_drops_dense_cells() {
        let mut g = grid(32);
        for step in 0..8 {
            let opts = OccUpdateOpts {
                warmup_steps: 2,
                n: 1,
                dilation: step % 2,
                ..Default::default()
            };
            let seen: std::sync::Mutex<Vec<(Vec3, f32)>> = Default::default();
            let report = g
                .update_every_n_steps(
                    step,
                    |p| {
                        let d = ball(p);
                        let mut seen = seen.lock().unwrap();
                        seen.extend(p.iter().copied().zip(d.iter().copied()));
                        d
                    },
                    &opts,
                )
                .unwrap()
                .unwrap();
            if step < 2 {
                assert_eq!(report.evaluated, g.num_cells());
            } else {
                assert!(report.evaluated < g.num_cells());
            }
            // The invariant: every evaluated point denser than the threshold is occupied.
            for (p, d) in seen.lock().unwrap().iter() {
                if *d > report.threshold {
                    assert!(g.is_occupied(*p), "step {step}: dropped {p} with {d}");
                }
            }
            assert!(g.is_occupied(vec3(0.3, 0.0, 0.0)));
            assert!(!g.is_occupied(vec3(-0.8, -0.8, -0.8)));
        }
        // Dilation grows exactly the undilated result by one cell.
        let undilated = OccUpdateOpts {
            warmup_steps: 0,
            ..Default::default()
        };
        let dilated = OccUpdateOpts {
            dilation: 1,
            ..undilated
        };
        let (mut a, mut b) = (g.clone(), g.clone());
        a.update(100, ball, &undilated).unwrap();
        b.update(100, ball, &dilated).unwrap();
        assert!(b.num_occupied() > a.num_occupied());
        a.dilate(1);
        assert_eq!(a, b);
        g.update(8, ball, &OccUpdateOpts::default()).unwrap();
        let occupied = g.num_occupied() as f32 / g.num_cells() as f32;
        let ball_fraction = 4.0 / 3.0 * std::f32::consts::PI * 0.4f32.powi(3) / 8.0;
        assert!(
            (occupied - ball_fraction).abs() < 0.02,
            "{occupied} vs {ball_fraction}"
        );
    }

    #[test]
    fn updates_are_deterministic_and_skip_off_steps() {
        let opts = OccUpdateOpts {
            warmup_steps: 0,
            seed: 9,
            ..Default::default()
        };
        let (mut a, mut b) = (grid(16), grid(16));
        a.update(32, ball, &opts).unwrap();
        b.update(32, ball, &opts).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.update_every_n_steps(3, ball, &opts).unwrap(), None);
        let mut c = grid(16);
        c.update(48, ball, &opts).unwrap();
        assert_ne!(
            a.occupancy(),
            c.occupancy(),
            "another step draws other cells"
        );
    }

    #[test]
    fn ema_forgets_density_that_moved_away() {
        let mut g = grid(8);
        let opts = OccUpdateOpts {
            warmup_steps: u32::MAX,
            ema_decay: 0.5,
            occ_thre: 0.01,
            ..Default::default()
        };
        g.update(0, ball, &opts).unwrap();
        assert!(g.is_occupied(vec3(0.5, 0.0, 0.0)));
        let moved = |p: &[Vec3]| ball(&p.iter().map(|p| -*p).collect::<Vec<_>>());
        for step in 1..20 {
            g.update(step, moved, &opts).unwrap();
        }
        assert!(!g.is_occupied(vec3(0.5, 0.0, 0.0)));
        assert!(g.is_occupied(vec3(-0.5, 0.0, 0.0)));
    }

    #[test]
    fn bad_density_callbacks_are_errors() {
        let mut g = grid(4);
        let opts = OccUpdateOpts::default();
        assert!(matches!(
            g.update(0, |p| vec![0.0; p.len() - 1], &opts),
            Err(GridError::LengthMismatch { .. })
        ));
        assert!(matches!(
            g.update(0, |p| vec![f32::NAN; p.len()], &opts),
            Err(GridError::NonFiniteValue { .. })
        ));
        // A bad chunk after good ones: the grid is left exactly as it was.
        let small_chunks = OccUpdateOpts { chunk: 8, ..opts };
        let before = (g.occupancy().to_vec(), g.bitfield().to_vec());
        let last_bad = |p: &[Vec3]| {
            p.iter()
                .map(|q| if q.x > 0.4 { f32::NAN } else { 100.0 })
                .collect()
        };
        assert!(g.update(0, last_bad, &small_chunks).is_err());
        assert_eq!((g.occupancy().to_vec(), g.bitfield().to_vec()), before);
    }

    #[test]
    fn capsules_marks_union_and_dilation() {
        let mut g = grid(20);
        let arm = Capsule {
            a: vec3(-0.5, 0.0, 0.0),
            b: vec3(0.5, 0.0, 0.0),
            radius: 0.1,
            part: Part::Arms,
            bone: 16,
        };
        g.mark_capsules(&[arm], 0.05).unwrap();
        // Every point of the inflated capsule lies in a marked cell, far points do not.
        for k in 0..=100 {
            let t = k as f32 / 100.0;
            for dir in [Vec3::Y, Vec3::Z, -Vec3::Y, vec3(0.0, 0.7, 0.7)] {
                let p = arm.a.lerp(arm.b, t) + dir * 0.149;
                assert!(g.is_occupied(p), "{p}");
            }
        }
        assert!(!g.is_occupied(vec3(0.0, 0.5, 0.0)));
        // Union keeps both sets.
        let mut other = grid(20);
        other.mark(&[vec3(0.0, 0.5, 0.0), vec3(9.0, 9.0, 9.0)]);
        let marked = g.num_occupied();
        g.union(&other).unwrap();
        assert_eq!(g.num_occupied(), marked + 1);
        assert!(g.is_occupied(vec3(0.0, 0.5, 0.0)));
        assert!(g.union(&grid(10)).is_err());
        // Intersection keeps what both hold: of the arm, only the marked point's cell.
        let mut both = g.clone();
        let mut point = grid(20);
        point.mark(&[arm.a, vec3(0.0, 0.5, 0.0) + Vec3::X]);
        both.intersect(&point).unwrap();
        assert_eq!(both.num_occupied(), 1);
        assert!(both.is_occupied(arm.a));
        assert!(both.intersect(&grid(10)).is_err());
        // Restricted, the cleared cells leave the support.
        both.restrict_to_marked();
        assert_eq!(both.num_supported(), 1);
        // Dilation by one cell grows a single cell into a 3x3x3 block.
        let mut single = grid(20);
        single.mark(&[Vec3::splat(0.01)]);
        single.dilate(1);
        assert_eq!(single.num_occupied(), 27);
        assert!(single.is_occupied(Vec3::splat(0.01) + 0.1));
        assert!(!single.is_occupied(Vec3::splat(0.01) + 0.2));
    }

    /// Chunks are evaluated on several threads: the result must not depend on how the
    /// cells are split.
    #[test]
    fn updates_do_not_depend_on_the_chunking() {
        let wavy = |p: &[Vec3]| -> Vec<f32> {
            p.iter()
                .map(|p| (7.0 * p.x).sin() * (5.0 * p.y).cos() + p.z)
                .collect()
        };
        let (mut a, mut b) = (grid(24), grid(24));
        for step in [0, 40, 80] {
            let small = OccUpdateOpts {
                chunk: 37,
                warmup_steps: 10,
                ..Default::default()
            };
            let whole = OccUpdateOpts {
                chunk: 1 << 20,
                ..small
            };
            let ra = a.update(step, wavy, &small).unwrap();
            let rb = b.update(step, wavy, &whole).unwrap();
            assert_eq!(ra, rb, "step {step}");
        }
        assert_eq!(a.occupancy, b.occupancy);
        assert_eq!(a.bitfield, b.bitfield);
    }

    #[test]
    fn cells_outside_the_support_are_never_evaluated_nor_occupied() {
        let mut grid = OccupancyGrid::new(Vec3::ZERO, Vec3::ONE, [4, 4, 4]).unwrap();
        grid.mark(&[Vec3::splat(0.1), Vec3::splat(0.9)]);
        grid.restrict_to_marked();
        assert_eq!(grid.num_supported(), 2);
        let opts = OccUpdateOpts {
            warmup_steps: 10,
            ema_decay: 0.0,
            ..OccUpdateOpts::default()
        };
        // The field says everything is dense: only the support may turn on.
        let asked = std::sync::atomic::AtomicUsize::new(0);
        let report = grid
            .update(
                0,
                |p| {
                    asked.fetch_add(p.len(), std::sync::atomic::Ordering::Relaxed);
                    vec![5.0; p.len()]
                },
                &opts,
            )
            .unwrap();
        assert_eq!(
            (asked.into_inner(), report.evaluated, report.occupied),
            (2, 2, 2)
        );
        // After warm-up too (occupied cells plus a random quarter of all cells).
        let report = grid.update(20, |p| vec![5.0; p.len()], &opts).unwrap();
        assert_eq!((report.evaluated, report.occupied), (2, 2));
        // An empty field culls the support; it can come back.
        let report = grid.update(20, |p| vec![0.0; p.len()], &opts).unwrap();
        assert_eq!(report.occupied, 0);
        let report = grid.update(20, |p| vec![5.0; p.len()], &opts).unwrap();
        assert!(report.occupied <= 2);
        assert_eq!(grid.num_supported(), 2);
        // Marking brings a cell into the support.
        grid.mark(&[Vec3::new(0.1, 0.9, 0.1)]);
        assert_eq!(grid.num_supported(), 3);
    }
}
