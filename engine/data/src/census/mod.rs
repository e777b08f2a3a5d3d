//! A census of the frames a run trains on: per subject, how many pixels each part covers,
//! how much its articulation moves over the frames, how large a pixel is at the person's
//! depth, and how many frames and views there are. It describes the data only; what a run
//! builds from it is the trainer's plan.

mod articulation;
mod pixels;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

pub use articulation::Articulation;
pub use pixels::{LabelSource, PartPixels};

use crate::dataset::{Dataset, DatasetError, Matting};

/// At most this many frames of a subject have their pixels counted (evenly spaced over
/// its frames): label derivation costs about 0.1 s a 512x512 frame on one core, and the
/// shares of 24 spread frames are within a point of all 90 on ZJU-MoCap 387.
pub const MAX_COUNTED_FRAMES: usize = 24;

/// What the frames of every subject hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Census {
    pub subjects: Vec<SubjectCensus>,
    /// The frames are a camera's (`"matting": "by_mask"`, what `import` writes): masks
    /// from a segmenter and fits from a fitter, which place the body from frame to frame
    /// within about a centimetre, not exactly as a synthetic scene's.
    #[serde(default)]
    pub capture: bool,
}

/// What one subject's frames hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SubjectCensus {
    pub name: String,
    /// Frames of this subject the census was taken over.
    pub frames: usize,
    /// Distinct cameras among them.
    pub views: usize,
    /// Frames whose pixels were counted.
    pub frames_counted: usize,
    /// Mean pixels a counted frame, by part.
    pub pixels: PartPixels,
    /// Where the part labels came from.
    pub labels: LabelSource,
    /// How much the fits' articulation moves over the frames.
    pub articulation: Articulation,
    /// Millimetres a pixel spans at the pelvis' depth (median over the frames); `None`
    /// without frames.
    pub footprint_mm: Option<f64>,
    /// The canonical body's size: its limb capsules in the canonical pose.
    pub canonical: CanonicalSize,
}

/// The canonical body's size, from its limb capsules in the canonical pose.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CanonicalSize {
    /// The longest side of the capsules' bounding box (metres).
    pub extent_m: f64,
    /// The capsules' summed surface (square metres; overlaps counted twice).
    pub surface_m2: f64,
}

impl CanonicalSize {
    fn of(skeleton: &talkin_human::body::Skeleton) -> CanonicalSize {
        let posed = skeleton.pose(&talkin_human::body::canonical_params());
        let capsules = talkin_human::body::limb_capsules(skeleton, &posed);
        let (lo, hi) = talkin_grids::capsule_bounds(&capsules, 0.0);
        let surface: f64 = capsules
            .iter()
            .map(|c| {
                let (r, len) = (f64::from(c.radius), f64::from(c.a.distance(c.b)));
                2.0 * std::f64::consts::PI * r * len + 4.0 * std::f64::consts::PI * r * r
            })
            .sum();
        let extent = f64::from((hi - lo).max_element());
        CanonicalSize {
            extent_m: if extent.is_finite() { extent } else { 0.0 },
            surface_m2: surface,
        }
    }
}

impl Census {
    /// The census of `frames` (indices into `dataset.frames`), by subject in the dataset's
    /// order; a subject without frames is listed with zeros. Decodes each counted frame's
    /// mask and labels (deriving labels where the frame has none), in parallel.
    pub fn of(dataset: &Dataset, frames: &[usize]) -> Result<Census, DatasetError> {
        let mut by_subject: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for &i in frames {
            by_subject
                .entry(dataset.frames[i].subject)
                .or_default()
                .push(i);
        }
        let subjects = (0..dataset.subjects.len())
            .map(|s| {
                let own = by_subject.remove(&s).unwrap_or_default();
                subject_census(dataset, s, &own)
            })
            .collect::<Result<_, _>>()?;
        Ok(Census {
            subjects,
            capture: dataset.matting == Matting::ByMask,
        })
    }

    /// The subjects that have frames.
    pub fn present(&self) -> impl Iterator<Item = &SubjectCensus> {
        self.subjects.iter().filter(|s| s.frames > 0)
    }
}

fn subject_census(
    dataset: &Dataset,
    subject: usize,
    frames: &[usize],
) -> Result<SubjectCensus, DatasetError> {
    let counted = spread(frames, MAX_COUNTED_FRAMES);
    let (pixels, labels) = pixels::count(dataset, &counted)?;
    let params: Vec<_> = frames.iter().map(|&i| &dataset.frames[i].params).collect();
    let skeleton = &dataset.subjects[subject].skeleton;
    let mut footprints: Vec<f64> = frames
        .iter()
        .filter_map(|&i| {
            let frame = &dataset.frames[i];
            let pelvis = skeleton.pose(&frame.params).joint(0);
            let depth = frame.camera.depth_of(pelvis);
            let focal = frame.camera.intrinsics.x_axis.x;
            let mm = 1000.0 * depth / focal;
            (depth > 0.0 && focal > 0.0 && mm.is_finite()).then_some(mm)
        })
        .collect();
    footprints.sort_by(f64::total_cmp);
    Ok(SubjectCensus {
        name: dataset.subjects[subject].name.clone(),
        frames: frames.len(),
        views: views(dataset, frames),
        frames_counted: counted.len(),
        pixels,
        labels,
        articulation: Articulation::of(&params),
        footprint_mm: footprints.get(footprints.len() / 2).copied(),
        canonical: CanonicalSize::of(skeleton),
    })
}

/// At most `n` of `items`, evenly spaced, the first included (also how `inspect` picks a
/// contact sheet's frames).
pub(crate) fn spread(items: &[usize], n: usize) -> Vec<usize> {
    if items.len() <= n {
        return items.to_vec();
    }
    (0..n).map(|k| items[k * items.len() / n]).collect()
}

/// Distinct cameras among `frames`: centres within a millimetre and optical axes within
/// a thousandth of a radian are one view.
fn views(dataset: &Dataset, frames: &[usize]) -> usize {
    let mut seen: Vec<(glam::DVec3, glam::DVec3)> = Vec::new();
    for &i in frames {
        let camera = &dataset.frames[i].camera;
        let (centre, axis) = (camera.center_in_world(), camera.forward_in_world());
        let known = seen
            .iter()
            .any(|(c, a)| c.distance(centre) < 1e-3 && a.distance(axis) < 1e-3);
        if !known {
            seen.push((centre, axis));
        }
    }
    seen.len()
}

#[cfg(test)]
mod tests;
