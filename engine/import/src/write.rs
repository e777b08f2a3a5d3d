//! Writing an imported dataset: frame selection and splits, pixels (undistorted,
//! downscaled), cameras in the dataset's conventions, `dataset.json` and `import.json`,
//! all in a hidden directory beside `--out` that is renamed into place at the end.

use std::path::{Path, PathBuf};

use image::{GrayImage, RgbImage, imageops::FilterType};

use super::{ImportError, ImportOptions, MaskFile, Skipped, Source, SourceFrame, undistort};
use talkin_data::array::Dim;
use talkin_data::dataset::{Dataset, Frame, Split, Subject};
use talkin_human::body::Skeleton;
use talkin_human::camera::Camera;

/// The report written beside dataset.json as `import.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ImportReport {
    pub format: String,
    pub source: String,
    pub subject: String,
    /// How the rest joints were obtained.
    pub body_shape: String,
    pub frames_in_source: usize,
    pub frames_written: usize,
    pub train: usize,
    pub test_same: usize,
    /// Lens distortion was removed from the pixels.
    pub undistorted: bool,
    /// Image scale applied by `--max-size` (1 when none).
    pub scale: f64,
    pub skipped: Vec<Skipped>,
    pub notes: Vec<String>,
}

/// `out` must not exist, or be an empty directory.
pub(crate) fn check_out(out: &Path) -> Result<(), ImportError> {
    if out.exists() {
        let mut entries = std::fs::read_dir(out).map_err(ImportError::io(out))?;
        if entries.next().is_some() {
            return Err(ImportError::file(
                out,
                "exists and is not empty: import writes a new dataset; choose another --out",
            ));
        }
    }
    Ok(())
}

pub(crate) fn write(
    opts: &ImportOptions,
    source: Source,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ImportReport, ImportError> {
    let frames_in_source = source.frames.len();
    let kept = kept_frames(opts, source.frames)?;
    let test_every = test_every(opts, &kept);
    let split_of = |k: usize, f: &SourceFrame| match test_every {
        Some(n) if n > 0 && (k + 1).is_multiple_of(n) => Split::TestSame,
        Some(_) => Split::Train,
        None => f.split.unwrap_or(Split::Train),
    };
    let tmp = staging_dir(&opts.out)?;

    let subject = super::subject_name(opts);
    let total = kept.len();
    progress(0, total);
    let mut frames = Vec::with_capacity(total);
    let mut undistorted = false;
    let mut scale = 1.0;
    for (k, f) in kept.iter().enumerate() {
        let (frame, s) = write_frame(opts, tmp.path(), k, f, split_of(k, f))?;
        undistorted |= f.distortion.is_some_and(|d| d.iter().any(|&c| c != 0.0));
        scale = s;
        frames.push(frame);
        progress(k + 1, total);
    }
    let dataset = Dataset {
        root: tmp.path().to_path_buf(),
        background: [1.0, 1.0, 1.0],
        matting: talkin_data::dataset::Matting::ByMask,
        masks: talkin_data::dataset::Masks::Matte,
        subjects: vec![Subject {
            name: subject.clone(),
            skeleton: Skeleton {
                rest_joints: source.rest_joints,
            },
        }],
        frames,
    };
    save_checked(&dataset)?;

    let count = |s: Split| dataset.frames.iter().filter(|f| f.split == s).count();
    let report = ImportReport {
        format: opts.format.name().into(),
        source: opts.src.display().to_string(),
        subject,
        body_shape: source.body_shape,
        frames_in_source: frames_in_source + source.skipped.len(),
        frames_written: dataset.frames.len(),
        train: count(Split::Train),
        test_same: count(Split::TestSame),
        undistorted,
        scale,
        skipped: source.skipped,
        notes: source.notes,
    };
    let report_file = tmp.path().join(super::IMPORT_REPORT);
    let text = serde_json::to_string_pretty(&report)
        .map_err(|e| ImportError::Usage(format!("cannot serialise import.json: {e}")))?;
    talkin_data::atomic::write_atomic(&report_file, text.as_bytes())
        .map_err(ImportError::io(&report_file))?;
    move_into_place(tmp, &opts.out)?;
    Ok(report)
}

/// Every `--every`th frame of the source; an error if none is left.
fn kept_frames(
    opts: &ImportOptions,
    frames: Vec<SourceFrame>,
) -> Result<Vec<SourceFrame>, ImportError> {
    let kept: Vec<SourceFrame> = frames
        .into_iter()
        .enumerate()
        .filter(|(i, _)| i.is_multiple_of(opts.every))
        .map(|(_, f)| f)
        .collect();
    if kept.is_empty() {
        return Err(ImportError::file(&opts.src, "no frames to import"));
    }
    Ok(kept)
}

/// Which kept frames are held out: every `--test-every`th, else the format's own splits
/// where every frame has one (`None`), else every [`super::DEFAULT_TEST_EVERY`]th.
fn test_every(opts: &ImportOptions, kept: &[SourceFrame]) -> Option<usize> {
    let has_splits = kept.iter().all(|f| f.split.is_some());
    match opts.test_every {
        Some(n) => Some(n),
        None if has_splits => None,
        None => Some(super::DEFAULT_TEST_EVERY),
    }
}

/// A hidden directory beside `out` (the same file system, so the final rename is
/// atomic) with `images/` and `masks/`; removed when dropped unless kept.
fn staging_dir(out: &Path) -> Result<tempfile::TempDir, ImportError> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(ImportError::io(&parent))?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}.import-"))
        .tempdir_in(&parent)
        .map_err(ImportError::io(&parent))?;
    for dir in ["images", "masks"] {
        let d = tmp.path().join(dir);
        std::fs::create_dir_all(&d).map_err(ImportError::io(&d))?;
    }
    Ok(tmp)
}

