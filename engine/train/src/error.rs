//! Why a run could not start, step or save. Each names the file, frame, subject or flag.

use std::path::PathBuf;

use talkin_avatar::checkpoint::CheckpointError;
use talkin_avatar::subject::SubjectModelError;
use talkin_data::dataset::DatasetError;
use talkin_grids::GridError;
use talkin_nets::NetsError;
use talkin_nets::loss::LossError;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Subject(#[from] SubjectModelError),
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {source}", file.display())]
    Log {
        file: PathBuf,
        #[source]
        source: csv::Error,
    },
    #[error("option `{flag}`: {problem}")]
    BadOption { flag: &'static str, problem: String },
    #[error("{}: no frame of split `train` for the chosen identities", file.display())]
    NoTrainFrames { file: PathBuf },
    #[error("{}: frames[{frame}]: sampling: {source}", file.display())]
    Grid {
        file: PathBuf,
        frame: usize,
        #[source]
        source: GridError,
    },
    #[error("subject `{subject}`: occupancy grid: {source}")]
    Occupancy {
        subject: String,
        #[source]
        source: GridError,
    },
    #[error(transparent)]
    Device(#[from] talkin_nets::DeviceError),
    #[error("field: {source}")]
    Field {
        #[source]
        source: NetsError,
    },
    #[error("perceptual loss: {source}")]
    Perceptual {
        #[source]
        source: LossError,
    },
    #[error("step {step}: the loss is not finite ({loss}); lower --lr?")]
    NonFinite { step: usize, loss: f32 },
    /// The peers of a data-parallel run refused each other or an exchange failed.
    #[error(transparent)]
    Peers(#[from] talkin_peers::PeerError),
    /// The peers stopped drawing the same run (a bug, or machines whose arithmetic
    /// differs): stopped before they train different models.
    #[error(
        "step {step}: the peers no longer agree on {what} (peer {rank} holds {mine}, the \
         peers' mean is {mean}); the last checkpoint stands"
    )]
    PeersDiverged {
        step: usize,
        what: &'static str,
        rank: usize,
        mine: f32,
        mean: f32,
    },
    #[error("step {step}: handing its work to the device failed: {problem}")]
    Flush { step: usize, problem: String },
    #[error("steps {first}-{last}: reading their losses back from the device failed: {problem}")]
    Readback {
        first: usize,
        last: usize,
        problem: String,
    },
    #[error("{}: {problem}", file.display())]
    Resume { file: PathBuf, problem: String },
    #[error("{}: cannot record the run: {problem}", file.display())]
    Recipe { file: PathBuf, problem: String },
    #[error(
        "{}: the run was trained on {} (dataset.json SHA-256 {trained_sha256}), but {} has \
         SHA-256 {given_sha256}: resume with the run's dataset, or start a new run with --force",
        run.display(),
        trained_on.display(),
        given.display()
    )]
    OtherDataset {
        run: PathBuf,
        trained_on: PathBuf,
        trained_sha256: String,
        given: PathBuf,
        given_sha256: String,
    },
}
