//! Multiresolution hash encoding (instant-ngp): per level a grid of trainable feature vectors,
//! dense where it fits in `2^log2_hashmap_size` entries and spatially hashed above that,
//! trilinearly interpolated. Corner indices are piecewise constant in the point, so carry no
//! gradient: the fused CPU op computes them on the host, the composed ops as int tensor ops
//! on the device (`hash_corners`). The interpolation weights are tensor ops on the point,
//! so gradients reach both the table and the input points.

use burn::prelude::*;
use burn::tensor::Distribution;

use super::hash_corners::corners_on_device;
use super::hash_primes::{IDENTITY_PRIME, PRIMES};
use crate::init::WeightRng;
use crate::kernels::hash::{self as hash_fused, Corners};
use crate::rows::gather_rows;
use crate::util::{floats, host, ints};

/// Table row of integer vertex `c` of identity `id` on `level` of a grid with these
/// per-level `resolutions` and row `offsets`: dense levels hold one block per identity
/// (an identity added after training wraps onto the others' blocks), hashed levels hash
/// the identity with the vertex.
fn vertex_row(
    resolutions: &[usize],
    offsets: &[usize],
    level: usize,
    c: [u32; 3],
    id: u32,
) -> usize {
    let res1 = resolutions[level] + 1;
    let block = res1.pow(3);
    let size = offsets[level + 1] - offsets[level];
    let dense = c[0] as usize + res1 * (c[1] as usize + res1 * c[2] as usize);
    let local = if block <= size && size.is_multiple_of(block) {
        (dense + id as usize * block) % size
    } else {
        // size is a power of two when hashed.
        let h = c[0].wrapping_mul(PRIMES[0])
            ^ c[1].wrapping_mul(PRIMES[1])
            ^ c[2].wrapping_mul(PRIMES[2])
            ^ id.wrapping_mul(IDENTITY_PRIME);
        h as usize & (size - 1)
    };
    offsets[level] + local
}

/// The table rows of one identity's cell corners, level by level, with the per-level
/// arithmetic of [`vertex_row`] (divisions, the dense/hashed choice) done once per call:
/// the fused op's fast path. [`vertex_row`] stays the plain statement of the indexing
/// (the composed path and the f64 reference use it), so the two are checked against each
/// other (`fused_op_matches_composed_ops`).
pub(crate) struct CellRows {
    levels: Vec<LevelRows>,
}

enum LevelRows {
    /// `offset + (x + res1 (y + res1 z) + shift) mod size`, `shift < size`, every index
    /// `< res1^3 <= size`.
    Dense {
        offset: u32,
        res1: u32,
        size: u32,
        shift: u32,
    },
    /// `offset + (x P0 ^ y P1 ^ z P2 ^ id P3) & mask`.
    Hashed {
        offset: u32,
        mask: u32,
        id_hash: u32,
    },
}

impl CellRows {
    pub(crate) fn new(resolutions: &[usize], offsets: &[usize], id: u32) -> CellRows {
        let levels = (0..resolutions.len())
            .map(|level| {
                let res1 = resolutions[level] + 1;
                let block = res1.pow(3);
                let size = offsets[level + 1] - offsets[level];
                let offset = offsets[level] as u32;
                if block <= size && size.is_multiple_of(block) {
                    LevelRows::Dense {
                        offset,
                        res1: res1 as u32,
                        size: size as u32,
                        shift: ((id as usize * block) % size) as u32,
                    }
                } else {
                    LevelRows::Hashed {
                        offset,
                        mask: size as u32 - 1,
                        id_hash: id.wrapping_mul(IDENTITY_PRIME),
                    }
                }
            })
            .collect();
        CellRows { levels }
    }

