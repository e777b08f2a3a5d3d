//! One frame's geometry in posed (world) space: skeleton, capsules, bounding box, rays.

use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use talkin_grids::{Capsule, GridError, LabelledRay, Ray};

use talkin_data::dataset::FrameImages;
use talkin_human::body::{N_JOINTS, PosedSkeleton, Skeleton, canonical_from_posed, limb_capsules};
use talkin_human::camera::Camera;

/// A posed frame: its skeleton, bare capsules and per-joint posed-to-canonical maps.
#[derive(Clone, Debug)]
pub struct FrameScene {
    pub posed: PosedSkeleton,
    /// Bare (uninflated) limb capsules in world space.
    pub capsules: Vec<Capsule>,
    /// Per SMPL-X joint: posed (world) -> canonical, for points rigidly attached to it.
    pub canonical_from_posed: [Affine3A; N_JOINTS],
}

impl FrameScene {
    pub fn new(
        skeleton: &Skeleton,
        canonical: &PosedSkeleton,
        params: &talkin_human::body::FrameParams,
    ) -> FrameScene {
        let posed = skeleton.pose(params);
        let capsules = shell_capsules(skeleton, &posed);
        let maps = canonical_from_posed(&posed, canonical);
        let canonical_from_posed = maps
            .map(|m| Affine3A::from_mat3_translation(m.matrix3.as_mat3(), m.translation.as_vec3()));
        FrameScene {
            posed,
            capsules,
            canonical_from_posed,
        }
    }
}

/// Capsules longer than this (metres, in units of the skeleton's size) are cut in two for
/// the sampler, so each half fits its own shell: a skirt flares at the knee, not the hip;
/// a sleeve at the cuff, not the shoulder.
pub const SPLIT_LENGTH: f32 = 0.08;

/// The sampler's capsules of a posed skeleton: the limb capsules with every long one cut
/// into equal pieces of at most `SPLIT_LENGTH` (same part, bone and radius), in a fixed
/// order, so per-capsule shells fitted on one frame apply to every frame and to the
/// canonical pose.
pub fn shell_capsules(skeleton: &Skeleton, posed: &PosedSkeleton) -> Vec<Capsule> {
    let max_len = SPLIT_LENGTH * skeleton.scale() as f32;
    let rest = limb_capsules(
        skeleton,
        &skeleton.pose(&talkin_human::body::FrameParams::default()),
    );
    limb_capsules(skeleton, posed)
        .into_iter()
        .zip(rest)
        .flat_map(|(c, r)| {
            // The piece count comes from the rest pose so it never changes between frames.
            let pieces = ((r.b - r.a).length() / max_len).ceil().max(1.0) as usize;
            (0..pieces).map(move |k| {
                let (t0, t1) = (k as f32 / pieces as f32, (k + 1) as f32 / pieces as f32);
                Capsule {
                    a: c.a.lerp(c.b, t0),
                    b: c.a.lerp(c.b, t1),
                    ..c
                }
            })
        })
        .collect()
}

/// The box around capsules (grids' own, re-exported where a frame's scene is built).
pub use talkin_grids::capsule_bounds;

/// Rays through the person's pixels (mask >= 128), labelled with their segmentation part
/// (a person pixel labelled background counts as body). Also returns each ray's pixel
/// index (`y * width + x`).
pub fn foreground_rays(
    camera: &Camera,
    images: &FrameImages,
) -> Result<(Vec<LabelledRay>, Vec<u32>), GridError> {
    let mut rays = Vec::new();
    let mut pixels = Vec::new();
    for (x, y, m) in images.mask.enumerate_pixels() {
        if m.0[0] < 128 {
            continue;
        }
        let (origin, dir) = camera.pixel_ray(x, y);
        let label = images.segmentation.get_pixel(x, y).0[0].max(1);
        rays.push(LabelledRay {
            ray: Ray::new(origin.as_vec3(), dir.as_vec3(), 0.0, f32::INFINITY)?,
            label,
        });
        pixels.push(y * camera.width + x);
    }
    Ok((rays, pixels))
}

/// The step the dense sampler takes on the median ray: its chord through the box over the
/// dense sample count. The accelerated sampler uses it, so both sample the body equally
/// finely. 5 mm if no ray crosses the box.
pub fn median_dense_step(rays: &[Ray], lo: Vec3, hi: Vec3, dense_samples: u32) -> f32 {
    let mut chords: Vec<f32> = rays
        .par_iter()
        .filter_map(|r| talkin_grids::ray::clip_to_box(r, lo, hi))
        .map(|(t0, t1)| t1 - t0)
        .collect();
    // The element a full sort would put in the middle, found in linear time: this runs
    // in every frame's build, over all of the frame's rays (the chords on every thread:
    // a 540x540 render's build took 5 ms on one).
    let mid = chords.len() / 2;
    if !chords.is_empty() {
        chords.select_nth_unstable_by(mid, f32::total_cmp);
    }
    chords
        .get(mid)
        .map(|c| c / dense_samples as f32)
        .filter(|s| s.is_finite() && *s > 0.0)
        .unwrap_or(0.005)
}

#[cfg(test)]
mod tests {
    use glam::vec3;

    use super::*;

    /// The linear-time selection gives the sorted middle chord: rays through a unit box at
    /// different offsets have chords of different lengths.
    #[test]
    fn median_step_is_the_sorted_middle_chord() {
        let (lo, hi) = (Vec3::ZERO, Vec3::ONE);
        let mut chords = Vec::new();
        let mut rays = Vec::new();
        for k in 0..101 {
            // Rays from inside the box at angles in a scrambled order: their chords (to
            // the x = 1 face or the top) all differ.
            let angle = ((k * 37) % 101) as f32 / 101.0 * 1.2 + 0.01;
            let direction = vec3(angle.cos(), angle.sin(), 0.0);
            let ray = Ray::new(vec3(0.0, 0.5, 0.5), direction, 0.0, f32::INFINITY).unwrap();
            let (t0, t1) = talkin_grids::ray::clip_to_box(&ray, lo, hi).unwrap();
            chords.push(t1 - t0);
            rays.push(ray);
        }
        // A ray that misses the box is not counted.
        rays.push(Ray::new(vec3(-1.0, 5.0, 0.5), Vec3::X, 0.0, f32::INFINITY).unwrap());
        // The unsorted middle is another chord, so this checks the selection.
        let unsorted_middle = chords[50];
        chords.sort_by(f32::total_cmp);
        assert_ne!(unsorted_middle, chords[50]);
        assert_eq!(median_dense_step(&rays, lo, hi, 4), chords[50] / 4.0);
        assert_eq!(median_dense_step(&[], lo, hi, 4), 0.005);
    }
}
