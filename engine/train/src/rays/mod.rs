//! One step's rays: LPIPS patches and part-aware random pixels (the paper's schedule),
//! with their target colours and segmentation labels, from a cached training frame.

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use talkin_grids::{GridError, Ray};
use talkin_nets::FrameConditions;

mod pool;

pub(crate) use pool::PixelPool;

use crate::schedule::PartFractions;
use talkin_avatar::field_inputs::frame_conditions;
use talkin_avatar::scene::{FrameSampler, FrameScene};
use talkin_avatar::subject::SubjectModel;
use talkin_data::dataset::{Dataset, DatasetError, FrameImages, N_LABELS, on_mask_cut};
use talkin_grids::SplitMix64;
use talkin_human::body::FrameParams;

/// Side of an LPIPS patch (pixels).
pub const PATCH: u32 = 32;

/// A training frame's decoded images, pixel lists and sampler (built once per frame).
pub(crate) struct FrameCache {
    pub images: FrameImages,
    /// Where its random rays come from.
    pub pixels: PixelPool,
    pub conditions: FrameConditions,
    pub sampler: FrameSampler,
    /// The person's pixel rays (the accelerated step is measured on them).
    foreground_rays: Vec<Ray>,
    /// The pose correction the conditions and sampler were built with (`None`: the fit).
    pub posed_with: Option<Vec<f32>>,
}

/// The training frames cached so far, by dataset frame (a frame is cached on its first
/// draw and kept for the run).
#[derive(Default)]
pub(crate) struct FrameCaches {
    by_frame: HashMap<usize, FrameCache>,
}

impl FrameCaches {
    /// Frame `i`'s cache, built by `build` on its first use.
    pub fn get_or_build<E>(
        &mut self,
        i: usize,
        build: impl FnOnce() -> Result<FrameCache, E>,
    ) -> Result<&mut FrameCache, E> {
        match self.by_frame.entry(i) {
            Entry::Occupied(e) => Ok(e.into_mut()),
            Entry::Vacant(e) => Ok(e.insert(build()?)),
        }
    }

    /// Frame `i`'s cache; `i` has been drawn ([`FrameCaches::get_or_build`]).
    pub fn get(&self, i: usize) -> &FrameCache {
        &self.by_frame[&i]
    }

    /// [`FrameCaches::get`], to change.
    pub fn get_mut(&mut self, i: usize) -> &mut FrameCache {
        self.by_frame
            .get_mut(&i)
            .expect("a frame is cached before its rays are drawn")
    }
}

/// Why a frame could not be cached.
#[derive(Debug)]
pub(crate) enum CacheError {
    Dataset(DatasetError),
    Grid(GridError),
}

impl FrameCache {
    /// Frame `i` of `dataset`, its subject being identity `slot` with `model`, posed as
    /// its fit; random rays stay `mask_edge` px off the mask's cut; for a field that
    /// skins the finger joints (`finger_bones`) or not, and reads frame code `code`.
    pub fn new(
        dataset: &Dataset,
        i: usize,
        slot: usize,
        model: &SubjectModel,
        mask_edge: u32,
        finger_bones: bool,
        code: Option<usize>,
    ) -> Result<FrameCache, CacheError> {
        let frame = &dataset.frames[i];
        let images = dataset.images(i).map_err(CacheError::Dataset)?;
        let scene = FrameScene::new(&model.skeleton, &model.canonical, &frame.params);
        let mut rays = Vec::new();
        for (x, y, m) in images.mask.enumerate_pixels() {
            if m.0[0] < 128 {
                continue;
            }
            let (o, d) = frame.camera.pixel_ray(x, y);
            rays.push(
                Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY).map_err(CacheError::Grid)?,
            );
        }
        let pixels = PixelPool::new(&images.mask, &images.segmentation, mask_edge);
        let conditions = FrameConditions {
            frame_code: code,
            ..frame_conditions(slot, &frame.params, &scene, &model.shells, finger_bones)
        };
        let sampler = FrameSampler::new(scene, &model.shells, &rays, finger_bones)
            .map_err(CacheError::Grid)?;
        Ok(FrameCache {
            images,
            pixels,
            conditions,
            sampler,
            foreground_rays: rays,
            posed_with: None,
        })
    }

    /// Rebuilds the frame's conditions and sampler in pose `params` (the fit with
    /// correction `delta`): the capsule intervals follow the corrected body.
    pub fn repose(
        &mut self,
        params: &FrameParams,
        delta: &[f32],
        slot: usize,
        model: &SubjectModel,
        finger_bones: bool,
    ) -> Result<(), GridError> {
        let scene = FrameScene::new(&model.skeleton, &model.canonical, params);
        let conditions = FrameConditions {
            frame_code: self.conditions.frame_code,
            ..frame_conditions(slot, params, &scene, &model.shells, finger_bones)
        };
        self.sampler =
            FrameSampler::new(scene, &model.shells, &self.foreground_rays, finger_bones)?;
        self.conditions = conditions;
        self.posed_with = Some(delta.to_vec());
        Ok(())
    }
}

