//! Writing one rendered frame in the dataset format: the RGB image, the coverage mask, the
//! segmentation labels and the 16-bit depth (in `DEPTH_UNIT_M` steps, 0 = background).

use std::path::{Path, PathBuf};

use talkin_data::dataset::DEPTH_UNIT_M;

use crate::SynthError;
use crate::render::Rendered;

/// The folders of the four files of a frame, under the dataset's root.
pub(crate) const DIRS: [&str; 4] = ["images", "masks", "segmentation", "depth"];

/// Paths of one frame's files, relative to the dataset's root.
pub(crate) struct FramePaths {
    pub image: PathBuf,
    pub mask: PathBuf,
    pub segmentation: PathBuf,
    pub depth: PathBuf,
}

fn png_err(file: &Path) -> impl Fn(image::ImageError) -> SynthError + '_ {
    move |e| SynthError::Png {
        file: file.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes frame `index` (a `w` x `h` render) under `out` and returns where.
pub(crate) fn write_frame(
    out: &Path,
    index: usize,
    img: &Rendered,
    w: u32,
    h: u32,
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
        segmentation: rel("segmentation"),
        depth: rel("depth"),
    })
}
