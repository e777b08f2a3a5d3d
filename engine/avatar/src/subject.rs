//! What the engine keeps of each trained subject besides the field's weights: the rest
//! skeleton, its canonical pose, the capsule shells fitted to its training frames and its
//! canonical occupancy grid. Training builds these from a dataset; a checkpoint stores
//! them, so rendering needs no dataset.

use talkin_grids::{GridError, MarginFitOpts, OccupancyGrid};
use talkin_nets::skinning::BoneSegment;

use crate::scene::{
    CanonicalGrid, CapsuleShells, DilatedGrids, canonical_surface_points, fit_subject_margins,
};
use talkin_data::dataset::{Dataset, DatasetError};
use talkin_human::body::{PosedSkeleton, Skeleton, canonical_params, limb_capsules};

/// One trained subject.
#[derive(Clone, Debug)]
pub struct SubjectModel {
    pub name: String,
    pub skeleton: Skeleton,
    /// The skeleton in the canonical (A-)pose.
    pub canonical: PosedSkeleton,
    /// Per sampler capsule: margin and solid core, fitted to the training frames.
    pub shells: CapsuleShells,
    /// Canonical occupancy (initially the union of the training hand and jaw poses).
    pub grid: OccupancyGrid,
    /// `grid` dilated for the accelerated sampler's cull, shared by the subject's frames
    /// (kept per grid: occupancy updates change the grid).
    pub dilated: DilatedGrids,
}

/// One subject slot of a run: every dataset subject has an identity code; only subjects
/// with training frames have a model (shells, grid).
#[derive(Clone, Debug)]
pub struct SubjectSlot {
    pub name: String,
    pub model: Option<SubjectModel>,
}

/// Why a subject model could not be built.
#[derive(Debug, thiserror::Error)]
pub enum SubjectModelError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("subject `{subject}`: occupancy grid: {source}")]
    Grid {
        subject: String,
        #[source]
        source: GridError,
    },
}

impl SubjectModel {
    /// Fits subject `subject`'s shells on its frames `train_frames` (dataset indices) and
    /// builds its initial grid with `grid_resolution` cells along the longest axis.
    pub fn fit(
        dataset: &Dataset,
        subject: usize,
        train_frames: &[usize],
        grid_resolution: u32,
    ) -> Result<SubjectModel, SubjectModelError> {
        let s = &dataset.subjects[subject];
        let margins = fit_subject_margins(dataset, subject, &MarginFitOpts::default())?;
        let surface = canonical_surface_points(dataset, train_frames, &margins.shells)?;
        let grid = CanonicalGrid::initial(
            &s.skeleton,
            train_frames.iter().map(|&i| &dataset.frames[i].params),
            &margins.shells,
            grid_resolution,
            surface.as_deref(),
        )
        .map_err(|source| SubjectModelError::Grid {
            subject: s.name.clone(),
            source,
        })?;
        Ok(SubjectModel::new(
            s.name.clone(),
            s.skeleton.clone(),
            margins.shells,
            grid,
        ))
    }

    /// Assembles a subject from its parts (the canonical pose is derived).
    pub fn new(
        name: String,
        skeleton: Skeleton,
        shells: CapsuleShells,
        grid: OccupancyGrid,
    ) -> SubjectModel {
        let canonical = skeleton.pose(&canonical_params());
        SubjectModel {
            name,
            skeleton,
            canonical,
            shells,
            grid,
            dilated: DilatedGrids::default(),
        }
    }
}

/// The skinning-weight prior of the field: every subject's canonical limb capsules as
/// segments labelled with their joint (the field reads each as its skinned joint).
pub fn bone_prior<'a>(skeletons: impl IntoIterator<Item = &'a Skeleton>) -> Vec<BoneSegment> {
    let mut prior = Vec::new();
    for skeleton in skeletons {
        let canonical = skeleton.pose(&canonical_params());
        for c in limb_capsules(skeleton, &canonical) {
            prior.push(BoneSegment {
                bone: c.bone as usize,
                a: c.a.to_array(),
                b: c.b.to_array(),
            });
        }
    }
    prior
}