    /// Rows of the 8 corners of the cell with lower corner `c` on `level`; corner `k` is
    /// `c + (k & 1, k >> 1 & 1, k >> 2)`.
    #[inline]
    pub(crate) fn rows(&self, level: usize, c: [u32; 3]) -> [u32; 8] {
        let mut out = [0u32; 8];
        match self.levels[level] {
            LevelRows::Dense {
                offset,
                res1,
                size,
                shift,
            } => {
                let base = c[0] + res1 * (c[1] + res1 * c[2]) + shift;
                for (k, o) in out.iter_mut().enumerate() {
                    let k = k as u32;
                    let mut i = base + (k & 1) + res1 * ((k >> 1) & 1) + res1 * res1 * (k >> 2);
                    if i >= size {
                        i -= size;
                    }
                    *o = offset + i;
                }
            }
            LevelRows::Hashed {
                offset,
                mask,
                id_hash,
            } => {
                let hx = [
                    c[0].wrapping_mul(PRIMES[0]),
                    (c[0] + 1).wrapping_mul(PRIMES[0]),
                ];
                let hy = [
                    c[1].wrapping_mul(PRIMES[1]),
                    (c[1] + 1).wrapping_mul(PRIMES[1]),
                ];
                let hz = [
                    c[2].wrapping_mul(PRIMES[2]),
                    (c[2] + 1).wrapping_mul(PRIMES[2]),
                ];
                for (k, o) in out.iter_mut().enumerate() {
                    let h = hx[k & 1] ^ hy[(k >> 1) & 1] ^ hz[k >> 2] ^ id_hash;
                    *o = offset + (h & mask);
                }
            }
        }
        out
    }
}

/// Configuration of [`HashGrid`] (tiny-cuda-nn's `HashGrid` fields).
#[derive(Config, Debug)]
pub struct HashGridConfig {
    /// Number of resolution levels.
    #[config(default = 16)]
    pub n_levels: usize,
    /// Feature width per level (output width is `n_levels * n_features_per_level`).
    #[config(default = 2)]
    pub n_features_per_level: usize,
    /// Entries per level, as a power of two.
    #[config(default = 19)]
    pub log2_hashmap_size: usize,
    /// Cells per axis of the coarsest level.
    #[config(default = 16)]
    pub base_resolution: usize,
    /// Resolution growth from one level to the next.
    #[config(default = 1.5)]
    pub per_level_scale: f64,
    /// Table entries start uniform in `[-init_scale, init_scale]` (instant-ngp: 1e-4).
    #[config(default = 1e-4)]
    pub init_scale: f64,
    /// Identities with their own features (a fourth hashed coordinate): subjects share
    /// the table's capacity but not its entries, so one canonical place can hold three
    /// people's different clothes. Dense levels hold `n_identities` blocks.
    #[config(default = 1)]
    pub n_identities: usize,
}

impl HashGridConfig {
    /// Builds the grid with a freshly initialised table drawn from `rng`.
    pub fn init(&self, device: &Device, rng: &mut WeightRng) -> HashGrid {
        let max_entries = 1usize << self.log2_hashmap_size;
        let mut resolutions = Vec::with_capacity(self.n_levels);
        let mut offsets = Vec::with_capacity(self.n_levels + 1);
        let mut total = 0usize;
        for level in 0..self.n_levels {
            let res = (self.base_resolution as f64 * self.per_level_scale.powi(level as i32))
                .floor()
                .max(1.0) as usize;
            let dense = (res + 1).pow(3) * self.n_identities.max(1);
            resolutions.push(res);
            offsets.push(total);
            total += dense.min(max_entries);
        }
        offsets.push(total);
        let s = self.init_scale;
        let table = rng.tensor(
            [total, self.n_features_per_level],
            Distribution::Uniform(-s, s),
            device,
        );
        HashGrid {
            table: burn::module::Param::from_tensor(table),
            resolutions,
            offsets,
            n_features: self.n_features_per_level,
        }
    }
}

/// Points per piece of the composed encoding (the GPU's): the table gather's index is
/// `8 L F` ints a point (192 for the fast preset), so a piece's stays near 50 MB, under
/// the 128 MiB a storage binding may hold on some adapters (lavapipe).
const COMPOSED_CHUNK: usize = 1 << 16;

