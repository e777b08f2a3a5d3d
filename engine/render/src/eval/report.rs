//! The evaluation report: averages, per-frame scores, JSON and a short table.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::EvalError;
use super::anchors::{ANCHOR_SSIM_RANGE, AnchorScore};
use super::lpips::BACKBONE;
use super::regions::{PersonRegions, RegionScore};
use super::thickness::Thickness;
use crate::crops::CropKind;
use crate::metrics::{PSNR_CAP_DB, Rect};
use talkin_data::dataset::Dataset;

/// LPIPS is reported x1000 (the paper's LPIPS*).
pub const LPIPS_SCALE: f64 = 1000.0;

/// One scored crop.
#[derive(Clone, Debug, Serialize)]
pub struct CropScore {
    pub kind: CropKind,
    pub rect: Rect,
    pub psnr: f64,
    /// `None` below the 11x11 SSIM window.
    pub ssim: Option<f64>,
    /// x1000; `None` without weights or below 32x32.
    pub lpips: Option<f64>,
}

/// A crop that was not scored, and why.
#[derive(Clone, Debug, Serialize)]
pub struct SkippedCrop {
    pub kind: CropKind,
    pub reason: String,
}

/// A path as text for people: non-UTF-8 bytes become U+FFFD instead of an error.
fn lossy_path<S: serde::Serializer>(path: &Path, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&path.to_string_lossy())
}

fn lossy_path_opt<S: serde::Serializer>(path: &Option<PathBuf>, s: S) -> Result<S::Ok, S::Error> {
    match path {
        Some(p) => lossy_path(p, s),
        None => s.serialize_none(),
    }
}

/// One evaluated frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameScore {
    /// Index into the dataset's frames.
    pub frame: usize,
    /// The frame's subject (whose image is the ground truth).
    pub subject: String,
    /// The avatar identity that rendered it.
    pub rendered_as: String,
    pub time: f64,
    /// The PNG that was scored (when renders were written).
    #[serde(serialize_with = "lossy_path_opt")]
    pub render: Option<PathBuf>,
    pub psnr: f64,
    pub ssim: Option<f64>,
    pub lpips: Option<f64>,
    /// The whole frame by the anchors' protocol (`None` below SSIM's 7x7 window).
    pub anchors: Option<AnchorScore>,
    pub crops: Vec<CropScore>,
    /// The person box split by the target's mask (`None` where the box was skipped).
    pub person_regions: Option<PersonRegions>,
    /// How thick the person renders inside its mask (`None` where the box was skipped or
    /// no ray inside it is opaque).
    pub thickness: Option<Thickness>,
    pub skipped_crops: Vec<SkippedCrop>,
    /// Field samples evaluated for the render.
    pub samples: usize,
    /// Render seconds.
    pub seconds: f64,
}

/// What `talkin eval` writes.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// The run evaluated (set by the caller; the avatar does not know its directory).
    #[serde(serialize_with = "lossy_path_opt")]
    pub run: Option<PathBuf>,
    #[serde(serialize_with = "lossy_path")]
    pub dataset: PathBuf,
    /// The split every evaluated frame belongs to; `None` if they mix splits.
    pub split: Option<String>,
    /// The colour truth and render were composited over, RGB in [0, 1].
    pub background: [f32; 3],
    pub smooth: bool,
    pub frames_evaluated: usize,
    /// Means over frames (full frame).
    pub psnr: f64,
    /// NaN (`null` in JSON) only if some frame is smaller than SSIM's 11x11 window.
    pub ssim: f64,
    /// x1000.
    pub lpips: Option<f64>,
    /// Means over the person boxes that were scored (the posed body's projected bounds:
    /// what Neural Body and Instant-NVR score).
    pub psnr_person: Option<f64>,
    pub ssim_person: Option<f64>,
    pub lpips_person: Option<f64>,
    /// Means over frames by the anchors' protocol (HumanNeRF's and Neural Body's tables:
    /// whole frame, SSIM as scikit-image 0.19 on floats, LPIPS-VGG x1000).
    pub anchors: Option<AnchorMeans>,
    /// The person boxes split by the targets' masks: means over frames of each region's
    /// PSNR and share of the box's squared error.
    pub person_inside: Option<RegionMeans>,
    pub person_outline: Option<RegionMeans>,
    pub person_around: Option<RegionMeans>,
    /// How thick the person renders inside its mask: means over frames of each frame's
    /// median and 90th percentile depth spread.
    pub thickness_inside: Option<ThicknessMeans>,
    /// Means over the face crops that were scored.
    pub psnr_face: Option<f64>,
    pub ssim_face: Option<f64>,
    pub lpips_face: Option<f64>,
    /// Means over all hand crops (left and right) that were scored.
    pub psnr_hands: Option<f64>,
    pub ssim_hands: Option<f64>,
    pub lpips_hands: Option<f64>,
    pub person_crops: usize,
    pub face_crops: usize,
    pub hand_crops: usize,
    pub skipped_crops: usize,
    pub lpips_backbone: &'static str,
    pub lpips_scale: f64,
    /// PSNR of identical images (JSON has no infinity).
    pub psnr_cap_db: f64,
    /// Why LPIPS is null, when it is (also in `notes`).
    pub lpips_note: Option<String>,
    pub notes: Vec<String>,
    pub seconds: f64,
    pub frames: Vec<FrameScore>,
    /// The same frames scored again after a test-time fit of their poses with the model
    /// frozen (`talkin eval --pose-fit`): beside the plain score, never instead of it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_fit: Option<PoseFitScore>,
}

