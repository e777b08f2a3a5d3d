//! The occupancy grid's file: safetensors, so any tool that reads safetensors (Python's
//! `safetensors`, numpy) can open it. Tensors: `aabb` (F32 [2, 3]: min, max),
//! `resolution` (U32 [3]), `occupancy` (F32 [rx * ry * rz], every cell's value) and
//! `bitfield` (U64 [ceil(cells / 64)], cell `i` is bit `i % 64` of word `i / 64`) and
//! `depth` (U8 [rx * ry * rz], the field's optical depth per cell in sixteenths, what
//! stops a ray whose light is spent; a file without it reads as zeros and stops none);
//! the header's metadata says `format: talkin occupancy grid v1`. Reading checks every
//! dtype and shape against the resolution; the grid itself refuses non-finite values.

use std::collections::HashMap;
use std::path::Path;

use glam::Vec3;
use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};
use talkin_grids::OccupancyGrid;

use super::CheckpointError;

const FORMAT: &str = "talkin occupancy grid v1";

/// The grid as safetensors bytes.
pub fn grid_to_bytes(grid: &OccupancyGrid) -> Result<Vec<u8>, CheckpointError> {
    let (lo, hi) = grid.aabb();
    let aabb: Vec<u8> = lo
        .to_array()
        .into_iter()
        .chain(hi.to_array())
        .flat_map(f32::to_le_bytes)
        .collect();
    let resolution: Vec<u8> = grid
        .resolution()
        .into_iter()
        .flat_map(u32::to_le_bytes)
        .collect();
    let occupancy: Vec<u8> = grid
        .occupancy()
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let bitfield: Vec<u8> = grid
        .bitfield()
        .iter()
        .flat_map(|w| w.to_le_bytes())
        .collect();
    let depth = grid.depth_codes();
    let internal = |e: safetensors::SafeTensorError| CheckpointError::Format {
        file: "grid".into(),
        field: "grid".into(),
        problem: format!("cannot encode the grid: {e}"),
    };
    let views = [
        ("aabb", TensorView::new(Dtype::F32, vec![2, 3], &aabb)),
        (
            "resolution",
            TensorView::new(Dtype::U32, vec![3], &resolution),
        ),
        (
            "occupancy",
            TensorView::new(Dtype::F32, vec![grid.occupancy().len()], &occupancy),
        ),
        (
            "bitfield",
            TensorView::new(Dtype::U64, vec![grid.bitfield().len()], &bitfield),
        ),
        (
            "depth",
            TensorView::new(Dtype::U8, vec![depth.len()], depth),
        ),
    ];
    let mut tensors = Vec::with_capacity(views.len());
    for (name, view) in views {
        tensors.push((name, view.map_err(internal)?));
    }
    let metadata = HashMap::from([("format".to_string(), FORMAT.to_string())]);
    safetensors::serialize(tensors, Some(metadata)).map_err(internal)
}