/// One step's rays and their targets.
pub(crate) struct Batch {
    pub rays: Vec<Ray>,
    /// `[r * 3]` in [0, 1].
    pub rgb: Vec<f32>,
    pub labels: Vec<i32>,
    /// 1 where the mask is sure of the pixel (off its cut), 0 on the cut: the weight of
    /// the ray's silhouette term. `[r]`
    pub silhouette: Vec<f32>,
    /// The mask's coverage of the pixel (mask / 255), what the target was composited
    /// with. `[r]`
    pub alpha: Vec<f32>,
    /// The first `patches * PATCH * PATCH` rays are row-major patches.
    pub patches: usize,
}

/// What to draw.
pub(crate) struct BatchSpec {
    pub patches: usize,
    pub random_rays: usize,
    pub bbox_fraction: f32,
    pub parts: PartFractions,
}

/// Draws `spec.patches` 32x32 patches overlapping the person's box, then
/// `spec.random_rays` pixels: `bbox_fraction` of them in the person's box, of which
/// `parts.hands` from hand pixels and `parts.arms` from arm pixels (when the frame has
/// any), the rest anywhere in the image. A random ray on the mask's edge is drawn again
/// (the patches are kept whole: LPIPS compares whole patches).
pub(crate) fn draw_batch(
    dataset: &Dataset,
    i: usize,
    fc: &FrameCache,
    spec: &BatchSpec,
    rng: &mut SplitMix64,
) -> Result<Batch, GridError> {
    let camera = &dataset.frames[i].camera;
    let (w, h) = (camera.width, camera.height);
    let mut pixels: Vec<(u32, u32)> = Vec::new();
    let patches = if w >= PATCH && h >= PATCH {
        spec.patches
    } else {
        0
    };
    for _ in 0..patches {
        let [x0, y0, x1, y1] = fc.pixels.bbox.unwrap_or([0, 0, w - 1, h - 1]);
        // A patch centre in the box; the patch is clamped into the image.
        let cx = x0 + rng.below(u64::from(x1 - x0 + 1)) as u32;
        let cy = y0 + rng.below(u64::from(y1 - y0 + 1)) as u32;
        let px = cx.saturating_sub(PATCH / 2).min(w - PATCH);
        let py = cy.saturating_sub(PATCH / 2).min(h - PATCH);
        for y in py..py + PATCH {
            for x in px..px + PATCH {
                pixels.push((x, y));
            }
        }
    }
    for _ in 0..spec.random_rays {
        pixels.push(fc.pixels.draw(spec, rng));
    }
    let mut batch = Batch {
        rays: Vec::with_capacity(pixels.len()),
        rgb: Vec::with_capacity(3 * pixels.len()),
        labels: Vec::with_capacity(pixels.len()),
        silhouette: Vec::with_capacity(pixels.len()),
        alpha: Vec::with_capacity(pixels.len()),
        patches,
    };
    for (x, y) in pixels {
        let (o, d) = camera.pixel_ray(x, y);
        batch
            .rays
            .push(Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY)?);
        let c = fc.images.rgb.get_pixel(x, y).0;
        batch.rgb.extend(c.iter().map(|&v| f32::from(v) / 255.0));
        let coverage = fc.images.mask.get_pixel(x, y).0[0];
        batch.alpha.push(f32::from(coverage) / 255.0);
        let person = coverage >= 128;
        let label = fc.images.segmentation.get_pixel(x, y).0[0];
        // A person pixel labelled background counts as body (labels are validated on
        // decode, so every label is below N_LABELS).
        let label = if person { label.max(1) } else { 0 };
        debug_assert!((label as usize) < N_LABELS);
        batch.labels.push(i32::from(label));
        // Part person, part background: no silhouette target.
        let cut = on_mask_cut(&fc.images.mask, x, y);
        batch.silhouette.push(if cut { 0.0 } else { 1.0 });
    }
    Ok(batch)
}

impl Batch {
    /// Moves the targets from over `from` to over `to`: a target composited as
    /// `image x alpha + from x (1 - alpha)` becomes `image x alpha + to x (1 - alpha)`.
    pub fn recomposite(&mut self, from: [f32; 3], to: [f32; 3]) {
        for (rgb, a) in self.rgb.chunks_exact_mut(3).zip(&self.alpha) {
            for c in 0..3 {
                rgb[c] = (rgb[c] + (to[c] - from[c]) * (1.0 - a)).clamp(0.0, 1.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A target moved to another background keeps the person and swaps only the
    /// uncovered share of the old background.
    #[test]
    fn recompositing_swaps_only_the_background_share() {
        let mut batch = Batch {
            rays: vec![],
            rgb: vec![0.2, 0.4, 0.6, 1.0, 1.0, 1.0, 0.6, 0.7, 0.8],
            labels: vec![1, 0, 1],
            silhouette: vec![1.0; 3],
            alpha: vec![1.0, 0.0, 0.5],
            patches: 0,
        };
        batch.recomposite([1.0; 3], [0.0, 0.5, 1.0]);
        let want = [0.2, 0.4, 0.6, 0.0, 0.5, 1.0, 0.1, 0.45, 0.8];
        for (g, w) in batch.rgb.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{:?}", batch.rgb);
        }
    }
}