/// An evaluation after a test-time fit of the frames' poses (InstantAvatar's evaluation
/// of novel poses), with what the fit did.
#[derive(Clone, Debug, Serialize)]
pub struct PoseFitScore {
    pub steps_per_frame: usize,
    pub lr: f64,
    /// Seconds the fit took (its evaluation not included).
    pub seconds: f64,
    /// Root mean square of the body joints' corrections (axis-angle norm, global
    /// orientation included), degrees.
    pub rotation_rms_deg: f64,
    /// Mean length of the translation's correction, metres.
    pub translation_mean_m: f64,
    /// Per dataset frame, its fitted correction in the layout of a checkpoint's
    /// `pose_refinement.delta` (`talkin_avatar::refined::layout`).
    pub corrections: std::collections::BTreeMap<usize, Vec<f32>>,
    /// The frames scored at their fitted poses.
    pub report: Box<EvalReport>,
}

/// The anchors' protocol ([`super::anchors`]) averaged over the frames.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AnchorMeans {
    pub psnr: f64,
    pub ssim: f64,
    /// The data range of `ssim` (scikit-image 0.19's for floats).
    pub ssim_data_range: f64,
    /// x1000; `None` without the VGG16 weights.
    pub lpips_vgg: Option<f64>,
    pub frames: usize,
}

impl AnchorMeans {
    fn over(frames: &[FrameScore]) -> Option<AnchorMeans> {
        let scores: Vec<AnchorScore> = frames.iter().map(|f| f.anchors).collect::<Option<_>>()?;
        Some(AnchorMeans {
            psnr: mean(scores.iter().map(|a| a.psnr))?,
            ssim: mean(scores.iter().map(|a| a.ssim))?,
            ssim_data_range: ANCHOR_SSIM_RANGE,
            lpips_vgg: mean_all(&scores.iter().map(|a| a.lpips_vgg).collect::<Vec<_>>()),
            frames: scores.len(),
        })
    }
}

/// Each frame's [`Thickness`], averaged over the frames that have one.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ThicknessMeans {
    pub median_mm: f64,
    pub p90_mm: f64,
    pub frames: usize,
}

impl ThicknessMeans {
    fn over(frames: &[FrameScore]) -> Option<ThicknessMeans> {
        let t: Vec<Thickness> = frames.iter().filter_map(|f| f.thickness).collect();
        Some(ThicknessMeans {
            median_mm: mean(t.iter().map(|t| t.median_mm))?,
            p90_mm: mean(t.iter().map(|t| t.p90_mm))?,
            frames: t.len(),
        })
    }
}

/// A person-box region ([`PersonRegions`]) averaged over the frames that have it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RegionMeans {
    pub psnr: f64,
    pub error_share: f64,
    /// The render's mean opacity over the region.
    pub opacity: f64,
    pub frames: usize,
}

