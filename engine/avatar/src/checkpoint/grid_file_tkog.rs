//! The occupancy grid's first file format, still read so that runs trained before the
//! grids moved to safetensors load: `TKOG`, version 1 (u32), box min and max (6 x f32),
//! resolution (3 x u32), every cell's occupancy (f32) and the bitfield (u64 words), all
//! little-endian, in `grid-<s>.bin`. Reading checks every size against the header.

use std::path::Path;

use glam::Vec3;
use talkin_grids::OccupancyGrid;

use super::CheckpointError;

pub const MAGIC: &[u8; 4] = b"TKOG";
const VERSION: u32 = 1;
const HEADER: usize = 4 + 4 + 6 * 4 + 3 * 4;

/// Reads a grid in the raw format; `file` names it in errors.
pub fn grid_from_tkog(bytes: &[u8], file: &Path) -> Result<OccupancyGrid, CheckpointError> {
    let bad = |problem: String| CheckpointError::Format {
        file: file.to_path_buf(),
        field: "grid".into(),
        problem,
    };
    if bytes.len() < HEADER || &bytes[..4] != MAGIC {
        return Err(bad(format!(
            "not an occupancy grid file (expected the `TKOG` magic and a {HEADER}-byte header, \
             found {} bytes)",
            bytes.len()
        )));
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap_or([0; 4]));
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap_or([0; 4]));
    let version = u32_at(4);
    if version != VERSION {
        return Err(bad(format!(
            "version {version}, this build reads {VERSION}"
        )));
    }
    let lo = Vec3::new(f32_at(8), f32_at(12), f32_at(16));
    let hi = Vec3::new(f32_at(20), f32_at(24), f32_at(28));
    let resolution = [u32_at(32), u32_at(36), u32_at(40)];
    if resolution.iter().any(|&r| r == 0 || r > 1024) {
        return Err(bad(format!(
            "resolution {resolution:?}: every axis must be in 1..=1024"
        )));
    }
    let cells: usize = resolution.iter().map(|&r| r as usize).product();
    let words = cells.div_ceil(64);
    let expected = HEADER + 4 * cells + 8 * words;
    if bytes.len() != expected {
        return Err(bad(format!(
            "{} bytes, expected {expected} for a {resolution:?} grid",
            bytes.len()
        )));
    }
    let occupancy: Vec<f32> = bytes[HEADER..HEADER + 4 * cells]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
        .collect();
    let bitfield: Vec<u64> = bytes[HEADER + 4 * cells..]
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
        .collect();
    OccupancyGrid::from_parts(lo, hi, resolution, occupancy, bitfield)
        .map_err(|e| bad(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid in the raw layout, written as the earlier builds wrote it.
    fn tkog(grid: &OccupancyGrid) -> Vec<u8> {
        let (lo, hi) = grid.aabb();
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        for v in lo.to_array().into_iter().chain(hi.to_array()) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for r in grid.resolution() {
            out.extend_from_slice(&r.to_le_bytes());
        }
        for v in grid.occupancy() {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for w in grid.bitfield() {
            out.extend_from_slice(&w.to_le_bytes());
        }
        out
    }

    #[test]
    fn old_grids_still_load_and_damage_is_named() {
        let mut grid =
            OccupancyGrid::new(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 0.5), [5, 7, 3]).unwrap();
        grid.mark(&[Vec3::ZERO, Vec3::new(0.9, 1.9, 0.4)]);
        let bytes = tkog(&grid);
        let file = Path::new("grid-0.bin");
        assert_eq!(grid_from_tkog(&bytes, file).unwrap(), grid);
        for damaged in [bytes[..bytes.len() - 1].to_vec(), {
            let mut b = bytes.clone();
            b[HEADER..HEADER + 4].copy_from_slice(&f32::NAN.to_le_bytes());
            b
        }] {
            let e = grid_from_tkog(&damaged, file).unwrap_err().to_string();
            assert!(e.contains("grid-0.bin"), "{e}");
        }
    }
}
