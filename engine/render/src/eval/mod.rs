//! Evaluation of an avatar against a dataset's frames: PSNR, SSIM and LPIPS (x1000, the
//! paper's LPIPS*) on the full frame, the person box, the face crop and the two hand crops;
//! the person box also split by the target's mask into inside, outline and around
//! ([`person_regions`]).
//!
//! What is scored is the 8-bit render exactly as written to PNG, so re-scoring a written
//! PNG gives the same numbers. Crops come from the ground-truth pose projected through the
//! frame's camera ([`frame_crops`]); a crop that misses the image is skipped and reported,
//! never faked, and without LPIPS weights every LPIPS value is `null` with a note.

pub mod anchors;
pub mod lpips;
mod regions;
mod report;
mod thickness;

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;

pub use crate::crops::{CropKind, MIN_CROP, frame_crops};
pub use crate::metrics::{PSNR_CAP_DB, Rect, psnr, ssim};
pub use anchors::{ANCHOR_SSIM_RANGE, AnchorScore, anchor_score, ssim_skimage};
pub use lpips::LpipsScorer;
pub use regions::{PersonRegions, RegionScore, outline_px, person_regions};
pub use report::{
    AnchorMeans, CropScore, EvalReport, FrameScore, LPIPS_SCALE, PoseFitScore, RegionMeans,
    SkippedCrop, ThicknessMeans,
};
pub use thickness::{THICKNESS_MIN_OPACITY, Thickness, thickness_inside};

use talkin_avatar::{Avatar, AvatarError};

use crate::avatar::RenderFrame;
use crate::sequence::{
    SequenceError, SheetRow, Shot, comparison_sheet, shots_from_frames, smooth_shots, write_png,
};
use talkin_data::dataset::{Dataset, DatasetError};
use talkin_human::smooth::Smoothing;

/// How to evaluate.
#[derive(Clone, Debug, Default)]
pub struct EvalOptions {
    /// Write each scored render here as `frame_<dataset index>.png` (the path is recorded
    /// per frame); `None`: score without writing.
    pub renders_dir: Option<PathBuf>,
    /// Directory holding `alex.safetensors`; `None` or a missing file: LPIPS is `null`.
    pub lpips_dir: Option<PathBuf>,
    /// Smooth each subject's poses and cameras over time (in the evaluated frames' time
    /// order) before rendering, with the paper's filter.
    pub smooth: bool,
    /// Also score every frame by the anchors' protocol ([`anchors`]); its LPIPS-VGG needs
    /// `vgg.safetensors` in `lpips_dir` and costs about 10 s a 512x512 frame on 2 cores.
    pub anchors: bool,
}

/// Why an evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Sequence(#[from] SequenceError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Avatar(#[from] AvatarError),
    #[error("LPIPS: {0}")]
    Lpips(#[from] talkin_nets::loss::LossError),
    #[error("no frames to evaluate")]
    NoFrames,
    #[error(
        "{}: frames[{frame}]: the ground truth is {found:?} px but the render is {expected:?} px",
        dir.display()
    )]
    SizeMismatch {
        dir: PathBuf,
        frame: usize,
        found: (u32, u32),
        expected: (u32, u32),
    },
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Renders dataset frames `frames` (each as its own subject, matched by name) and scores
/// them against their images.
pub fn evaluate(
    avatar: &Avatar,
    dataset: &Dataset,
    frames: &[usize],
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    evaluate_with_progress(avatar, dataset, frames, opts, &mut |_, _| {})
}

