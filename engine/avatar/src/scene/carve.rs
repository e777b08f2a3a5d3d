//! The canonical grid carved to the surfaces the training frames show. With depth
//! (synthetic data, RGB-D capture) every training pixel's surface point is known; mapped
//! into canonical space it says where the body and arms are, so the grid need not keep
//! the whole of their data-fitted capsules (a round capsule around a flat chest holds
//! mostly air). Hands and head keep their capsule marks: novel finger poses and
//! expressions move their surfaces in canonical space. What no training frame saw (the
//! back, for a camera that stays in front) is carved away too: the avatar is meant to be
//! rendered from the viewpoints it was trained from.

use glam::Vec3;
use rayon::prelude::*;
use talkin_grids::Part;

use super::shells::{CapsuleShells, frame_scene_and_rays};
use talkin_data::dataset::{Dataset, DatasetError};
use talkin_human::body::canonical_params;
use talkin_human::body::skeleton::body_ancestor;

/// How far past a capsule's box (metres) a point must lie to be skipped without its
/// exact distance: far above the rounding of either.
const BOX_SLACK_M: f32 = 1e-3;

/// Parts whose grid cells are carved to the training surfaces.
pub const CARVED_PARTS: [Part; 2] = [Part::Body, Part::Arms];

/// Canonical surface points of the body and arms over `frames` (dataset indices of one
/// subject's training frames), `None` if a frame has no depth or no frame shows a body or
/// arm pixel. A surface point is mapped
/// through every bone whose grown capsule holds it: the sampler's cull tries every
/// candidate bone of a sample, so each of them must find the surface where it puts it.
pub fn canonical_surface_points(
    dataset: &Dataset,
    frames: &[usize],
    shells: &CapsuleShells,
) -> Result<Option<Vec<Vec3>>, DatasetError> {
    let per_frame: Vec<Option<Vec<Vec3>>> = frames
        .par_iter()
        .map(|&i| frame_surface_points(dataset, i, shells))
        .collect::<Result<_, _>>()?;
    // No frames, or frames without a body or arm pixel, say nothing: nothing to carve.
    Ok(per_frame
        .into_iter()
        .collect::<Option<Vec<_>>>()
        .map(|v| v.concat())
        .filter(|points| !points.is_empty()))
}

fn frame_surface_points(
    dataset: &Dataset,
    i: usize,
    shells: &CapsuleShells,
) -> Result<Option<Vec<Vec3>>, DatasetError> {
    let frame = &dataset.frames[i];
    let canonical = dataset.subjects[frame.subject]
        .skeleton
        .pose(&canonical_params());
    let Some(depth) = dataset.depth(i)? else {
        return Ok(None);
    };
    let (scene, rays, pixels) = frame_scene_and_rays(dataset, &canonical, i)?;
    let grown = shells.inflate(&scene.capsules);
    let boxes: Vec<(Vec3, Vec3)> = grown
        .iter()
        .map(|c| {
            let reach = Vec3::splat(c.radius + BOX_SLACK_M);
            (c.a.min(c.b) - reach, c.a.max(c.b) + reach)
        })
        .collect();
    let forward = frame.camera.forward_in_world().as_vec3();
    let mut out = Vec::new();
    for (l, &px) in rays.iter().zip(&pixels) {
        let carved = Part::from_label(l.label).is_some_and(|p| CARVED_PARTS.contains(&p));
        let Some(z) = depth[px as usize].filter(|_| carved) else {
            continue;
        };
        let p_posed = l.ray.at(z / l.ray.direction.dot(forward));
        let mut done = 0u64;
        for (c, (lo, hi)) in grown.iter().zip(&boxes) {
            let bone = body_ancestor(c.bone as usize);
            // Outside the capsule's box by a millimetre is outside the capsule, whatever
            // the rounding: the exact distance is only taken near it.
            if done & (1 << bone) != 0
                || p_posed.cmplt(*lo).any()
                || p_posed.cmpgt(*hi).any()
                || talkin_grids::intersect::distance_to_segment(p_posed, c.a, c.b) > c.radius
            {
                continue;
            }
            done |= 1 << bone;
            out.push(scene.canonical_from_posed[bone].transform_point3(p_posed));
        }
    }
    Ok(Some(out))
}