impl RegionMeans {
    fn over(scores: &[RegionScore]) -> Option<RegionMeans> {
        Some(RegionMeans {
            psnr: mean(scores.iter().map(|r| r.psnr))?,
            error_share: mean(scores.iter().map(|r| r.error_share))?,
            opacity: mean(scores.iter().map(|r| r.opacity))?,
            frames: scores.len(),
        })
    }
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// The mean of `f` over values where it is `Some`, but `None` if any is missing: an
/// average over a subset would not be comparable.
fn mean_all(values: &[Option<f64>]) -> Option<f64> {
    if values.iter().any(Option::is_none) {
        return None;
    }
    mean(values.iter().flatten().copied())
}

impl EvalReport {
    pub(super) fn new(
        dataset: &Dataset,
        frames: Vec<FrameScore>,
        smooth: bool,
        lpips_note: Option<String>,
        seconds: f64,
    ) -> EvalReport {
        let mut notes: Vec<String> = lpips_note.iter().cloned().collect();
        let splits: Vec<_> = frames
            .iter()
            .map(|f| dataset.frames[f.frame].split)
            .collect();
        let split = splits
            .iter()
            .all(|s| *s == splits[0])
            .then(|| splits[0].name().to_string());
        let crops = |kinds: &[CropKind]| -> Vec<&CropScore> {
            frames
                .iter()
                .flat_map(|f| &f.crops)
                .filter(|c| kinds.contains(&c.kind))
                .collect()
        };
        let (person, face, hands) = (
            crops(&[CropKind::Person]),
            crops(&[CropKind::Face]),
            crops(&[CropKind::LeftHand, CropKind::RightHand]),
        );
        let skipped_crops = frames.iter().map(|f| f.skipped_crops.len()).sum();
        if skipped_crops > 0 {
            notes.push(format!(
                "{skipped_crops} crops skipped (outside the image or behind the camera); \
                 see frames[].skipped_crops"
            ));
        }
        let crop_means = |cs: &[&CropScore]| {
            (
                mean(cs.iter().map(|c| c.psnr)),
                mean_all(&cs.iter().map(|c| c.ssim).collect::<Vec<_>>()),
                mean_all(&cs.iter().map(|c| c.lpips).collect::<Vec<_>>()),
            )
        };
        let (psnr_person, ssim_person, lpips_person) = crop_means(&person);
        let region = |f: fn(&PersonRegions) -> Option<RegionScore>| {
            let scores: Vec<RegionScore> = frames
                .iter()
                .filter_map(|fr| fr.person_regions.as_ref().and_then(f))
                .collect();
            RegionMeans::over(&scores)
        };
        let person_inside = region(|r| r.inside);
        let person_outline = region(|r| r.outline);
        let person_around = region(|r| r.around);
        let (psnr_face, ssim_face, lpips_face) = crop_means(&face);
        let (psnr_hands, ssim_hands, lpips_hands) = crop_means(&hands);
        EvalReport {
            run: None,
            dataset: dataset.root.clone(),
            split,
            background: dataset.background,
            smooth,
            frames_evaluated: frames.len(),
            psnr: mean(frames.iter().map(|f| f.psnr)).unwrap_or(f64::NAN),
            ssim: mean_all(&frames.iter().map(|f| f.ssim).collect::<Vec<_>>()).unwrap_or(f64::NAN),
            lpips: mean_all(&frames.iter().map(|f| f.lpips).collect::<Vec<_>>()),
            anchors: AnchorMeans::over(&frames),
            psnr_person,
            ssim_person,
            lpips_person,
            person_inside,
            person_outline,
            person_around,
            thickness_inside: ThicknessMeans::over(&frames),
            psnr_face,
            ssim_face,
            lpips_face,
            psnr_hands,
            ssim_hands,
            lpips_hands,
            person_crops: person.len(),
            face_crops: face.len(),
            hand_crops: hands.len(),
            skipped_crops,
            lpips_backbone: BACKBONE.name(),
            lpips_scale: LPIPS_SCALE,
            psnr_cap_db: PSNR_CAP_DB,
            lpips_note,
            notes,
            seconds,
            frames,
            pose_fit: None,
        }
    }

