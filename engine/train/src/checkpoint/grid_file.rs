//! The occupancy grid's binary file: `TKOG`, version 1 (u32), box min and max (6 x f32),
//! resolution (3 x u32), then every cell's occupancy (f32) and the bitfield (u64 words),
//! all little-endian. Reading checks every size against the header.

use std::path::Path;

use glam::Vec3;
use talkin_grids::OccupancyGrid;

use super::CheckpointError;

const MAGIC: &[u8; 4] = b"TKOG";
const VERSION: u32 = 1;
const HEADER: usize = 4 + 4 + 6 * 4 + 3 * 4;

/// The grid as bytes.
pub fn grid_to_bytes(grid: &OccupancyGrid) -> Vec<u8> {
    let (lo, hi) = grid.aabb();
    let occupancy = grid.occupancy();
    let bits = grid.bitfield();
    let mut out = Vec::with_capacity(HEADER + 4 * occupancy.len() + 8 * bits.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    for v in lo.to_array().into_iter().chain(hi.to_array()) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for r in grid.resolution() {
        out.extend_from_slice(&r.to_le_bytes());
    }
    for v in occupancy {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for w in bits {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out
}

/// Reads a grid written by [`grid_to_bytes`]; `file` names it in errors.
pub fn grid_from_bytes(bytes: &[u8], file: &Path) -> Result<OccupancyGrid, CheckpointError> {
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
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
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
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    let bitfield: Vec<u64> = bytes[HEADER + 4 * cells..]
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect();
    OccupancyGrid::from_parts(lo, hi, resolution, occupancy, bitfield)
        .map_err(|e| bad(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_damage() {
        let mut grid =
            OccupancyGrid::new(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 0.5), [5, 7, 3]).unwrap();
        grid.mark(&[Vec3::ZERO, Vec3::new(0.9, 1.9, 0.4)]);
        let bytes = grid_to_bytes(&grid);
        let file = Path::new("grid-0.bin");
        assert_eq!(grid_from_bytes(&bytes, file).unwrap(), grid);
        // Truncated, wrong magic, NaN occupancy: named errors.
        for damaged in [
            bytes[..bytes.len() - 1].to_vec(),
            [b"XXXX", &bytes[4..]].concat(),
            {
                let mut b = bytes.clone();
                b[HEADER..HEADER + 4].copy_from_slice(&f32::NAN.to_le_bytes());
                b
            },
        ] {
            let e = grid_from_bytes(&damaged, file).unwrap_err().to_string();
            assert!(e.contains("grid-0.bin"), "{e}");
        }
    }
}