/// Checks `dataset.json` by the rules every command applies when it opens a dataset,
/// then writes it.
fn save_checked(dataset: &Dataset) -> Result<(), ImportError> {
    let text = serde_json::to_string_pretty(&dataset.to_json())
        .map_err(|e| ImportError::Usage(format!("cannot serialise dataset.json: {e}")))?;
    Dataset::from_json_str(&text, &dataset.root)?;
    dataset.save_index()?;
    Ok(())
}

/// Renames the finished staging directory to `out` (absent, or checked empty before).
fn move_into_place(tmp: tempfile::TempDir, out: &Path) -> Result<(), ImportError> {
    let kept_dir = tmp.keep();
    if out.exists() {
        // Checked empty above; rename cannot replace a directory on every platform.
        std::fs::remove_dir(out).map_err(ImportError::io(out))?;
    }
    if let Err(source) = std::fs::rename(&kept_dir, out) {
        let _ = std::fs::remove_dir_all(&kept_dir);
        return Err(ImportError::Io {
            file: out.to_path_buf(),
            source,
        });
    }
    Ok(())
}

/// Reads, undistorts, scales and writes frame `k`; returns it and the scale applied.
fn write_frame(
    opts: &ImportOptions,
    root: &Path,
    k: usize,
    f: &SourceFrame,
    split: Split,
) -> Result<(Frame, f64), ImportError> {
    let mut rgb = read_rgb(&f.image)?;
    let mut mask = read_mask(&f.mask)?;
    let (w, h) = rgb.dimensions();
    if mask.dimensions() != (w, h) {
        let file = match &f.mask {
            MaskFile::Image(p) | MaskFile::Npy(p) => p,
        };
        return Err(ImportError::file(
            file,
            format!(
                "is {}x{} but its frame {} is {w}x{h}",
                mask.width(),
                mask.height(),
                f.image.display()
            ),
        ));
    }
    let mut k_cv = f.intrinsics;
    if let Some(d) = f.distortion.filter(|d| d.iter().any(|&c| c != 0.0)) {
        rgb = undistort::undistort_rgb(&rgb, &k_cv, &d);
        mask = undistort::undistort_mask(&mask, &k_cv, &d);
    }
    // OpenCV puts pixel centres at integer coordinates, the dataset at x + 0.5.
    k_cv[0][2] += 0.5;
    k_cv[1][2] += 0.5;
    let mut k_ours = k_cv;
    let mut s = 1.0;
    if let Some(max) = opts.max_size
        && w.max(h) > max
    {
        s = max as f64 / w.max(h) as f64;
        let nw = ((w as f64 * s).round() as u32).max(1);
        let nh = ((h as f64 * s).round() as u32).max(1);
        let (sx, sy) = (nw as f64 / w as f64, nh as f64 / h as f64);
        rgb = image::imageops::resize(&rgb, nw, nh, FilterType::Triangle);
        mask = image::imageops::resize(&mask, nw, nh, FilterType::Triangle);
        for c in 0..3 {
            k_ours[0][c] *= sx;
            k_ours[1][c] *= sy;
        }
    }
    let (w, h) = rgb.dimensions();
    let camera = Camera::new(w, h, k_ours, f.extrinsics).map_err(|e| {
        ImportError::field(
            &opts.src,
            format!("frame {}: camera {}", f.name, e.field),
            e.problem,
        )
    })?;
    if !f.params.is_finite() {
        return Err(ImportError::field(
            &opts.src,
            format!("frame {}: parameters", f.name),
            "non-finite pose or translation",
        ));
    }
    let image = PathBuf::from(format!("images/{k:05}.png"));
    let mask_rel = PathBuf::from(format!("masks/{k:05}.png"));
    save(&rgb, &root.join(&image))?;
    save(&mask, &root.join(&mask_rel))?;
    Ok((
        Frame {
            subject: 0,
            split,
            time: f.time,
            image,
            mask: mask_rel,
            segmentation: None,
            depth: None,
            camera,
            params: f.params.clone(),
        },
        s,
    ))
}

