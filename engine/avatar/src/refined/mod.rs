//! A run's refined training fits as everything after training reads them: renders and
//! evaluations of training frames, and `talkin export-poses`. Training learns them (the
//! trainer's pose refinement); a checkpoint records them in `state.json`.

pub mod layout;

use std::collections::HashMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use talkin_data::dataset::Dataset;
use talkin_human::body::FrameParams;

use layout::DIM;

/// The corrections of a run's training frames and their optimizer state: what a
/// checkpoint records (`state.json`'s `pose_refinement`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefinerState {
    /// Dataset frame of each slot (the run's training frames, in order).
    pub frames: Vec<usize>,
    /// Per slot: the correction ([`layout::DIM`] numbers).
    pub delta: Vec<Vec<f32>>,
    /// Per slot: Adam's first and second moments and its step count.
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
    pub t: Vec<u32>,
}

/// The corrections a checkpoint recorded, keyed by dataset frame, with the fingerprint of
/// the dataset they belong to.
#[derive(Clone, Debug, PartialEq)]
pub struct RefinedFits {
    /// SHA-256 of the `dataset.json` the run trained on.
    pub dataset_sha256: String,
    pub delta: HashMap<usize, Vec<f32>>,
}

impl RefinedFits {
    /// The corrections of `state` for the dataset with fingerprint `dataset_sha256`.
    pub fn new(state: &RefinerState, dataset_sha256: &str) -> RefinedFits {
        RefinedFits {
            dataset_sha256: dataset_sha256.to_string(),
            delta: state
                .frames
                .iter()
                .copied()
                .zip(state.delta.iter().cloned())
                .collect(),
        }
    }

    /// What a checkpoint's `state.json` records: `Ok(None)` for a run that trusted its
    /// fits; `Err` names the field that is malformed.
    pub fn from_state_json(state: &Value) -> Result<Option<RefinedFits>, String> {
        let recorded = match state.get("pose_refinement") {
            None | Some(Value::Null) => return Ok(None),
            Some(v) => v,
        };
        let refiner: RefinerState = serde_json::from_value(recorded.clone())
            .map_err(|e| format!("`pose_refinement`: {e}"))?;
        if refiner.delta.len() != refiner.frames.len()
            || refiner.delta.iter().any(|d| d.len() != DIM)
        {
            return Err(format!(
                "`pose_refinement.delta`: expected one list of {DIM} numbers per frame of \
                 `pose_refinement.frames` ({})",
                refiner.frames.len()
            ));
        }
        if refiner.delta.iter().flatten().any(|v| !v.is_finite()) {
            return Err("`pose_refinement.delta`: not every number is finite".into());
        }
        let sha = state
            .get("dataset_sha256")
            .and_then(Value::as_str)
            .ok_or("`dataset_sha256`: expected the trained dataset's fingerprint")?;
        Ok(Some(RefinedFits::new(&refiner, sha)))
    }

    /// Dataset frame `i`'s refined parameters, if `dataset` (fingerprint
    /// `dataset_sha256`) is the one the run trained on and `i` a frame it refined.
    pub fn params(&self, dataset: &Dataset, dataset_sha256: &str, i: usize) -> Option<FrameParams> {
        if dataset_sha256 != self.dataset_sha256 {
            return None;
        }
        let fit = &dataset.frames.get(i)?.params;
        self.delta.get(&i).map(|d| layout::corrected(fit, d))
    }
}
