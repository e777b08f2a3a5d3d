//! Checkpoints: everything needed to resume a run exactly or to render without the
//! dataset, written so that a kill at any moment leaves the last good checkpoint.
//!
//! ```text
//! RUN/checkpoint/LATEST            name of the newest complete checkpoint ("step-000500")
//! RUN/checkpoint/step-000500/
//!     model.bpk        the field's parameters (burnpack)
//!     optimizer.bpk    Adam's moments (absent in inference-only checkpoints)
//!     config.json      the field's FieldConfig
//!     subjects.json    background, subject names, rest joints and capsule shells
//!     grid-<s>.bin     each trained subject's canonical occupancy grid
//!     state.json       step, elapsed time, RNG state, the run's options
//! ```
//!
//! A checkpoint is written into `step-N.tmp/`, renamed to `step-N/`, and only then named
//! in `LATEST` (itself replaced atomically); older step directories are removed last.

mod grid_file;
mod subjects_file;

use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::store::ModuleRecord;
use burn::tensor::Bytes;
use talkin_nets::{FieldConfig, TalkinField};

pub use grid_file::{grid_from_bytes, grid_to_bytes};
pub use subjects_file::SubjectsFile;

use crate::subject::{SubjectSlot, bone_prior};

/// The checkpoint directory inside a run directory.
pub const CHECKPOINT_DIR: &str = "checkpoint";
/// The file naming the newest complete checkpoint.
pub const LATEST_FILE: &str = "LATEST";
pub const MODEL_FILE: &str = "model.bpk";
pub const OPTIMIZER_FILE: &str = "optimizer.bpk";
pub const CONFIG_FILE: &str = "config.json";
pub const SUBJECTS_FILE: &str = "subjects.json";
/// Written last.
pub const STATE_FILE: &str = "state.json";

/// What went wrong reading or writing a checkpoint; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: field `{field}`: {problem}", file.display())]
    Format {
        file: PathBuf,
        field: String,
        problem: String,
    },
    #[error(
        "{}: no checkpoint (expected {} naming a step directory; was the run trained?)",
        run.display(),
        Path::new(CHECKPOINT_DIR).join(LATEST_FILE).display()
    )]
    Missing { run: PathBuf },
}

impl CheckpointError {
    fn io(file: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
        move |source| CheckpointError::Io {
            file: file.to_path_buf(),
            source,
        }
    }

    fn format(file: &Path, field: &str, problem: impl ToString) -> CheckpointError {
        CheckpointError::Format {
            file: file.to_path_buf(),
            field: field.to_string(),
            problem: problem.to_string(),
        }
    }
}

/// A checkpoint as read back (the weights stay bytes until a field is built on a device).
pub struct Checkpoint {
    pub dir: PathBuf,
    pub config: FieldConfig,
    pub background: [f32; 3],
    pub subjects: Vec<SubjectSlot>,
    /// The run's state as JSON (its schema belongs to the trainer).
    pub state: serde_json::Value,
    model_bytes: Vec<u8>,
    optimizer_bytes: Option<Vec<u8>>,
}

/// What a writer hands over.
pub struct CheckpointContents<'a> {
    pub step: usize,
    pub field: &'a TalkinField,
    pub config: &'a FieldConfig,
    /// `None`: an inference-only checkpoint.
    pub optimizer: Option<Vec<u8>>,
    pub background: [f32; 3],
    pub subjects: &'a [SubjectSlot],
    pub state: &'a serde_json::Value,
}

/// Held by whoever seeds the device or draws a field's initial weights: burn's device
/// RNG is process-wide, and a draw interleaved with another thread's (tests, benches)
/// would make the same seed give different weights.
pub static DEVICE_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The checkpoint directory of a run.
pub fn checkpoint_root(run: &Path) -> PathBuf {
    run.join(CHECKPOINT_DIR)
}