/// The trainable multiresolution hash table.
#[derive(Module, Debug)]
pub struct HashGrid {
    /// All levels' feature vectors, level after level. `[entries, features]`
    pub table: burn::module::Param<Tensor<2>>,
    resolutions: Vec<usize>,
    /// Start of each level in `table`, plus the total at the end.
    offsets: Vec<usize>,
    n_features: usize,
}

impl HashGrid {
    /// Output width: `n_levels * n_features_per_level`.
    pub fn output_dim(&self) -> usize {
        self.resolutions.len() * self.n_features
    }

    /// Number of table rows.
    pub fn n_entries(&self) -> usize {
        *self.offsets.last().unwrap_or(&0)
    }

    /// Table row of integer vertex `c` of identity `id` on `level` (see [`vertex_row`]).
    fn vertex_index(&self, level: usize, c: [u32; 3], id: u32) -> usize {
        vertex_row(&self.resolutions, &self.offsets, level, c, id)
    }

    /// Host-side lower cell corners `[n, L, 3]` and the 8 vertex rows `[n, L, 8]` of each
    /// point (points already clamped to [0, 1]). Corner `k` is `(k & 1, k >> 1 & 1, k >> 2)`.
    fn corners(&self, points: &[f32], id: u32) -> (Vec<f32>, Vec<i32>) {
        let n = points.len() / 3;
        let l = self.resolutions.len();
        let mut lower = Vec::with_capacity(n * l * 3);
        let mut rows = Vec::with_capacity(n * l * 8);
        for p in points.chunks_exact(3) {
            for (level, &res) in self.resolutions.iter().enumerate() {
                let mut c = [0u32; 3];
                for a in 0..3 {
                    let cell = (p[a] as f64 * res as f64)
                        .floor()
                        .clamp(0.0, res as f64 - 1.0);
                    c[a] = cell as u32;
                    lower.push(cell as f32);
                }
                for k in 0..8u32 {
                    let v = [c[0] + (k & 1), c[1] + ((k >> 1) & 1), c[2] + (k >> 2)];
                    rows.push(self.vertex_index(level, v, id) as i32);
                }
            }
        }
        (lower, rows)
    }

    /// Encodes points of identity `identity` given in the unit cube (clamped to it:
    /// outside, the gradient w.r.t. the point is zero).
    ///
    /// # Shapes
    /// - `x`: `[n, 3]` in [0, 1]^3
    /// - output: `[n, n_levels * n_features_per_level]`, level-major.
    pub fn forward(&self, x: Tensor<2>, identity: usize) -> Tensor<2> {
        let [n, _] = x.dims();
        let l = self.resolutions.len();
        let f = self.n_features;
        let device = x.device();
        if n == 0 {
            return Tensor::zeros([0, l * f], &device);
        }
        let x = x.clamp(0.0, 1.0);
        let table = self.table.val();
        let (resolutions, offsets) = (&self.resolutions, &self.offsets);
        let id = identity as u32;
        match hash_fused::encode(&table, &x, |points| {
            let cells = CellRows::new(resolutions, offsets, id);
            Corners::new(points, resolutions, offsets, f, &|l, c| cells.rows(l, c))
        }) {
            Some(out) => out,
            None => self.forward_device(table, x, identity),
        }
    }

    /// Off the CPU: the device op (`kernels::cube`, one launch) in a build with the GPU
    /// backend, else the composed ops.
    fn forward_device(&self, table: Tensor<2>, x: Tensor<2>, identity: usize) -> Tensor<2> {
        #[cfg(feature = "wgpu")]
        if let Some(levels) = self.device_levels(identity as u32) {
            let id_hash = (identity as u32).wrapping_mul(IDENTITY_PRIME);
            return crate::kernels::cube::hash::encode(table, x, &levels, id_hash);
        }
        self.forward_pieces(table, x, identity, COMPOSED_CHUNK)
    }

