//! Dataset format v1: a directory with `dataset.json` and per-frame PNGs (image, mask,
//! segmentation). The format real data is converted into and the synthetic generator
//! writes. See the README for the schema.
//!
//! [`Dataset::load`] validates the whole JSON and every image header up front, so a
//! training run never dies on frame 900; pixels are decoded lazily ([`Dataset::images`]).

mod derive_labels;
mod error;
mod images;
mod load;
mod matting;
mod write;

use std::path::PathBuf;

pub use derive_labels::derived_segmentation;
pub use error::DatasetError;
pub use images::{FrameImages, LABEL_NAMES, N_LABELS};
pub use load::camera_field;
pub use load::parse_camera;
pub use matting::{
    Composited, EDGE_BAND_PX, MAX_OFF_SHARE, Masks, Matting, OFF_BY, Surroundings, composite,
    dilate, mask_edge_band, mask_edge_px, on_mask_cut, recomposite, surroundings,
};
pub use write::write_atomic;

use talkin_human::body::{FrameParams, Skeleton};
use talkin_human::camera::Camera;

/// The `format` value of a dataset.json.
pub const FORMAT: &str = "talkin-dataset";
/// The only version this build reads.
pub const VERSION: u64 = 1;
/// The file name inside a dataset directory.
pub const INDEX_FILE: &str = "dataset.json";

/// The report an importer (`talkin import`) writes beside [`INDEX_FILE`]: a dataset that
/// has one came from a fitter, so its fits are an estimator's.
pub const IMPORT_REPORT: &str = "import.json";
/// Metres per unit of the optional 16-bit depth PNGs (0.1 mm: 6.5 m range).
pub const DEPTH_UNIT_M: f64 = 1e-4;

/// Which evaluation a frame belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Split {
    /// Training frames.
    Train,
    /// Held-out frames of the same subject and motion.
    TestSame,
    /// A subject driven by another subject's motion.
    TestCross,
    /// A wider motion range than training.
    TestOod,
}

impl Split {
    pub const ALL: [Split; 4] = [
        Split::Train,
        Split::TestSame,
        Split::TestCross,
        Split::TestOod,
    ];

    pub const fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::TestSame => "test_same",
            Split::TestCross => "test_cross",
            Split::TestOod => "test_ood",
        }
    }

    pub fn from_name(name: &str) -> Option<Split> {
        Split::ALL.into_iter().find(|s| s.name() == name)
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Split {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Split::from_name(s).ok_or_else(|| {
            format!("unknown split {s:?}: expected one of train, test_same, test_cross, test_ood")
        })
    }
}

/// One subject (identity).
#[derive(Clone, Debug, PartialEq)]
pub struct Subject {
    pub name: String,
    pub skeleton: Skeleton,
}

/// One frame: which subject, which split, its camera, pose and image files.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub subject: usize,
    pub split: Split,
    /// Seconds since the start of the subject's clip.
    pub time: f64,
    /// Paths relative to the dataset directory.
    pub image: PathBuf,
    pub mask: PathBuf,
    /// DensePose-style part labels; `None`: derived from the mask and the posed capsules
    /// when the frame is decoded ([`Dataset::images`]).
    pub segmentation: Option<PathBuf>,
    /// Optional ground-truth depth (16-bit PNG, camera z in units of [`DEPTH_UNIT_M`],
    /// 0 = no surface). Only synthetic data has it; benchmarks use it to find the true
    /// surface point of each pixel.
    pub depth: Option<PathBuf>,
    pub camera: Camera,
    pub params: FrameParams,
}

/// A validated dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// The directory holding dataset.json.
    pub root: PathBuf,
    /// Colour the person is shown over, RGB in [0, 1].
    pub background: [f32; 3],
    /// Whether the image files already show the person over `background`, or are camera
    /// frames that every command composites by their masks ([`Dataset::images`]).
    pub matting: Matting,
    /// Whether the masks are exact coverage (what `synth` writes) or a matte.
    pub masks: Masks,
    pub subjects: Vec<Subject>,
    pub frames: Vec<Frame>,
}

impl Dataset {
    /// Indices of the frames of a split.
    pub fn split_indices(&self, split: Split) -> Vec<usize> {
        (0..self.frames.len())
            .filter(|&i| self.frames[i].split == split)
            .collect()
    }

    /// Indices of subject `s`'s frames of a split, in time order (its video).
    pub fn subject_frames(&self, s: usize, split: Split) -> Vec<usize> {
        let mut frames: Vec<usize> = (0..self.frames.len())
            .filter(|&i| self.frames[i].split == split && self.frames[i].subject == s)
            .collect();
        frames.sort_by(|&a, &b| self.frames[a].time.total_cmp(&self.frames[b].time));
        frames
    }

    /// Every frame's target shown over `background` (RGB in [0, 1]) instead of the
    /// declared colour, as camera captures are scored (over black): a `by_mask` dataset
    /// composites its frames over it, a matted one with coverage masks recomposites them
    /// ([`Matting::Reshown`]). A matted dataset with a matte cannot: its edge pixels keep
    /// the colour they were written over.
    pub fn show_over(&mut self, background: [f32; 3]) -> Result<(), DatasetError> {
        self.matting = match self.matting {
            Matting::Matted if self.masks == Masks::Coverage => Matting::Reshown {
                files_over: self.background,
            },
            Matting::Matted => {
                return Err(DatasetError::Invalid {
                    file: self.root.join(INDEX_FILE),
                    field: "masks".into(),
                    problem: format!(
                        "the frames are matted over {:?} and the masks are a matte, which \
                         cannot take that colour out of the edge pixels: only a dataset \
                         composited by its masks (\"matting\": \"by_mask\") or one with exact \
                         coverage masks (\"masks\": \"coverage\", what `synth` writes) is \
                         shown over another colour",
                        self.background
                    ),
                });
            }
            // Composited by its masks, or already recomposited from its files' colour.
            other => other,
        };
        self.background = background;
        Ok(())
    }

    /// Whether every frame's person can be shown over another colour
    /// ([`Dataset::show_over`]): composited by its masks, or matted with coverage masks.
    pub fn can_show_over(&self) -> bool {
        self.matting != Matting::Matted || self.masks == Masks::Coverage
    }

    /// Index of a subject by name.
    pub fn subject_index(&self, name: &str) -> Option<usize> {
        self.subjects.iter().position(|s| s.name == name)
    }
}