/// Reads a grid written by [`grid_to_bytes`]; `file` names it in errors.
pub fn grid_from_bytes(bytes: &[u8], file: &Path) -> Result<OccupancyGrid, CheckpointError> {
    let bad = |field: &str, problem: String| CheckpointError::Format {
        file: file.to_path_buf(),
        field: field.into(),
        problem,
    };
    if bytes.starts_with(super::grid_file_tkog::MAGIC) {
        return super::grid_file_tkog::grid_from_tkog(bytes, file);
    }
    let st = SafeTensors::deserialize(bytes).map_err(|e| {
        bad(
            "grid",
            format!("not an occupancy grid file (expected safetensors: {e})"),
        )
    })?;
    let tensor = |name: &str, dtype: Dtype, shape: &[usize]| {
        let view = st
            .tensor(name)
            .map_err(|_| bad(name, format!("missing (expected {dtype:?} {shape:?})")))?;
        if view.dtype() != dtype || view.shape() != shape {
            return Err(bad(
                name,
                format!(
                    "{:?} {:?}, expected {dtype:?} {shape:?}",
                    view.dtype(),
                    view.shape()
                ),
            ));
        }
        Ok(view.data().to_vec())
    };
    let words4 = |b: Vec<u8>| -> Vec<[u8; 4]> {
        b.chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect()
    };
    let aabb: Vec<f32> = words4(tensor("aabb", Dtype::F32, &[2, 3])?)
        .into_iter()
        .map(f32::from_le_bytes)
        .collect();
    let res: Vec<u32> = words4(tensor("resolution", Dtype::U32, &[3])?)
        .into_iter()
        .map(u32::from_le_bytes)
        .collect();
    let resolution = [res[0], res[1], res[2]];
    if resolution.iter().any(|&r| r == 0 || r > 1024) {
        return Err(bad(
            "resolution",
            format!("{resolution:?}: every axis must be in 1..=1024"),
        ));
    }
    let cells: usize = resolution.iter().map(|&r| r as usize).product();
    let occupancy: Vec<f32> = words4(tensor("occupancy", Dtype::F32, &[cells])?)
        .into_iter()
        .map(f32::from_le_bytes)
        .collect();
    let bitfield: Vec<u64> = tensor("bitfield", Dtype::U64, &[cells.div_ceil(64)])?
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    let depth = match st.tensor("depth") {
        Err(_) => None,
        Ok(_) => Some(tensor("depth", Dtype::U8, &[cells])?),
    };
    let lo = Vec3::new(aabb[0], aabb[1], aabb[2]);
    let hi = Vec3::new(aabb[3], aabb[4], aabb[5]);
    let mut grid = OccupancyGrid::from_parts(lo, hi, resolution, occupancy, bitfield)
        .map_err(|e| bad("grid", e.to_string()))?;
    if let Some(depth) = depth {
        grid.set_depth_codes(depth)
            .map_err(|e| bad("depth", e.to_string()))?;
    }
    Ok(grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_damage() {
        let mut grid =
            OccupancyGrid::new(Vec3::splat(-1.0), Vec3::new(1.0, 2.0, 0.5), [5, 7, 3]).unwrap();
        grid.mark(&[Vec3::ZERO, Vec3::new(0.9, 1.9, 0.4)]);
        let bytes = grid_to_bytes(&grid).unwrap();
        let file = Path::new("grid-0.safetensors");
        assert_eq!(grid_from_bytes(&bytes, file).unwrap(), grid);
        // Readable as plain safetensors, with the documented names and shapes.
        let st = SafeTensors::deserialize(&bytes).unwrap();
        assert_eq!(st.tensor("occupancy").unwrap().shape(), &[5 * 7 * 3]);
        assert_eq!(st.tensor("bitfield").unwrap().dtype(), Dtype::U64);
        // The field's depth codes travel with the grid.
        grid.update(
            0,
            |p: &[Vec3]| p.iter().map(|q| q.x.max(0.0) * 3.0).collect(),
            &talkin_grids::OccUpdateOpts::default(),
        )
        .unwrap();
        assert!(grid.depth_codes().iter().any(|&d| d > 0));
        let bytes = grid_to_bytes(&grid).unwrap();
        assert_eq!(grid_from_bytes(&bytes, file).unwrap(), grid);
        // Truncated, not safetensors, a wrong shape, NaN occupancy: named errors.
        // A 5x7x3 grid file whose occupancy holds `cells` copies of `value`.
        let file_with = |cells: usize, value: f32| {
            let aabb: Vec<u8> = [-1f32, -1., -1., 1., 2., 0.5]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            let res: Vec<u8> = [5u32, 7, 3].iter().flat_map(|v| v.to_le_bytes()).collect();
            let occ: Vec<u8> = vec![value; cells]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            let bits = vec![0u8; 16];
            let view =
                |dtype, shape: Vec<usize>, data| TensorView::new(dtype, shape, data).unwrap();
            safetensors::serialize(
                [
                    ("aabb", view(Dtype::F32, vec![2, 3], &aabb)),
                    ("resolution", view(Dtype::U32, vec![3], &res)),
                    ("occupancy", view(Dtype::F32, vec![cells], &occ)),
                    ("bitfield", view(Dtype::U64, vec![2], &bits)),
                ],
                None,
            )
            .unwrap()
        };
        // A file written before the depth codes reads as none.
        let old = grid_from_bytes(&file_with(105, 0.5), file).unwrap();
        assert!(old.depth_codes().iter().all(|&d| d == 0));
        let (nan, wrong_shape) = (file_with(105, f32::NAN), file_with(104, 0.0));
        for (damaged, needle) in [
            (bytes[..bytes.len() - 1].to_vec(), "grid"),
            (b"XXXX\x01\x00\x00\x00".to_vec(), "safetensors"),
            (wrong_shape, "occupancy"),
            (nan, "grid"),
        ] {
            let e = grid_from_bytes(&damaged, file).unwrap_err().to_string();
            assert!(
                e.contains("grid-0.safetensors") && e.contains(needle),
                "{e}"
            );
        }
    }
}
