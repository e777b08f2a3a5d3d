//! Lazily decoded per-frame images: RGB, person mask and part segmentation.

use image::{GrayImage, RgbImage};

use super::{Dataset, DatasetError};

/// Number of segmentation labels: 0 background, 1 body, 2 arms, 3 hands, 4 head.
pub const N_LABELS: usize = 5;
/// Names of the segmentation labels, by label.
pub const LABEL_NAMES: [&str; N_LABELS] = ["background", "body", "arms", "hands", "head"];

/// A frame's decoded images, all of the camera's size.
#[derive(Clone, Debug)]
pub struct FrameImages {
    pub rgb: RgbImage,
    /// 255 = person (values >= 128 count as person for soft mattes).
    pub mask: GrayImage,
    /// Labels 0..=4.
    pub segmentation: GrayImage,
}

impl Dataset {
    /// Decodes frame `index`'s image, mask and segmentation, checking sizes and labels.
    pub fn images(&self, index: usize) -> Result<FrameImages, DatasetError> {
        let frame = &self.frames[index];
        let size = (frame.camera.width, frame.camera.height);
        let open = |rel: &std::path::Path| -> Result<image::DynamicImage, DatasetError> {
            let file = self.root.join(rel);
            let img = image::ImageReader::open(&file)
                .map_err(|source| DatasetError::Io {
                    file: file.clone(),
                    source,
                })?
                .with_guessed_format()
                .map_err(|source| DatasetError::Io {
                    file: file.clone(),
                    source,
                })?
                .decode()
                .map_err(|e| DatasetError::Image {
                    file: file.clone(),
                    problem: format!("cannot decode PNG: {e}"),
                })?;
            if img.dimensions_tuple() != size {
                return Err(DatasetError::Image {
                    file,
                    problem: format!(
                        "is {:?} but the frame's camera is {size:?}",
                        img.dimensions_tuple()
                    ),
                });
            }
            Ok(img)
        };
        let rgb = open(&frame.image)?.into_rgb8();
        let mask = open(&frame.mask)?.into_luma8();
        let segmentation = open(&frame.segmentation)?.into_luma8();
        if let Some(bad) = segmentation.pixels().find(|p| p.0[0] as usize >= N_LABELS) {
            return Err(DatasetError::Image {
                file: self.root.join(&frame.segmentation),
                problem: format!(
                    "label {} is not one of 0..={} ({})",
                    bad.0[0],
                    N_LABELS - 1,
                    LABEL_NAMES.join(", ")
                ),
            });
        }
        Ok(FrameImages {
            rgb,
            mask,
            segmentation,
        })
    }
}

trait Dimensions {
    fn dimensions_tuple(&self) -> (u32, u32);
}

impl Dimensions for image::DynamicImage {
    fn dimensions_tuple(&self) -> (u32, u32) {
        (self.width(), self.height())
    }
}

impl Dataset {
    /// Decodes frame `index`'s ground-truth depth (camera z in metres per pixel, row-major,
    /// `None` where there is no surface), if the frame has a depth file.
    pub fn depth(&self, index: usize) -> Result<Option<Vec<Option<f32>>>, DatasetError> {
        let frame = &self.frames[index];
        let Some(rel) = &frame.depth else {
            return Ok(None);
        };
        let file = self.root.join(rel);
        let img = image::ImageReader::open(&file)
            .map_err(|source| DatasetError::Io {
                file: file.clone(),
                source,
            })?
            .decode()
            .map_err(|e| DatasetError::Image {
                file: file.clone(),
                problem: format!("cannot decode PNG: {e}"),
            })?;
        if img.dimensions_tuple() != (frame.camera.width, frame.camera.height) {
            return Err(DatasetError::Image {
                file,
                problem: "depth size differs from the camera's".into(),
            });
        }
        let depth = img
            .into_luma16()
            .pixels()
            .map(|p| (p.0[0] > 0).then(|| (p.0[0] as f64 * super::DEPTH_UNIT_M) as f32))
            .collect();
        Ok(Some(depth))
    }
}
