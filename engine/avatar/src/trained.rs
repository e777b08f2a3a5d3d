//! A trained avatar as `talkin-avatar` defines it: the field on an inference device plus
//! each subject's skeleton, shells and occupancy grid. Loaded once from a run's checkpoint
//! (render, eval, the server) or wrapped around a field still in training (the
//! benchmarks' evaluations).
//!
//! Must not know about rendering: `talkin-render` renders an avatar's frames.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use talkin_grids::SamplerKind;
use talkin_nets::{FieldConfig, TalkinField};

use crate::checkpoint::{Checkpoint, CheckpointError, STATE_FILE};
use crate::refined::RefinedFits;
use crate::subject::{SubjectModel, SubjectSlot};

/// Why an avatar could not be loaded or could not render.
#[derive(Debug, thiserror::Error)]
pub enum AvatarError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("{}: state.json: field `{field}`: {problem}", file.display())]
    State {
        file: PathBuf,
        field: &'static str,
        problem: String,
    },
    #[error("{0}")]
    Subject(String),
    #[error("{what}: {problem}")]
    BadInput { what: String, problem: String },
    #[error("sampling: {0}")]
    Grid(#[from] talkin_grids::GridError),
    #[error("field: {0}")]
    Field(#[from] talkin_nets::NetsError),
}

/// A field with what it needs to render any pose of its subjects.
pub struct Avatar {
    pub field: TalkinField,
    pub config: FieldConfig,
    pub background: [f32; 3],
    pub subjects: Vec<SubjectSlot>,
    /// The sampler the field was trained with (and renders with by default).
    pub sampler: SamplerKind,
    /// The step passed to the field (D_nr switch, Hann windows): the run's last.
    pub field_step: usize,
    /// The run's refined training fits (`None`: it trusted its fits); renders and
    /// evaluations of its training frames use them.
    pub refined: Option<RefinedFits>,
}

impl Avatar {
    /// Loads the newest checkpoint of `run` onto the CPU (Flex) device.
    pub fn load(run: &Path) -> Result<Avatar, AvatarError> {
        Avatar::load_on(run, &Device::flex())
    }

    /// Loads the newest checkpoint of `run` onto `device` (any device: checkpoints hold
    /// host arrays, whichever device trained them).
    pub fn load_on(run: &Path, device: &Device) -> Result<Avatar, AvatarError> {
        let checkpoint = Checkpoint::load(run)?;
        let field = checkpoint.field(device)?;
        let state_file = checkpoint.dir.join(STATE_FILE);
        let bad = |field: &'static str, problem: &str| AvatarError::State {
            file: state_file.clone(),
            field,
            problem: problem.to_string(),
        };
        let sampler = checkpoint
            .state
            .get("options")
            .and_then(|o| o.get("sampler"))
            .and_then(|s| s.as_str())
            .ok_or_else(|| bad("options.sampler", "expected \"dense\" or \"accelerated\""))?
            .parse::<SamplerKind>()
            .map_err(|e| bad("options.sampler", &e.to_string()))?;
        let field_step = checkpoint
            .state
            .get("field_step")
            .and_then(|s| s.as_u64())
            .ok_or_else(|| bad("field_step", "expected a non-negative integer"))?
            as usize;
        let refined = RefinedFits::from_state_json(&checkpoint.state)
            .map_err(|problem| bad("pose_refinement", &problem))?;
        Ok(Avatar {
            refined,
            field,
            config: checkpoint.config,
            background: checkpoint.background,
            subjects: checkpoint.subjects,
            sampler,
            field_step,
        })
    }

    /// The device the field lives on (renders run there).
    pub fn device(&self) -> Device {
        self.field.identity.val().device()
    }

    /// The subject named `name` and its index; the error lists the trained subjects.
    pub fn subject(&self, name: &str) -> Result<(usize, &SubjectModel), AvatarError> {
        let trained = || {
            self.subjects
                .iter()
                .filter(|s| s.model.is_some())
                .map(|s| format!("`{}`", s.name))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match self.subjects.iter().position(|s| s.name == name) {
            Some(i) => match &self.subjects[i].model {
                Some(m) => Ok((i, m)),
                None => Err(AvatarError::Subject(format!(
                    "subject `{name}` has an identity code but was never trained; trained: {}",
                    trained()
                ))),
            },
            None => Err(AvatarError::Subject(format!(
                "unknown subject `{name}`; trained: {}",
                trained()
            ))),
        }
    }

    /// The model of subject index `s`, if trained.
    pub fn subject_at(&self, s: usize) -> Result<&SubjectModel, AvatarError> {
        self.subjects
            .get(s)
            .and_then(|slot| slot.model.as_ref())
            .ok_or_else(|| {
                AvatarError::Subject(format!(
                    "subject index {s} is not a trained subject of this avatar"
                ))
            })
    }

    /// Names of the trained subjects, in identity order.
    pub fn trained_subjects(&self) -> Vec<&str> {
        self.subjects
            .iter()
            .filter(|s| s.model.is_some())
            .map(|s| s.name.as_str())
            .collect()
    }
}