/// Writes a checkpoint of `run` and points `LATEST` at it; returns its directory.
pub fn save(run: &Path, c: &CheckpointContents) -> Result<PathBuf, CheckpointError> {
    let root = checkpoint_root(run);
    let name = format!("step-{:06}", c.step);
    let dir = root.join(&name);
    let tmp = root.join(format!("{name}.tmp"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(CheckpointError::io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(CheckpointError::io(&tmp))?;
    let write = |file: &str, bytes: &[u8]| {
        let path = tmp.join(file);
        std::fs::write(&path, bytes).map_err(CheckpointError::io(&path))
    };
    let model = c
        .field
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| CheckpointError::format(&tmp.join(MODEL_FILE), "record", e))?;
    write(MODEL_FILE, &model)?;
    if let Some(bytes) = &c.optimizer {
        write(OPTIMIZER_FILE, bytes)?;
    }
    let config = serde_json::to_string_pretty(c.config).expect("a config serialises");
    write(CONFIG_FILE, config.as_bytes())?;
    let subjects = SubjectsFile::from_slots(c.background, c.subjects);
    write(SUBJECTS_FILE, &subjects.to_json())?;
    for (s, slot) in c.subjects.iter().enumerate() {
        if let Some(m) = &slot.model {
            write(&SubjectsFile::grid_file(s), &grid_to_bytes(&m.grid))?;
        }
    }
    let state = serde_json::to_string_pretty(c.state).expect("JSON serialises");
    write(STATE_FILE, state.as_bytes())?;
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(CheckpointError::io(&dir))?;
    }
    std::fs::rename(&tmp, &dir).map_err(CheckpointError::io(&dir))?;
    let latest = root.join(LATEST_FILE);
    talkin_data::atomic::write_atomic(&latest, format!("{name}\n").as_bytes())
        .map_err(CheckpointError::io(&latest))?;
    // Older checkpoints go only after LATEST names the new one.
    for entry in std::fs::read_dir(&root)
        .map_err(CheckpointError::io(&root))?
        .flatten()
    {
        let file_name = entry.file_name();
        let other = file_name.to_string_lossy();
        if other.starts_with("step-") && other != name {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
    Ok(dir)
}

/// The directory `LATEST` names in `run`.
pub fn latest_dir(run: &Path) -> Result<PathBuf, CheckpointError> {
    let root = checkpoint_root(run);
    let latest = root.join(LATEST_FILE);
    let name = match std::fs::read_to_string(&latest) {
        Ok(name) => name,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(CheckpointError::Missing {
                run: run.to_path_buf(),
            });
        }
        Err(source) => {
            return Err(CheckpointError::Io {
                file: latest,
                source,
            });
        }
    };
    let name = name.trim();
    if !name.starts_with("step-") || name.contains(['/', '\\']) || name.contains("..") {
        return Err(CheckpointError::format(
            &latest,
            "LATEST",
            format!("expected a step directory name like `step-000500`, found {name:?}"),
        ));
    }
    Ok(root.join(name))
}

fn read(path: &Path) -> Result<Vec<u8>, CheckpointError> {
    std::fs::read(path).map_err(CheckpointError::io(path))
}

impl Checkpoint {
    /// Reads the newest checkpoint of `run`, validating every file.
    pub fn load(run: &Path) -> Result<Checkpoint, CheckpointError> {
        let dir = latest_dir(run)?;
        let config_file = dir.join(CONFIG_FILE);
        let config: FieldConfig = serde_json::from_slice(&read(&config_file)?)
            .map_err(|e| CheckpointError::format(&config_file, "FieldConfig", e))?;
        let subjects_file = dir.join(SUBJECTS_FILE);
        let file = SubjectsFile::from_json(&read(&subjects_file)?, &subjects_file)?;
        if file.subjects.len() != config.n_identities {
            return Err(CheckpointError::format(
                &subjects_file,
                "subjects",
                format!(
                    "{} subjects, but the field has {} identity codes",
                    file.subjects.len(),
                    config.n_identities
                ),
            ));
        }
        let background = file.background;
        let subjects = file.into_slots(&dir)?;
        let state_file = dir.join(STATE_FILE);
        let state = serde_json::from_slice(&read(&state_file)?)
            .map_err(|e| CheckpointError::format(&state_file, "state", e))?;
        let model_bytes = read(&dir.join(MODEL_FILE))?;
        let optimizer_file = dir.join(OPTIMIZER_FILE);
        let optimizer_bytes = if optimizer_file.exists() {
            Some(read(&optimizer_file)?)
        } else {
            None
        };
        Ok(Checkpoint {
            dir,
            config,
            background,
            subjects,
            state,
            model_bytes,
            optimizer_bytes,
        })
    }

    /// Builds the field on `device` (add `.autodiff()` to train it further) with the
    /// checkpoint's weights.
    pub fn field(&self, device: &Device) -> Result<TalkinField, CheckpointError> {
        let model_file = self.dir.join(MODEL_FILE);
        let skeletons: Vec<_> = self
            .subjects
            .iter()
            .filter_map(|s| s.model.as_ref().map(|m| &m.skeleton))
            .collect();
        let field = {
            let _guard = DEVICE_RNG.lock().unwrap_or_else(|e| e.into_inner());
            self.config.init(&bone_prior(skeletons), device)
        }
        .map_err(|e| CheckpointError::format(&self.dir.join(CONFIG_FILE), "FieldConfig", e))?;
        let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(self.model_bytes.clone()))
            .map_err(|e| CheckpointError::format(&model_file, "record", e))?;
        field
            .try_load_record(record)
            .map_err(|e| CheckpointError::format(&model_file, "record", e))
    }

    /// The optimizer's saved bytes (`None` in inference-only checkpoints).
    pub fn optimizer_bytes(&self) -> Option<&[u8]> {
        self.optimizer_bytes.as_deref()
    }

    /// The file the optimizer state came from (for error messages).
    pub fn optimizer_file(&self) -> PathBuf {
        self.dir.join(OPTIMIZER_FILE)
    }
}
