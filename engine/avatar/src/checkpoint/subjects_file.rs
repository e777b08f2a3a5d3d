//! `subjects.json`: the dataset background and, per identity code, the subject's name and
//! (when trained) its rest joints and capsule shells; the grids live in `grid-<s>.safetensors`
//! (`grid-<s>.bin` in runs from earlier builds, still read).

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::{CheckpointError, grid_from_bytes, read};
use crate::scene::{CapsuleShells, shell_capsules};
use crate::subject::SubjectModel;
use crate::subject::SubjectSlot;
use talkin_human::body::{N_JOINTS, Skeleton};

#[derive(Serialize, Deserialize)]
pub struct SubjectsFile {
    pub background: [f32; 3],
    pub subjects: Vec<SubjectEntry>,
}

#[derive(Serialize, Deserialize)]
pub struct SubjectEntry {
    pub name: String,
    /// Absent for a subject that has an identity code but no training frames.
    pub model: Option<ModelEntry>,
}

#[derive(Serialize, Deserialize)]
pub struct ModelEntry {
    /// `[55][3]` metres.
    pub rest_joints: Vec<[f64; 3]>,
    pub margin: Vec<f32>,
    pub core: Vec<f32>,
    pub core_shrink: Vec<f32>,
    pub shells_from_depth: bool,
    /// File name of the grid inside the checkpoint directory.
    pub grid: String,
}

impl SubjectsFile {
    /// The grid file of subject `s`.
    pub fn grid_file(s: usize) -> String {
        format!("grid-{s}.safetensors")
    }

    /// The grid file of subject `s` in runs written before grids were safetensors.
    pub fn legacy_grid_file(s: usize) -> String {
        format!("grid-{s}.bin")
    }

    pub fn from_slots(background: [f32; 3], slots: &[SubjectSlot]) -> SubjectsFile {
        let subjects = slots
            .iter()
            .enumerate()
            .map(|(s, slot)| SubjectEntry {
                name: slot.name.clone(),
                model: slot.model.as_ref().map(|m| ModelEntry {
                    rest_joints: m
                        .skeleton
                        .rest_joints
                        .iter()
                        .map(|j| j.to_array())
                        .collect(),
                    margin: m.shells.margin.clone(),
                    core: m.shells.core.clone(),
                    core_shrink: m.shells.core_shrink.clone(),
                    shells_from_depth: m.shells.from_depth,
                    grid: Self::grid_file(s),
                }),
            })
            .collect();
        SubjectsFile {
            background,
            subjects,
        }
    }

    pub fn to_json(&self) -> Result<Vec<u8>, serde_json::Error> {
        serde_json::to_vec_pretty(self)
    }

    pub fn from_json(bytes: &[u8], file: &Path) -> Result<SubjectsFile, CheckpointError> {
        let parsed: SubjectsFile = serde_json::from_slice(bytes)
            .map_err(|e| CheckpointError::format(file, "subjects.json", e))?;
        if !parsed.background.iter().all(|v| v.is_finite()) {
            return Err(CheckpointError::format(
                file,
                "background",
                "expected 3 finite numbers",
            ));
        }
        Ok(parsed)
    }

    /// Checks every entry and reads the grids from `dir`.
    pub fn into_slots(self, dir: &Path) -> Result<Vec<SubjectSlot>, CheckpointError> {
        let file = dir.join(super::SUBJECTS_FILE);
        let mut slots = Vec::with_capacity(self.subjects.len());
        for (s, entry) in self.subjects.into_iter().enumerate() {
            let field = |name: &str| format!("subjects[{s}].model.{name}");
            let model = match entry.model {
                None => None,
                Some(m) => {
                    if m.rest_joints.len() != N_JOINTS
                        || m.rest_joints.iter().flatten().any(|v| !v.is_finite())
                    {
                        return Err(CheckpointError::format(
                            &file,
                            &field("rest_joints"),
                            format!(
                                "expected {N_JOINTS} x 3 finite numbers, found {} joints",
                                m.rest_joints.len()
                            ),
                        ));
                    }
                    let mut rest = [DVec3::ZERO; N_JOINTS];
                    for (dst, j) in rest.iter_mut().zip(&m.rest_joints) {
                        *dst = DVec3::from_array(*j);
                    }
                    let skeleton = Skeleton { rest_joints: rest };
                    let n = shell_capsules(
                        &skeleton,
                        &skeleton.pose(&talkin_human::body::canonical_params()),
                    )
                    .len();
                    for (name, values) in [
                        ("margin", &m.margin),
                        ("core", &m.core),
                        ("core_shrink", &m.core_shrink),
                    ] {
                        if values.len() != n || values.iter().any(|v| !(v.is_finite() && *v >= 0.0))
                        {
                            return Err(CheckpointError::format(
                                &file,
                                &field(name),
                                format!(
                                    "expected {n} finite non-negative numbers (one per sampler \
                                     capsule), found {}",
                                    values.len()
                                ),
                            ));
                        }
                    }
                    if m.grid != SubjectsFile::grid_file(s)
                        && m.grid != SubjectsFile::legacy_grid_file(s)
                    {
                        return Err(CheckpointError::format(
                            &file,
                            &field("grid"),
                            format!(
                                "expected {:?}, found {:?}",
                                SubjectsFile::grid_file(s),
                                m.grid
                            ),
                        ));
                    }
                    let grid_path = dir.join(&m.grid);
                    let grid = grid_from_bytes(&read(&grid_path)?, &grid_path)?;
                    let shells = CapsuleShells {
                        margin: m.margin,
                        core: m.core,
                        core_shrink: m.core_shrink,
                        from_depth: m.shells_from_depth,
                    };
                    Some(SubjectModel::new(
                        entry.name.clone(),
                        skeleton,
                        shells,
                        grid,
                    ))
                }
            };
            slots.push(SubjectSlot {
                name: entry.name,
                model,
            });
        }
        Ok(slots)
    }
}
