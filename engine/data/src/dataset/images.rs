//! Lazily decoded per-frame images: RGB, person mask and part segmentation.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use image::{DynamicImage, GrayImage, ImageFormat, ImageReader, RgbImage};

use super::matting::{Composited, Matting, Surroundings, composite, recomposite, surroundings};
use super::{Dataset, DatasetError, derived_segmentation};

/// Number of segmentation labels: 0 background, 1 body, 2 arms, 3 hands, 4 head.
pub const N_LABELS: usize = 5;
/// Names of the segmentation labels, by label.
pub const LABEL_NAMES: [&str; N_LABELS] = ["background", "body", "arms", "hands", "head"];

/// A frame's decoded images, all of the camera's size.
#[derive(Clone, Debug)]
pub struct FrameImages {
    /// The target every command trains on, scores against and shows: the person over the
    /// dataset's background (the file composited by its mask, unless the file already is).
    pub rgb: RgbImage,
    /// Whether and why `rgb` was composited from the file ([`Dataset::file_rgb`] gives
    /// the file as it is).
    pub composited: Composited,
    /// How far the file's pixels outside the mask lie from the background.
    pub surroundings: Surroundings,
    /// 255 = person (values >= 128 count as person for soft mattes).
    pub mask: GrayImage,
    /// Labels 0..=4.
    pub segmentation: GrayImage,
    /// The frame had no segmentation file: the labels were derived from the mask and
    /// the posed capsules ([`super::derived_segmentation`]).
    pub labels_derived: bool,
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

/// Decodes the PNG at `root/rel` and checks it is `size` (width, height): from its header
/// first, so that a file claiming another size (say 60000 x 60000) is refused before any
/// pixel is allocated.
fn decode_png(root: &Path, rel: &Path, size: (u32, u32)) -> Result<DynamicImage, DatasetError> {
    let file = root.join(rel);
    let bad = |e: image::ImageError| DatasetError::Image {
        file: file.clone(),
        problem: format!("cannot decode PNG: {e}"),
    };
    let wrong_size = |found: (u32, u32)| DatasetError::Image {
        file: file.clone(),
        problem: format!(
            "is {}x{} but the frame's camera is {}x{}",
            found.0, found.1, size.0, size.1
        ),
    };
    let claimed = open_png(&file)?.into_dimensions().map_err(bad)?;
    if claimed != size {
        return Err(wrong_size(claimed));
    }
    let img = open_png(&file)?.decode().map_err(bad)?;
    let decoded = (img.width(), img.height());
    if decoded != size {
        return Err(wrong_size(decoded));
    }
    Ok(img)
}

/// The image as RGB; an image with an alpha channel is composited over `background`
/// (what the dataset's images are matted onto), never left to lose its alpha and show
/// black where it was transparent.
fn over_background(img: DynamicImage, background: [f32; 3]) -> RgbImage {
    if !img.color().has_alpha() {
        return img.into_rgb8();
    }
    let rgba = img.into_rgba32f();
    RgbImage::from_fn(rgba.width(), rgba.height(), |x, y| {
        let p = rgba.get_pixel(x, y).0;
        let a = p[3].clamp(0.0, 1.0);
        image::Rgb(std::array::from_fn(|c| {
            let v = p[c].clamp(0.0, 1.0) * a + background[c] * (1.0 - a);
            (v * 255.0).round() as u8
        }))
    })
}

impl Dataset {
    /// The colour a matted dataset's files show around the person.
    fn files_over(&self) -> [f32; 3] {
        match self.matting {
            Matting::Reshown { files_over } => files_over,
            _ => self.background,
        }
    }

    /// Frame `index`'s image file as RGB, not composited by its mask (an alpha channel is
    /// still composited over the background): what overlays draw on.
    pub fn file_rgb(&self, index: usize) -> Result<RgbImage, DatasetError> {
        let frame = &self.frames[index];
        let size = (frame.camera.width, frame.camera.height);
        Ok(over_background(
            decode_png(&self.root, &frame.image, size)?,
            self.files_over(),
        ))
    }

    /// Frame `index`'s image file (as [`Dataset::file_rgb`]), its mask, and how far the
    /// file's surroundings lie from the background.
    fn file_and_mask(
        &self,
        index: usize,
    ) -> Result<(RgbImage, GrayImage, Surroundings), DatasetError> {
        let frame = &self.frames[index];
        let size = (frame.camera.width, frame.camera.height);
        let file_rgb = self.file_rgb(index)?;
        let mask = decode_png(&self.root, &frame.mask, size)?.into_luma8();
        let around = surroundings(&file_rgb, &mask, self.files_over());
        Ok((file_rgb, mask, around))
    }

    /// Decodes frame `index`'s target image (the person over the background: composited
    /// by the mask when the dataset's matting says so, or when the frame's surroundings
    /// contradict a declared matting), mask and segmentation (derived if the frame has
    /// none), checking sizes and labels.
    pub fn images(&self, index: usize) -> Result<FrameImages, DatasetError> {
        let frame = &self.frames[index];
        let size = (frame.camera.width, frame.camera.height);
        let (file_rgb, mask, around) = self.file_and_mask(index)?;
        let composited = match self.matting {
            Matting::ByMask => Composited::Declared,
            Matting::Matted | Matting::Reshown { .. } if around.contradicts() => {
                Composited::Contradicted
            }
            Matting::Matted => Composited::No,
            Matting::Reshown { .. } => Composited::Reshown,
        };
        let rgb = match composited {
            Composited::No => file_rgb,
            Composited::Reshown => {
                recomposite(&file_rgb, &mask, self.files_over(), self.background)
            }
            _ => composite(&file_rgb, &mask, self.background),
        };
        let Some(rel) = &frame.segmentation else {
            let skeleton = &self.subjects[frame.subject].skeleton;
            let segmentation = derived_segmentation(&mask, &frame.camera, skeleton, &frame.params);
            return Ok(FrameImages {
                rgb,
                composited,
                surroundings: around,
                mask,
                segmentation,
                labels_derived: true,
            });
        };
        let segmentation = decode_png(&self.root, rel, size)?.into_luma8();
        if let Some(bad) = segmentation.pixels().find(|p| p.0[0] as usize >= N_LABELS) {
            return Err(DatasetError::Image {
                file: self.root.join(rel),
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
            composited,
            surroundings: around,
            mask,
            segmentation,
            labels_derived: false,
        })
    }

    /// Of `frames`, those the dataset declares matted but whose surroundings contradict
    /// the background (they are composited by their masks when decoded); decodes each
    /// frame's image and mask, in parallel. Empty for a `by_mask` dataset.
    pub fn contradicting_frames(&self, frames: &[usize]) -> Result<Vec<usize>, DatasetError> {
        use rayon::prelude::*;
        if self.matting == Matting::ByMask {
            return Ok(Vec::new());
        }
        let flags = frames
            .par_iter()
            .map(|&i| Ok(self.file_and_mask(i)?.2.contradicts()))
            .collect::<Result<Vec<bool>, DatasetError>>()?;
        Ok(frames
            .iter()
            .zip(flags)
            .filter(|(_, c)| *c)
            .map(|(&i, _)| i)
            .collect())
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
