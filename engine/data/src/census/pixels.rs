//! Pixels a frame by part, from each frame's labels (the dataset's, or derived from the
//! posed capsules where a frame has none); a hand pixel belongs to the hand whose wrist
//! projects nearer.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use talkin_human::body::joint;

use crate::dataset::{Dataset, DatasetError};

/// Mean pixels a frame, by part (labels 1 body, 2 arms, 3 hands, 4 head).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartPixels {
    /// The whole frame.
    pub frame: f64,
    /// Inside the mask.
    pub person: f64,
    pub body: f64,
    pub arms: f64,
    pub head: f64,
    pub left_hand: f64,
    pub right_hand: f64,
    /// Counted frames in which any hand pixel shows.
    pub frames_with_hands: usize,
    /// Counted frames in which any head pixel shows.
    pub frames_with_head: usize,
}

impl PartPixels {
    /// Both hands.
    pub fn hands(&self) -> f64 {
        self.left_hand + self.right_hand
    }

    /// `part`'s share of the person's pixels (0 without a person).
    pub fn share(&self, part: f64) -> f64 {
        if self.person > 0.0 {
            part / self.person
        } else {
            0.0
        }
    }
}

/// Where the labels the pixels were counted from came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LabelSource {
    /// No frame counted.
    None,
    /// The dataset's segmentation files.
    Given,
    /// The posed capsules' projection.
    Derived,
    /// Some of each.
    Mixed,
}

/// The mean pixels a frame over `frames`, and where their labels came from.
pub(super) fn count(
    dataset: &Dataset,
    frames: &[usize],
) -> Result<(PartPixels, LabelSource), DatasetError> {
    let per_frame: Vec<(PartPixels, bool)> = frames
        .par_iter()
        .map(|&i| frame_pixels(dataset, i))
        .collect::<Result<_, _>>()?;
    let n = per_frame.len();
    if n == 0 {
        return Ok((PartPixels::default(), LabelSource::None));
    }
    let mut sum = PartPixels::default();
    for (p, _) in &per_frame {
        sum.frame += p.frame;
        sum.person += p.person;
        sum.body += p.body;
        sum.arms += p.arms;
        sum.head += p.head;
        sum.left_hand += p.left_hand;
        sum.right_hand += p.right_hand;
        sum.frames_with_hands += p.frames_with_hands;
        sum.frames_with_head += p.frames_with_head;
    }
    let mean = |x: f64| x / n as f64;
    let derived = per_frame.iter().filter(|(_, d)| *d).count();
    let source = match derived {
        0 => LabelSource::Given,
        d if d == n => LabelSource::Derived,
        _ => LabelSource::Mixed,
    };
    Ok((
        PartPixels {
            frame: mean(sum.frame),
            person: mean(sum.person),
            body: mean(sum.body),
            arms: mean(sum.arms),
            head: mean(sum.head),
            left_hand: mean(sum.left_hand),
            right_hand: mean(sum.right_hand),
            ..sum
        },
        source,
    ))
}

/// One frame's pixels, and whether its labels were derived.
fn frame_pixels(dataset: &Dataset, index: usize) -> Result<(PartPixels, bool), DatasetError> {
    let images = dataset.images(index)?;
    let frame = &dataset.frames[index];
    let posed = dataset.subjects[frame.subject].skeleton.pose(&frame.params);
    let wrist = |j: usize| frame.camera.project(posed.joint(j)).map(|p| p.truncate());
    let (left, right) = (wrist(joint::LEFT_WRIST), wrist(joint::RIGHT_WRIST));
    let mut p = PartPixels {
        frame: f64::from(images.mask.width()) * f64::from(images.mask.height()),
        ..PartPixels::default()
    };
    for (x, y, m) in images.mask.enumerate_pixels() {
        if m.0[0] < 128 {
            continue;
        }
        p.person += 1.0;
        match images.segmentation.get_pixel(x, y).0[0] {
            2 => p.arms += 1.0,
            3 => {
                let at = glam::DVec2::new(f64::from(x) + 0.5, f64::from(y) + 0.5);
                let gap = |w: Option<glam::DVec2>| w.map_or(f64::INFINITY, |w| w.distance(at));
                if gap(right) < gap(left) {
                    p.right_hand += 1.0;
                } else {
                    p.left_hand += 1.0;
                }
            }
            4 => p.head += 1.0,
            _ => p.body += 1.0,
        }
    }
    p.frames_with_hands = usize::from(p.hands() > 0.0);
    p.frames_with_head = usize::from(p.head > 0.0);
    Ok((p, images.labels_derived))
}
