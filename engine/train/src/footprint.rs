//! The finest detail the training images resolve: a pixel's footprint on the subject, and
//! the hash grid's finest level limited to it. Finer levels than the pixels see hold
//! cells whose every sample is a different pixel's colour: with a few hundred rays a
//! step they learn noise, which renders as speckle and fog on a real capture.

use talkin_data::dataset::Dataset;
use talkin_nets::FieldConfig;
use talkin_nets::encoding::EncodingConfig;

/// The median over `frames` of a pixel's footprint (metres) at the subject's pelvis:
/// its distance along the optical axis over the focal length. `None` when no frame puts
/// the pelvis in front of its camera.
pub fn pixel_footprint_m(dataset: &Dataset, frames: &[usize]) -> Option<f64> {
    let mut sizes: Vec<f64> = frames
        .iter()
        .filter_map(|&i| {
            let f = &dataset.frames[i];
            let pelvis = dataset.subjects[f.subject]
                .skeleton
                .pose(&f.params)
                .joint(0);
            let p = f.camera.project(pelvis)?;
            let focal = f
                .camera
                .intrinsics
                .x_axis
                .x
                .max(f.camera.intrinsics.y_axis.y);
            (p.z > 0.0 && focal > 0.0).then(|| p.z / focal)
        })
        .filter(|s| s.is_finite())
        .collect();
    sizes.sort_by(f64::total_cmp);
    sizes.get(sizes.len() / 2).copied()
}

/// Lowers each hash grid's growth per level so that its finest cell spans at least
/// `cell_m` metres of the field's box (never raising it above the preset's). Returns the
/// finest resolution of the body's grid, or `None` when the field has no hash grid.
pub fn limit_finest_cell(config: &mut FieldConfig, cell_m: f64) -> Option<usize> {
    let side = (0..3)
        .map(|a| f64::from(config.aabb_max[a] - config.aabb_min[a]))
        .fold(0.0, f64::max);
    if !(side > 0.0 && cell_m > 0.0) {
        return None;
    }
    let limit = |e: &mut EncodingConfig| -> Option<usize> {
        let EncodingConfig::HashGrid(g) = e else {
            return None;
        };
        if g.n_levels < 2 {
            return None;
        }
        let finest = (side / cell_m).max(g.base_resolution as f64);
        let scale = (finest / g.base_resolution as f64).powf(1.0 / (g.n_levels - 1) as f64);
        g.per_level_scale = g.per_level_scale.min(scale);
        Some(
            (g.base_resolution as f64 * g.per_level_scale.powi(g.n_levels as i32 - 1)).floor()
                as usize,
        )
    };
    if let Some(part) = config.part_encoding.as_mut() {
        limit(part);
    }
    limit(&mut config.encoding)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_finest_level_stops_at_the_cell_and_never_grows() {
        let mut c = FieldConfig::fast(1);
        c.aabb_min = [-1.0, 0.0, -0.5];
        c.aabb_max = [1.0, 2.0, 0.5];
        // 2 m over 5 mm: 400 cells.
        let finest = limit_finest_cell(&mut c, 0.005).unwrap();
        assert!((399..=400).contains(&finest), "{finest}");
        let EncodingConfig::HashGrid(part) = c.part_encoding.clone().unwrap() else {
            panic!("the fast preset's parts use hash grids");
        };
        assert!(
            (part.base_resolution as f64 * part.per_level_scale.powi(part.n_levels as i32 - 1))
                .floor()
                <= 400.0
        );
        // A cell finer than the preset's finest level changes nothing.
        let mut fine = FieldConfig::fast(1);
        fine.aabb_min = c.aabb_min;
        fine.aabb_max = c.aabb_max;
        let before = match &fine.encoding {
            EncodingConfig::HashGrid(g) => g.per_level_scale,
            _ => unreachable!(),
        };
        limit_finest_cell(&mut fine, 1e-5).unwrap();
        let EncodingConfig::HashGrid(g) = &fine.encoding else {
            unreachable!()
        };
        assert_eq!(g.per_level_scale, before);
        // No box, or the paper's frequency encoding: nothing to limit.
        assert!(limit_finest_cell(&mut FieldConfig::paper(1), 0.005).is_none());
    }
}
