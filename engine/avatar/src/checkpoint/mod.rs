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
//!     grid-<s>.safetensors  each trained subject's canonical occupancy grid
//!     state.json       step, elapsed time, RNG state, the run's options, the dataset
//!     manifest.json    size and SHA-256 of every file above (written last)
//! RUN/checkpoint/step-000250/    the previous checkpoint, kept as a fallback
//! ```
//!
//! A checkpoint is written into `step-N.tmp/` (each file fsynced), renamed to `step-N/`,
//! and only then named in `LATEST` (itself replaced atomically); the checkpoint before it
//! is kept and older ones are removed last. A save that fails (a full disk) removes what
//! it wrote, leaving `LATEST` on the previous checkpoint. Loading verifies every file against the
//! manifest and falls back to the previous checkpoint, saying so, when the newest is
//! damaged; weights that are not finite are refused.

mod grid_file;
mod grid_file_tkog;
pub mod manifest;
pub mod path_json;
mod subjects_file;

use std::path::{Path, PathBuf};

use burn::module::{ModuleVisitor, Param};
use burn::prelude::*;
use burn::store::ModuleRecord;
use burn::tensor::Bytes;
use talkin_data::atomic::{sync_dir, write_atomic, write_synced};
use talkin_data::dataset::{Dataset, INDEX_FILE};
use talkin_nets::init::WeightRng;
use talkin_nets::{FieldConfig, TalkinField};

pub use grid_file::{grid_from_bytes, grid_to_bytes};
pub use manifest::{MANIFEST_FILE, Manifest, sha256_hex};
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
pub const STATE_FILE: &str = "state.json";
/// Files every checkpoint has (besides the grids of its trained subjects).
const REQUIRED_FILES: [&str; 4] = [MODEL_FILE, CONFIG_FILE, SUBJECTS_FILE, STATE_FILE];

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
    #[error("{}: damaged: {problem}", file.display())]
    Damaged { file: PathBuf, problem: String },
    #[error(
        "{}: tensor `{tensor}` holds values that are not finite (NaN or infinite); the \
         weights cannot be used",
        file.display()
    )]
    NonFinite { file: PathBuf, tensor: String },
    #[error("{}: no usable checkpoint:\n  {}", run.display(), problems.join("\n  "))]
    Unusable { run: PathBuf, problems: Vec<String> },
}

impl CheckpointError {
    fn io(file: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
        move |source| CheckpointError::Io {
            file: file.to_path_buf(),
            source,
        }
    }

    /// A malformed `field` of `file` (the trainer's state, too: its schema is the
    /// trainer's).
    pub fn format(file: &Path, field: &str, problem: impl ToString) -> CheckpointError {
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
    /// What the loader had to say (already printed on stderr): a fallback from a damaged
    /// newest checkpoint, or a checkpoint without a manifest.
    pub notes: Vec<String>,
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
    /// A previous checkpoint directory to keep (the fallback); every other is removed.
    pub keep: Option<&'a Path>,
}

/// The checkpoint directory of a run.
pub fn checkpoint_root(run: &Path) -> PathBuf {
    run.join(CHECKPOINT_DIR)
}

/// The dataset's fingerprint: the SHA-256 of its `dataset.json` (every frame's files,
/// split, camera and parameters), recorded in each checkpoint and checked on resume.
pub fn dataset_sha256(dataset: &Dataset) -> Result<String, CheckpointError> {
    let file = dataset.root.join(INDEX_FILE);
    std::fs::read(&file)
        .map(|bytes| sha256_hex(&bytes))
        .map_err(|source| CheckpointError::Io { file, source })
}

/// The directory name of the checkpoint after `step` steps.
pub fn step_name(step: usize) -> String {
    format!("step-{step:06}")
}

/// The step of a checkpoint directory name (`step-000500` -> 500); `None` for anything
/// else (`step-000500.tmp` included).
fn step_of(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("step-")?;
    (!digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()))
        .then(|| digits.parse().ok())
        .flatten()
}

/// The complete-looking checkpoint directories of `run`, newest step first.
pub fn step_dirs(run: &Path) -> Vec<(usize, PathBuf)> {
    let root = checkpoint_root(run);
    let mut dirs: Vec<(usize, PathBuf)> = std::fs::read_dir(&root)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.path().is_dir())
        .filter_map(|e| Some((step_of(e.file_name().to_str()?)?, e.path())))
        .collect();
    dirs.sort_by(|a, b| b.cmp(a));
    dirs
}

