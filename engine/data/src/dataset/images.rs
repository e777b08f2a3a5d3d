//! Lazily decoded per-frame images: RGB, person mask and part segmentation.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use image::{DynamicImage, GrayImage, ImageFormat, ImageReader, RgbImage};

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

/// Opens `file` as a PNG (by content, not extension): a clear error for a missing file,
/// an unreadable one or another format.
pub(crate) fn open_png(file: &Path) -> Result<ImageReader<BufReader<File>>, DatasetError> {
    let io = |source| DatasetError::Io {
        file: file.to_path_buf(),
        source,
    };
    let reader = ImageReader::open(file)
        .map_err(io)?
        .with_guessed_format()
        .map_err(io)?;
    if reader.format() != Some(ImageFormat::Png) {
        return Err(DatasetError::Image {
            file: file.to_path_buf(),
            problem: "not a PNG file".into(),
        });
    }
    Ok(reader)
}

/// Decodes the PNG at `root/rel` and checks it is `size` (width, height).
fn decode_png(root: &Path, rel: &Path, size: (u32, u32)) -> Result<DynamicImage, DatasetError> {
    let file = root.join(rel);
    let img = open_png(&file)?.decode().map_err(|e| DatasetError::Image {
        file: file.clone(),
        problem: format!("cannot decode PNG: {e}"),
    })?;
    if (img.width(), img.height()) != size {
        return Err(DatasetError::Image {
            file,
            problem: format!(
                "is {}x{} but the frame's camera is {}x{}",
                img.width(),
                img.height(),
                size.0,
                size.1
            ),
        });
    }
    Ok(img)
}

impl Dataset {
    /// Decodes frame `index`'s image, mask and segmentation, checking sizes and labels.
    pub fn images(&self, index: usize) -> Result<FrameImages, DatasetError> {
        let frame = &self.frames[index];
        let size = (frame.camera.width, frame.camera.height);
        let rgb = decode_png(&self.root, &frame.image, size)?.into_rgb8();
        let mask = decode_png(&self.root, &frame.mask, size)?.into_luma8();
        let segmentation = decode_png(&self.root, &frame.segmentation, size)?.into_luma8();
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

    /// Decodes frame `index`'s ground-truth depth (camera z in metres per pixel, row-major,
    /// `None` where there is no surface), if the frame has a depth file.
    pub fn depth(&self, index: usize) -> Result<Option<Vec<Option<f32>>>, DatasetError> {
        let frame = &self.frames[index];
        let Some(rel) = &frame.depth else {
            return Ok(None);
        };
        let img = decode_png(&self.root, rel, (frame.camera.width, frame.camera.height))?;
        let depth = img
            .into_luma16()
            .pixels()
            .map(|p| (p.0[0] > 0).then(|| (p.0[0] as f64 * super::DEPTH_UNIT_M) as f32))
            .collect();
        Ok(Some(depth))
    }
}