    /// Each level's numbers for the device kernels (`kernels::cube`'s layout: cells per
    /// axis, first row, rows, vertices per axis or 0 when hashed, the identity's shift),
    /// every one exact in f32; `None` for a grid too large for that.
    #[cfg_attr(not(feature = "wgpu"), allow(dead_code))]
    fn device_levels(&self, id: u32) -> Option<Vec<f32>> {
        let exact = |v: usize| (v < 1 << 24).then_some(v as f32);
        let mut out = Vec::with_capacity(self.resolutions.len() * 5);
        for (level, &res) in self.resolutions.iter().enumerate() {
            let res1 = res + 1;
            let block = res1.pow(3);
            let size = self.offsets[level + 1] - self.offsets[level];
            let (res1, shift) = if block <= size && size.is_multiple_of(block) {
                (res1, (id as usize * block) % size)
            } else if size.is_power_of_two() {
                (0, 0)
            } else {
                return None;
            };
            for v in [res, self.offsets[level], size, res1, shift] {
                out.push(exact(v)?);
            }
        }
        // The table's last row too (rows are indexed in f32-exact offsets).
        exact(self.n_entries())?;
        Some(out)
    }

    /// [`HashGrid::forward_composed`] on pieces of at most `chunk` points, concatenated
    /// (the corners' row index is `8 L F` ints a point).
    fn forward_pieces(
        &self,
        table: Tensor<2>,
        x: Tensor<2>,
        identity: usize,
        chunk: usize,
    ) -> Tensor<2> {
        let [n, _] = x.dims();
        if n <= chunk {
            return self.forward_composed(table, x, identity);
        }
        let pieces = (0..n)
            .step_by(chunk)
            .map(|start| {
                let piece = x.clone().narrow(0, start, chunk.min(n - start));
                self.forward_composed(table.clone(), piece, identity)
            })
            .collect();
        Tensor::cat(pieces, 0)
    }

    /// [`HashGrid::forward`] as composed tensor ops, for backends without the fused op
    /// (`x` already clamped, `n > 0`).
    fn forward_composed(&self, table: Tensor<2>, x: Tensor<2>, identity: usize) -> Tensor<2> {
        let [n, _] = x.dims();
        let l = self.resolutions.len();
        let f = self.n_features;
        let device = x.device();
        let id = identity as u32;
        // On the device where the arithmetic fits in i32 (every preset's grid), else on
        // the host.
        let (lower, rows) = match corners_on_device(&x, &self.resolutions, &self.offsets, id) {
            Some(corners) => corners,
            None => {
                let (lower, rows) = self.corners(&host(&x), id);
                (floats(lower, [n, l, 3], &device), ints(rows, &device))
            }
        }; // [n, L, 3], [n L 8]
        let res: Vec<f32> = self.resolutions.iter().map(|&r| r as f32).collect();
        let res = floats(res, [1, l, 1], &device); // [1, L, 1]
        let frac = x.unsqueeze_dim::<3>(1) * res - lower; // [n, L, 3] in [0, 1]
        let axis = |a: usize| {
            let t = frac.clone().narrow(2, a, 1); // [n, L, 1]
            Tensor::cat(vec![t.clone().neg().add_scalar(1.0), t], 2) // [n, L, 2]
        };
        let weights = axis(0).reshape([n, l, 1, 1, 2])
            * axis(1).reshape([n, l, 1, 2, 1])
            * axis(2).reshape([n, l, 2, 1, 1]); // [n, L, z, y, x]
        let weights = weights.reshape([n, l, 8, 1]);
        let features = gather_rows(table, rows) // [n L 8, F]
            .reshape([n, l, 8, f]);
        (features * weights).sum_dim(2).reshape([n, l * f]) // [n, L F]
    }
}

#[cfg(test)]
pub(crate) mod tests;