/// Writes a checkpoint of `run` and points `LATEST` at it; returns its directory. Keeps
/// `c.keep` (the previous checkpoint) and removes every other step directory.
pub fn save(run: &Path, c: &CheckpointContents) -> Result<PathBuf, CheckpointError> {
    let root = checkpoint_root(run);
    let name = step_name(c.step);
    let dir = root.join(&name);
    if let Some(tensor) = first_non_finite(c.field) {
        return Err(CheckpointError::NonFinite {
            file: dir.join(MODEL_FILE),
            tensor,
        });
    }
    let tmp = root.join(format!("{name}.tmp"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(CheckpointError::io(&tmp))?;
    }
    // A save that fails (a full disk, most likely) leaves the run as it was: nothing of
    // the new checkpoint stays to hold the space, and `LATEST` names the previous one.
    let published = write_files(&tmp, c).and_then(|()| {
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(CheckpointError::io(&dir))?;
        }
        std::fs::rename(&tmp, &dir).map_err(CheckpointError::io(&dir))?;
        sync_dir(&root).map_err(CheckpointError::io(&root))?;
        let latest = root.join(LATEST_FILE);
        write_atomic(&latest, format!("{name}\n").as_bytes()).map_err(CheckpointError::io(&latest))
    });
    if let Err(e) = published {
        let _ = std::fs::remove_dir_all(&tmp);
        let _ = std::fs::remove_dir_all(&dir);
        return Err(e);
    }
    // Older checkpoints go only after LATEST names the new one; the previous one stays.
    let keep = c.keep.and_then(|k| k.file_name()).filter(|k| **k != *name);
    for entry in std::fs::read_dir(&root)
        .map_err(CheckpointError::io(&root))?
        .flatten()
    {
        let file_name = entry.file_name();
        let other = file_name.to_string_lossy();
        if other.starts_with("step-") && other != name && Some(file_name.as_os_str()) != keep {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
    Ok(dir)
}

/// Writes every file of `c` into `tmp` (created), each fsynced, the manifest last.
fn write_files(tmp: &Path, c: &CheckpointContents) -> Result<(), CheckpointError> {
    std::fs::create_dir_all(tmp).map_err(CheckpointError::io(tmp))?;
    let mut manifest = Manifest::new();
    let mut write = |file: &str, bytes: &[u8]| {
        let path = tmp.join(file);
        write_synced(&path, bytes).map_err(CheckpointError::io(&path))?;
        manifest.add(file, bytes);
        Ok::<(), CheckpointError>(())
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
    let config = serde_json::to_vec_pretty(c.config)
        .map_err(|e| CheckpointError::format(&tmp.join(CONFIG_FILE), "FieldConfig", e))?;
    write(CONFIG_FILE, &config)?;
    let subjects = SubjectsFile::from_slots(c.background, c.subjects)
        .to_json()
        .map_err(|e| CheckpointError::format(&tmp.join(SUBJECTS_FILE), "subjects", e))?;
    write(SUBJECTS_FILE, &subjects)?;
    for (s, slot) in c.subjects.iter().enumerate() {
        if let Some(m) = &slot.model {
            write(&SubjectsFile::grid_file(s), &grid_to_bytes(&m.grid)?)?;
        }
    }
    let state = serde_json::to_vec_pretty(c.state)
        .map_err(|e| CheckpointError::format(&tmp.join(STATE_FILE), "state", e))?;
    write(STATE_FILE, &state)?;
    let manifest_path = tmp.join(MANIFEST_FILE);
    let manifest = manifest
        .to_json()
        .map_err(|e| CheckpointError::format(&manifest_path, "manifest", e))?;
    write_synced(&manifest_path, &manifest).map_err(CheckpointError::io(&manifest_path))?;
    sync_dir(tmp).map_err(CheckpointError::io(tmp))
}

/// The module path of the first float tensor of `field` holding a NaN or an infinity.
/// Each tensor's flag is `sum(x - x)` (0 when every value is finite, NaN otherwise), and
/// the flags are read back together: on a GPU one wait, not one a tensor.
pub fn first_non_finite(field: &TalkinField) -> Option<String> {
    #[derive(Default)]
    struct Flags {
        path: Vec<String>,
        names: Vec<String>,
        flags: Vec<Tensor<1>>,
    }
    impl ModuleVisitor for Flags {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let t = param.val();
            self.names.push(self.path.join("."));
            self.flags.push((t.clone() - t).sum());
        }
    }
    let mut flags = Flags::default();
    field.visit(&mut flags);
    if flags.flags.is_empty() {
        return None;
    }
    match talkin_nets::read_floats(Tensor::cat(flags.flags, 0)) {
        Ok(values) => values
            .iter()
            .position(|v| *v != 0.0)
            .map(|i| flags.names[i].clone()),
        Err(e) => Some(format!("(the parameters could not be read back: {e:?})")),
    }
}

/// The directory `LATEST` names in `run`.
pub fn latest_dir(run: &Path) -> Result<PathBuf, CheckpointError> {
    latest_name(run)?
        .map(|name| checkpoint_root(run).join(name))
        .ok_or_else(|| CheckpointError::Missing {
            run: run.to_path_buf(),
        })
}

/// The name `LATEST` holds (`None` when there is no `LATEST`).
fn latest_name(run: &Path) -> Result<Option<String>, CheckpointError> {
    let latest = checkpoint_root(run).join(LATEST_FILE);
    let name = match std::fs::read_to_string(&latest) {
        Ok(name) => name,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(CheckpointError::Io {
                file: latest,
                source,
            });
        }
    };
    let name = name.trim();
    if step_of(name).is_none() {
        return Err(CheckpointError::format(
            &latest,
            "LATEST",
            format!("expected a step directory name like `step-000500`, found {name:?}"),
        ));
    }
    Ok(Some(name.to_string()))
}

fn read(path: &Path) -> Result<Vec<u8>, CheckpointError> {
    std::fs::read(path).map_err(CheckpointError::io(path))
}

impl Checkpoint {
    /// Reads the newest usable checkpoint of `run`: the one `LATEST` names, verified
    /// against its manifest and parsed; if that fails, the previous one (newest step
    /// first), with a warning on stderr and in [`Checkpoint::notes`].
    pub fn load(run: &Path) -> Result<Checkpoint, CheckpointError> {
        let latest = latest_name(run)?;
        let root = checkpoint_root(run);
        let newest = latest.as_ref().map(|n| root.join(n));
        let mut candidates: Vec<PathBuf> = newest.iter().cloned().collect();
        candidates.extend(
            step_dirs(run)
                .into_iter()
                .map(|(_, dir)| dir)
                .filter(|d| Some(d) != newest.as_ref()),
        );
        if candidates.is_empty() {
            return Err(CheckpointError::Missing {
                run: run.to_path_buf(),
            });
        }
        let mut failures: Vec<CheckpointError> = Vec::new();
        for dir in candidates {
            match Checkpoint::load_dir(&dir) {
                Ok(mut checkpoint) => {
                    let mut notes = Vec::new();
                    if latest.is_none() {
                        notes.push(format!(
                            "{} is missing; loaded the newest complete checkpoint, {}",
                            root.join(LATEST_FILE).display(),
                            dir.display()
                        ));
                    }
                    notes.extend(failures.iter().map(|e| {
                        format!("{e}; loaded the previous checkpoint, {}", dir.display())
                    }));
                    notes.append(&mut checkpoint.notes);
                    for note in &notes {
                        tracing::warn!("{note}");
                    }
                    checkpoint.notes = notes;
                    return Ok(checkpoint);
                }
                Err(e) => failures.push(e),
            }
        }
        if failures.len() == 1 {
            return Err(failures.remove(0));
        }
        Err(CheckpointError::Unusable {
            run: run.to_path_buf(),
            problems: failures.iter().map(ToString::to_string).collect(),
        })
    }

    /// Reads the checkpoint in `dir`, verifying its files against its manifest.
    fn load_dir(dir: &Path) -> Result<Checkpoint, CheckpointError> {
        let dir = dir.to_path_buf();
        let mut notes = Vec::new();
        match Manifest::read(&dir)? {
            Some(manifest) => manifest.verify(&dir, &REQUIRED_FILES)?,
            None => notes.push(format!(
                "{}: no {MANIFEST_FILE} (a checkpoint from an older build): its files \
                 are not verified",
                dir.display()
            )),
        }
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
            notes,
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
        let field = self
            .config
            // Whatever this draws is overwritten by the record.
            .init(&bone_prior(skeletons), device, &mut WeightRng::seeded(0))
            .map_err(|e| CheckpointError::format(&self.dir.join(CONFIG_FILE), "FieldConfig", e))?;
        let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(self.model_bytes.clone()))
            .map_err(|e| CheckpointError::format(&model_file, "record", e))?;
        let field = field
            .try_load_record(record)
            .map_err(|e| CheckpointError::format(&model_file, "record", e))?;
        match first_non_finite(&field) {
            Some(tensor) => Err(CheckpointError::NonFinite {
                file: model_file,
                tensor,
            }),
            None => Ok(field),
        }
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