fn save<P: image::PixelWithColorType>(
    img: &image::ImageBuffer<P, Vec<P::Subpixel>>,
    path: &Path,
) -> Result<(), ImportError>
where
    [P::Subpixel]: image::EncodableLayout,
{
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| ImportError::file(path, format!("cannot write PNG: {e}")))
}

fn open_image(path: &Path) -> Result<image::DynamicImage, ImportError> {
    if !path.is_file() {
        return Err(ImportError::file(path, "missing"));
    }
    image::ImageReader::open(path)
        .map_err(ImportError::io(path))?
        .with_guessed_format()
        .map_err(ImportError::io(path))?
        .decode()
        .map_err(|e| ImportError::file(path, format!("cannot decode image: {e}")))
}

pub(crate) fn read_rgb(path: &Path) -> Result<RgbImage, ImportError> {
    Ok(open_image(path)?.to_rgb8())
}

/// A mask as 8-bit grey, 255 the person; 0/1 masks are scaled to 0/255.
pub(crate) fn read_mask(mask: &MaskFile) -> Result<GrayImage, ImportError> {
    let mut grey = match mask {
        MaskFile::Image(path) => open_image(path)?.to_luma8(),
        MaskFile::Npy(path) => {
            let a = talkin_data::npz::read_npy(path)?;
            let v = super::error::checked_f64(&a, path, "mask", &[Dim::Any("H"), Dim::Any("W")])?;
            let (h, w) = (a.shape()[0], a.shape()[1]);
            let pixels = v
                .iter()
                .map(|&x| x.clamp(0.0, 255.0).round() as u8)
                .collect();
            GrayImage::from_raw(w as u32, h as u32, pixels)
                .ok_or_else(|| ImportError::file(path, "mask size does not match its data"))?
        }
    };
    if grey.iter().all(|&p| p <= 1) {
        grey.iter_mut().for_each(|p| *p *= 255);
    }
    Ok(grey)
}
