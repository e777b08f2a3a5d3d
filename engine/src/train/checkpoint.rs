//! Checkpoints: the field's parameters (burnpack), its `FieldConfig` (JSON) and the
//! training state (JSON), each written atomically (temp file in the same directory, then
//! a rename), the state last so a state file always names a complete checkpoint.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use serde::{Deserialize, Serialize};
use talkin_nets::{FieldConfig, TalkinField};

use super::TrainError;

/// The model record's file name inside a checkpoint directory.
pub const MODEL_FILE: &str = "model.bpk";
/// The field configuration's file name.
pub const CONFIG_FILE: &str = "config.json";
/// The training state's file name (written last).
pub const STATE_FILE: &str = "state.json";

/// What a checkpoint says about the run besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    /// Optimizer steps taken.
    pub step: usize,
    pub preset: String,
    pub sampler: String,
    pub seed: u64,
    /// Dataset directory the run trained on.
    pub data: PathBuf,
}

/// Paths of a written checkpoint.
#[derive(Clone, Debug)]
pub struct CheckpointPaths {
    pub dir: PathBuf,
    pub model: PathBuf,
    pub config: PathBuf,
    pub state: PathBuf,
}

/// Writes `bytes` to `path` atomically ([`crate::atomic::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    crate::atomic::write_atomic(path, bytes).map_err(|source| TrainError::Io {
        file: path.to_path_buf(),
        source,
    })
}

/// Saves `field` (any backend; autodiff included), its config and `state` under `dir`
/// (created).
pub fn save_checkpoint(
    dir: &Path,
    field: &TalkinField,
    config: &FieldConfig,
    state: &CheckpointState,
) -> Result<CheckpointPaths, TrainError> {
    std::fs::create_dir_all(dir).map_err(|source| TrainError::Io {
        file: dir.to_path_buf(),
        source,
    })?;
    let paths = CheckpointPaths {
        dir: dir.to_path_buf(),
        model: dir.join(MODEL_FILE),
        config: dir.join(CONFIG_FILE),
        state: dir.join(STATE_FILE),
    };
    let bytes = field
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| TrainError::Record {
            file: paths.model.clone(),
            problem: e.to_string(),
        })?;
    write_atomic(&paths.model, &bytes)?;
    let config_json = serde_json::to_string_pretty(config).map_err(|e| TrainError::Record {
        file: paths.config.clone(),
        problem: e.to_string(),
    })?;
    write_atomic(&paths.config, config_json.as_bytes())?;
    let state_json = serde_json::to_string_pretty(state).expect("plain data serialises");
    write_atomic(&paths.state, state_json.as_bytes())?;
    Ok(paths)
}

/// Reads a checkpoint's field configuration back.
pub fn load_config(dir: &Path) -> Result<FieldConfig, TrainError> {
    read_json(&dir.join(CONFIG_FILE))
}

/// Reads a checkpoint's training state back.
pub fn load_state(dir: &Path) -> Result<CheckpointState, TrainError> {
    read_json(&dir.join(STATE_FILE))
}

fn read_json<T: serde::de::DeserializeOwned>(file: &Path) -> Result<T, TrainError> {
    let text = std::fs::read_to_string(file).map_err(|source| TrainError::Io {
        file: file.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| TrainError::Record {
        file: file.to_path_buf(),
        problem: e.to_string(),
    })
}
