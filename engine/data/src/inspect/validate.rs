//! One validation for every command: what `talkin inspect` reports, `train`, `adapt`,
//! `eval`, `render` and `serve` check before any work, so a dataset whose masks are empty
//! or whose fits do not line up with the images is refused up front, not trained on.

use crate::dataset::{Dataset, DatasetError, INDEX_FILE};

use super::summary::{Summary, summarize};

/// Below this share of projected body joints on the person, over the whole dataset, the
/// fits or cameras do not line up with the images.
pub const MIN_JOINTS_ON_PERSON: f64 = 0.8;
/// A frame below this share is flagged (listed, not refused): one bad fit in a video.
pub const FRAME_MIN_JOINTS_ON_PERSON: f64 = 0.6;
/// Above this share of pixels where the mask and the segmentation disagree, they do not
/// mark the same person.
pub const MAX_MASK_SEG_DISAGREEMENT: f64 = 0.05;

/// Something the validation found.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem {
    /// The dataset.json field at fault (`frames[12].mask`, or `frames` for the whole).
    pub field: String,
    pub message: String,
    /// Whether the dataset is refused for it (else it is only flagged).
    pub fatal: bool,
}

impl Summary {
    /// What is wrong, fatal problems first, then flagged frames.
    pub fn problems(&self) -> Vec<Problem> {
        let mut fatal = Vec::new();
        let mut flagged = Vec::new();
        for c in &self.frames {
            let i = c.frame;
            if c.person_pixels == 0 {
                fatal.push(Problem {
                    field: format!("frames[{i}].mask"),
                    message: "the mask is empty: no pixel marks the person (255 = person)".into(),
                    fatal: true,
                });
            } else if c.joints_in_image == 0 {
                fatal.push(Problem {
                    field: format!("frames[{i}].camera"),
                    message: "no body joint projects into the image: the camera or the \
                              translation puts the body off-screen"
                        .into(),
                    fatal: true,
                });
            } else if c.joints_on_person_share() < FRAME_MIN_JOINTS_ON_PERSON {
                flagged.push(Problem {
                    field: format!("frames[{i}].params"),
                    message: format!(
                        "{} of {} projected body joints on the person: a bad fit?",
                        c.joints_on_person, c.joints_in_image
                    ),
                    fatal: false,
                });
            }
        }
        if self.frames.iter().any(|c| c.joints_in_image > 0)
            && self.joints_on_person < MIN_JOINTS_ON_PERSON
        {
            fatal.push(Problem {
                field: "frames".into(),
                message: format!(
                    "only {:.0}% of projected body joints land on the person mask: poses or \
                     cameras do not line up with the images (extrinsics must be \
                     world-to-camera in OpenCV axes; look at `talkin inspect --overlay`)",
                    100.0 * self.joints_on_person
                ),
                fatal: true,
            });
        }
        if self.mask_seg_disagreement > MAX_MASK_SEG_DISAGREEMENT {
            fatal.push(Problem {
                field: "frames".into(),
                message: format!(
                    "mask and segmentation disagree on {:.1}% of pixels: they should mark \
                     the same person",
                    100.0 * self.mask_seg_disagreement
                ),
                fatal: true,
            });
        }
        if !self.contradicting_frames.is_empty() {
            fatal.push(Problem {
                field: "matting".into(),
                message: format!(
                    "the dataset declares its images matted over the background, but {} of {} \
                     frames are not: outside their masks up to {:.0}% of pixels are off the \
                     background (frames {}). Every command composites those frames by their \
                     masks and training says so; declare it with `\"matting\": \"by_mask\"` \
                     in dataset.json (what `talkin import` writes)",
                    self.contradicting_frames.len(),
                    self.frames.len(),
                    100.0
                        * self
                            .frames
                            .iter()
                            .map(|c| c.surroundings_off_share)
                            .fold(0.0f32, f32::max),
                    super::summary::frame_list(&self.contradicting_frames)
                ),
                fatal: true,
            });
        }
        fatal.extend(flagged);
        fatal
    }
}

/// Decodes every frame and checks it as `talkin inspect` does; the first fatal problem is
/// the error (naming dataset.json and the field), flagged frames come back with the
/// summary for the caller to show.
pub fn validate(
    dataset: &Dataset,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Summary, DatasetError> {
    let summary = summarize(dataset, progress)?;
    if let Some(p) = summary.problems().into_iter().find(|p| p.fatal) {
        return Err(DatasetError::Invalid {
            file: dataset.root.join(INDEX_FILE),
            field: p.field,
            problem: p.message,
        });
    }
    Ok(summary)
}