    /// The report as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self)
            .expect("numbers, strings and lossily written paths always serialise")
    }

    /// Writes the JSON atomically.
    pub fn write_json(&self, file: &Path) -> Result<(), EvalError> {
        talkin_data::atomic::write_atomic(file, self.to_json().as_bytes()).map_err(|source| {
            EvalError::Io {
                file: file.to_path_buf(),
                source,
            }
        })
    }

    /// A short human-readable table of the averages.
    pub fn table(&self) -> String {
        let num = |v: Option<f64>, digits: usize| match v {
            Some(x) => format!("{x:.digits$}"),
            None => "-".to_string(),
        };
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} frames of split {}{}, over RGB {:?}",
            self.frames_evaluated,
            self.split.as_deref().unwrap_or("(mixed)"),
            if self.smooth { ", smoothed" } else { "" },
            self.background
        );
        let _ = writeln!(
            s,
            "{:<14}{:>9}{:>8}{:>10}",
            "region", "PSNR dB", "SSIM", "LPIPS*"
        );
        let rows = [
            (
                format!("full ({})", self.frames_evaluated),
                Some(self.psnr),
                Some(self.ssim).filter(|v| v.is_finite()),
                self.lpips,
            ),
            (
                format!("person ({})", self.person_crops),
                self.psnr_person,
                self.ssim_person,
                self.lpips_person,
            ),
            (
                format!("face ({})", self.face_crops),
                self.psnr_face,
                self.ssim_face,
                self.lpips_face,
            ),
            (
                format!("hands ({})", self.hand_crops),
                self.psnr_hands,
                self.ssim_hands,
                self.lpips_hands,
            ),
        ];
        for (name, p, q, l) in rows {
            let _ = writeln!(
                s,
                "{name:<14}{:>9}{:>8}{:>10}",
                num(p, 2),
                num(q, 4),
                num(l, 1)
            );
        }
        let regions = [
            ("inside", self.person_inside),
            ("outline", self.person_outline),
            ("around", self.person_around),
        ];
        if regions.iter().any(|(_, r)| r.is_some()) {
            let _ = writeln!(
                s,
                "person box by the mask: PSNR dB (share of its error), the render's opacity"
            );
            for (name, r) in regions {
                let _ = match r {
                    Some(r) => writeln!(
                        s,
                        "  {name:<12}{:>9.2}  ({:>3.0}%)  {:.3}",
                        r.psnr,
                        100.0 * r.error_share,
                        r.opacity
                    ),
                    None => writeln!(s, "  {name:<12}{:>9}", "-"),
                };
            }
        }
        if let Some(t) = &self.thickness_inside {
            let _ = writeln!(
                s,
                "thickness inside the mask (depth spread of opaque rays): median {:.1} mm, 90th percentile {:.1} mm",
                t.median_mm, t.p90_mm
            );
        }
        if let Some(a) = &self.anchors {
            let _ = writeln!(
                s,
                "anchors' protocol (HumanNeRF's table: whole frame, SSIM as scikit-image 0.19 on floats, LPIPS-VGG x1000): PSNR {:.2}  SSIM {:.4}  LPIPS-VGG {}",
                a.psnr,
                a.ssim,
                num(a.lpips_vgg, 1)
            );
        }
        if let Some(fit) = &self.pose_fit {
            let r = &fit.report;
            let _ = writeln!(
                s,
                "after a test-time pose fit (model frozen; {} steps a frame, corrections {:.2} deg RMS, {:.1} cm): full {:.2} dB, person {} dB / LPIPS* {}{}",
                fit.steps_per_frame,
                fit.rotation_rms_deg,
                100.0 * fit.translation_mean_m,
                r.psnr,
                num(r.psnr_person, 2),
                num(r.lpips_person, 1),
                r.anchors.as_ref().map_or(String::new(), |a| format!(
                    "; anchors' protocol PSNR {:.2}  SSIM {:.4}  LPIPS-VGG {}",
                    a.psnr,
                    a.ssim,
                    num(a.lpips_vgg, 1)
                ))
            );
        }
        for note in &self.notes {
            let _ = writeln!(s, "note: {note}");
        }
        s
    }
}