/// [`evaluate`], calling `progress(done, total)` after each frame.
pub fn evaluate_with_progress(
    avatar: &Avatar,
    dataset: &Dataset,
    frames: &[usize],
    opts: &EvalOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<EvalReport, EvalError> {
    let start = Instant::now();
    if frames.is_empty() {
        return Err(EvalError::NoFrames);
    }
    let mut shots = shots_from_frames(avatar, dataset, frames, None)?;
    if opts.smooth {
        smooth_shots(&mut shots, &Smoothing::PAPER)?;
    }
    let (scorer, lpips_note) =
        match LpipsScorer::from_dir(opts.lpips_dir.as_deref(), &avatar.device())? {
            Ok(s) => (Some(s), None),
            Err(note) => (None, Some(note)),
        };
    // The anchors' LPIPS, where its weights are beside AlexNet's.
    let vgg = match opts.anchors {
        true => LpipsScorer::with_backbone(
            opts.lpips_dir.as_deref(),
            talkin_nets::loss::Backbone::Vgg,
            &avatar.device(),
        )?
        .ok(),
        false => None,
    };
    if let Some(dir) = &opts.renders_dir {
        std::fs::create_dir_all(dir).map_err(|source| EvalError::Io {
            file: dir.clone(),
            source,
        })?;
    }
    let mut scores = Vec::with_capacity(shots.len());
    let mut hands = Vec::new();
    for (k, shot) in shots.iter().enumerate() {
        let (score, hand_rows) = score_shot(
            avatar,
            dataset,
            shot,
            opts.renders_dir.as_deref(),
            (scorer.as_ref(), opts.anchors.then_some(vgg.as_ref())),
        )?;
        scores.push(score);
        hands.extend(hand_rows);
        progress(k + 1, shots.len());
    }
    if let Some(dir) = &opts.renders_dir
        && !hands.is_empty()
    {
        write_png(&comparison_sheet(&hands), &dir.join(HANDS_SHEET))?;
    }
    Ok(EvalReport::new(
        dataset,
        scores,
        opts.smooth,
        lpips_note,
        start.elapsed().as_secs_f64(),
    ))
}

/// Renders one shot, writes it if asked, scores it and its crops; with `renders_dir`,
/// also its hand crops (truth and render at [`HAND_TILE`] px) for the hands sheet.
fn score_shot(
    avatar: &Avatar,
    dataset: &Dataset,
    shot: &Shot,
    renders_dir: Option<&Path>,
    (scorer, anchors): (Option<&LpipsScorer>, Option<Option<&LpipsScorer>>),
) -> Result<(FrameScore, Vec<SheetRow>), EvalError> {
    let index = shot
        .ground_truth
        .expect("evaluation shots come from dataset frames");
    let frame = &dataset.frames[index];
    let rendered = avatar.render(shot.identity, &shot.params, &shot.camera, None)?;
    let render = rendered.to_image();
    let images = dataset.images(index)?;
    let truth = images.rgb;
    if truth.dimensions() != render.dimensions() {
        return Err(EvalError::SizeMismatch {
            dir: dataset.root.clone(),
            frame: index,
            found: truth.dimensions(),
            expected: render.dimensions(),
        });
    }
    let file = match renders_dir {
        Some(dir) => {
            let file = dir.join(format!("frame_{index:05}.png"));
            write_png(&render, &file)?;
            Some(file)
        }
        None => None,
    };
    let score_rect = |r: Rect| -> (f64, Option<f64>, Option<f64>) {
        (
            psnr(&truth, &render, r),
            ssim(&truth, &render, r),
            scorer.and_then(|s| s.distance(&truth, &render, r).map(|d| d * LPIPS_SCALE)),
        )
    };
    let (psnr_full, ssim_full, lpips_full) = score_rect(Rect::full(&render));
    let anchors = anchors.and_then(|vgg| anchor_score(&truth, &render, vgg));
    let skeleton = &dataset.subjects[frame.subject].skeleton;
    let mut crops = Vec::new();
    let mut skipped = Vec::new();
    let mut hand_rows = Vec::new();
    let mut regions = None;
    let mut thickness = None;
    // The shot's pose: a training frame's refined fit, when the run refined it.
    for (kind, crop) in frame_crops(skeleton, &shot.params, &frame.camera) {
        match crop {
            Ok(rect) => {
                if file.is_some() && matches!(kind, CropKind::LeftHand | CropKind::RightHand) {
                    hand_rows.push(SheetRow {
                        truth: crop_tile(&truth, rect),
                        render: crop_tile(&render, rect),
                        outlines: Vec::new(),
                    });
                }
                if matches!(kind, CropKind::Person) {
                    regions = Some(person_regions(
                        &truth,
                        &render,
                        &rendered.opacity,
                        &images.mask,
                        rect,
                    ));
                    thickness = thickness_inside(
                        &images.mask,
                        &rendered.depth_spread,
                        &rendered.opacity,
                        rect,
                    );
                }
                let (p, s, l) = score_rect(rect);
                crops.push(CropScore {
                    kind,
                    rect,
                    psnr: p,
                    ssim: s,
                    lpips: l,
                });
            }
            Err(reason) => skipped.push(SkippedCrop { kind, reason }),
        }
    }
    let score = FrameScore {
        frame: index,
        subject: dataset.subjects[frame.subject].name.clone(),
        rendered_as: avatar.subjects[shot.identity].name.clone(),
        time: frame.time,
        render: file,
        psnr: psnr_full,
        ssim: ssim_full,
        lpips: lpips_full,
        anchors,
        crops,
        person_regions: regions,
        thickness,
        skipped_crops: skipped,
        samples: rendered.samples,
        seconds: rendered.seconds,
    };
    Ok((score, hand_rows))
}

/// The hands sheet beside the scored renders: every hand crop of the split, one row each
/// (two side by side beyond four), ground truth | render | error heat map.
pub const HANDS_SHEET: &str = "hands_sheet.png";
/// Side of a hand crop on the hands sheet (crops are squares, scaled to it).
pub const HAND_TILE: u32 = 96;

/// `rect` of `img`, scaled to a `HAND_TILE` square.
fn crop_tile(img: &RgbImage, rect: Rect) -> RgbImage {
    let crop = image::imageops::crop_imm(img, rect.x, rect.y, rect.width, rect.height).to_image();
    image::imageops::resize(
        &crop,
        HAND_TILE,
        HAND_TILE,
        image::imageops::FilterType::Nearest,
    )
}

/// Re-scores a written render against its ground truth (full-frame PSNR): what a reader
/// of the report can check.
pub fn rescore_png(dataset: &Dataset, frame: usize, png: &Path) -> Result<f64, EvalError> {
    let img: RgbImage = image::open(png)
        .map_err(|e| EvalError::Io {
            file: png.to_path_buf(),
            source: std::io::Error::other(e.to_string()),
        })?
        .into_rgb8();
    let truth = dataset.images(frame)?.rgb;
    if truth.dimensions() != img.dimensions() {
        return Err(EvalError::SizeMismatch {
            dir: dataset.root.clone(),
            frame,
            found: truth.dimensions(),
            expected: img.dimensions(),
        });
    }
    Ok(psnr(&truth, &img, Rect::full(&img)))
}
