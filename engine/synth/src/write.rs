//! Writing one rendered frame in the dataset format: the RGB image, the coverage mask, the
//! segmentation labels and the 16-bit depth (in `DEPTH_UNIT_M` steps, 0 = background).

use std::path::{Path, PathBuf};

use talkin_data::dataset::DEPTH_UNIT_M;

use crate::SynthError;
use crate::tracer::Rendered;

/// The folders of the four files of a frame, under the dataset's root.
pub(crate) const DIRS: [&str; 4] = ["images", "masks", "segmentation", "depth"];

/// Paths of one frame's files, relative to the dataset's root.
pub(crate) struct FramePaths {
    pub image: PathBuf,
    pub mask: PathBuf,
    /// `None` for a scene written with masks only.
    pub segmentation: Option<PathBuf>,
    pub depth: Option<PathBuf>,
}

fn png_err(file: &Path) -> impl Fn(image::ImageError) -> SynthError + '_ {
    move |e| SynthError::Png {
        file: file.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes frame `index` (a `w` x `h` render) under `out` and returns where; with
/// `masks_only`, its image and mask alone (what a matting tool gives).
pub(crate) fn write_frame(
    out: &Path,
    index: usize,
    img: &Rendered,
    (w, h): (u32, u32),
    masks_only: bool,
) -> Result<FramePaths, SynthError> {
    let name = format!("{index:05}.png");
    let rel = |dir: &str| PathBuf::from(dir).join(&name);
    let file = out.join(rel("images"));
    image::RgbImage::from_raw(w, h, img.rgb.iter().flatten().copied().collect())
        .expect("buffer matches the camera")
        .save_with_format(&file, image::ImageFormat::Png)
        .map_err(png_err(&file))?;
    let file = out.join(rel("masks"));
    image::GrayImage::from_raw(w, h, img.coverage.clone())
        .expect("buffer matches the camera")
        .save_with_format(&file, image::ImageFormat::Png)
        .map_err(png_err(&file))?;
    if masks_only {
        return Ok(FramePaths {
            image: rel("images"),
            mask: rel("masks"),
            segmentation: None,
            depth: None,
        });
    }
    let file = out.join(rel("segmentation"));
    image::GrayImage::from_raw(w, h, img.label.clone())
        .expect("buffer matches the camera")
        .save_with_format(&file, image::ImageFormat::Png)
        .map_err(png_err(&file))?;
    let file = out.join(rel("depth"));
    let depth: Vec<u16> = img
        .depth
        .iter()
        .zip(&img.label)
        .map(|(&z, &l)| {
            if l == 0 {
                0
            } else {
                (z as f64 / DEPTH_UNIT_M).round().clamp(1.0, 65535.0) as u16
            }
        })
        .collect();
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, depth)
        .expect("buffer matches the camera")
        .save_with_format(&file, image::ImageFormat::Png)
        .map_err(png_err(&file))?;
    Ok(FramePaths {
        image: rel("images"),
        mask: rel("masks"),
        segmentation: Some(rel("segmentation")),
        depth: Some(rel("depth")),
    })
}

/// Writes `dataset` with each frame's pose replaced by the true one (`fits`, dataset
/// order) beside `dataset.json` ([`crate::TRUE_FITS_FILE`]: the layout of `dataset.json`
/// and of `talkin export-poses`), atomically.
pub(crate) fn write_true_fits(
    dataset: &talkin_data::dataset::Dataset,
    fits: Vec<talkin_human::body::FrameParams>,
) -> Result<(), SynthError> {
    let mut truth = dataset.clone();
    for (frame, fit) in truth.frames.iter_mut().zip(fits) {
        frame.params = fit;
    }
    let file = dataset.root.join(crate::TRUE_FITS_FILE);
    let text =
        serde_json::to_string_pretty(&truth.to_json()).expect("numbers and strings serialise");
    talkin_data::atomic::write_atomic(&file, text.as_bytes())
        .map_err(|source| SynthError::Io { file, source })
}
