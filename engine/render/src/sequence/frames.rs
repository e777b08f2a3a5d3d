//! Rendering a sequence to `frame_0000.png`, ... and a comparison contact sheet.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;

use super::sheet::{SheetRow, comparison_sheet};
use super::{SequenceError, Shot};
use talkin_avatar::Avatar;

use crate::avatar::RenderFrame;
use crate::crops::{CropKind, frame_crops};
use talkin_data::dataset::Dataset;
use talkin_data::draw::LABEL_COLOURS;

/// Outline colour of a crop on the sheet: its part's segmentation colour.
fn crop_colour(kind: CropKind) -> [u8; 3] {
    match kind {
        CropKind::Person => LABEL_COLOURS[1],
        CropKind::Face => LABEL_COLOURS[4],
        CropKind::LeftHand | CropKind::RightHand => LABEL_COLOURS[3],
    }
}

/// Most frames on a contact sheet (spread evenly over the sequence).
pub const SHEET_MAX_FRAMES: usize = 12;
/// The contact sheet's file name inside the output directory.
pub const SHEET_FILE: &str = "contact_sheet.png";

/// What [`render_sequence`] wrote.
#[derive(Clone, Debug)]
pub struct SequenceRenders {
    /// One PNG per shot, in shot order.
    pub frames: Vec<PathBuf>,
    /// Ground truth (face and hand crops outlined) | render | error, when the shots have
    /// ground truth.
    pub contact_sheet: Option<PathBuf>,
    /// Field samples evaluated over all frames.
    pub samples: usize,
    pub seconds: f64,
}

/// An image as PNG bytes.
pub fn encode_png(img: &RgbImage, file: &Path) -> Result<Vec<u8>, SequenceError> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| SequenceError::Png {
        file: file.to_path_buf(),
        problem: e.to_string(),
    })?;
    Ok(bytes)
}

/// Writes `img` as a PNG atomically (no half-written image is ever left).
pub fn write_png(img: &RgbImage, file: &Path) -> Result<(), SequenceError> {
    let bytes = encode_png(img, file)?;
    talkin_data::atomic::write_atomic(file, &bytes).map_err(|source| SequenceError::Io {
        file: file.to_path_buf(),
        source,
    })
}

/// Renders every shot to `out/frame_0000.png`, ... (creating `out`), and, when `dataset`
/// is given and shots carry ground truth, `out/contact_sheet.png` with up to
/// [`SHEET_MAX_FRAMES`] of them. `progress(done, total)` after each frame.
pub fn render_sequence(
    avatar: &Avatar,
    shots: &[Shot],
    dataset: Option<&Dataset>,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SequenceRenders, SequenceError> {
    let start = Instant::now();
    std::fs::create_dir_all(out).map_err(|source| SequenceError::Io {
        file: out.to_path_buf(),
        source,
    })?;
    let with_truth: Vec<usize> = (0..shots.len())
        .filter(|&k| dataset.is_some() && shots[k].ground_truth.is_some())
        .collect();
    let n_sheet = with_truth.len().min(SHEET_MAX_FRAMES);
    let on_sheet: Vec<usize> = (0..n_sheet)
        .map(|i| with_truth[i * with_truth.len() / n_sheet])
        .collect();
    let mut rows = Vec::new();
    let mut frames = Vec::with_capacity(shots.len());
    let mut samples = 0;
    for (k, shot) in shots.iter().enumerate() {
        let rendered = avatar.render(shot.identity, &shot.params, &shot.camera, None)?;
        samples += rendered.samples;
        let img = rendered.to_image();
        let file = out.join(format!("frame_{k:04}.png"));
        write_png(&img, &file)?;
        frames.push(file);
        if let (Some(d), Some(gt), true) = (dataset, shot.ground_truth, on_sheet.contains(&k)) {
            let truth = d.images(gt)?.rgb;
            // The regions the face and hand metrics score (from the ground-truth pose).
            let f = &d.frames[gt];
            let outlines = frame_crops(&d.subjects[f.subject].skeleton, &f.params, &f.camera)
                .into_iter()
                .filter_map(|(kind, crop)| Some((crop.ok()?, crop_colour(kind))))
                .collect();
            // A ground truth of another size (another camera) cannot sit beside the render.
            if truth.dimensions() == img.dimensions() {
                rows.push(SheetRow {
                    truth,
                    render: img,
                    outlines,
                });
            }
        }
        progress(k + 1, shots.len());
    }
    let contact_sheet = if rows.is_empty() {
        None
    } else {
        // Tiles must share a size: keep the first frame's.
        let size = rows[0].truth.dimensions();
        rows.retain(|r| r.truth.dimensions() == size);
        let file = out.join(SHEET_FILE);
        write_png(&comparison_sheet(&rows), &file)?;
        Some(file)
    };
    Ok(SequenceRenders {
        frames,
        contact_sheet,
        samples,
        seconds: start.elapsed().as_secs_f64(),
    })
}
