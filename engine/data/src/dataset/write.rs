//! Writing dataset.json (atomically: a temp file, then rename).

use std::path::Path;

use serde_json::{Value, json};

use super::{Dataset, DatasetError, FORMAT, INDEX_FILE, Masks, Matting, VERSION};
use crate::params_json::ParamsJson;

impl Dataset {
    /// The dataset.json document.
    pub fn to_json(&self) -> Value {
        let subjects: Vec<Value> = self
            .subjects
            .iter()
            .map(|s| {
                let joints: Vec<[f64; 3]> = s
                    .skeleton
                    .rest_joints
                    .iter()
                    .map(|j| j.to_array().map(round9))
                    .collect();
                json!({"name": s.name, "rest_joints": joints})
            })
            .collect();
        let frames: Vec<Value> = self
            .frames
            .iter()
            .map(|f| {
                let mut frame = json!({
                    "subject": f.subject,
                    "split": f.split.name(),
                    "time": round9(f.time),
                    "image": path_string(&f.image),
                    "mask": path_string(&f.mask),
                    "camera": {
                        "width": f.camera.width,
                        "height": f.camera.height,
                        "intrinsics": f.camera.intrinsics_rows().map(|r| r.map(round9)),
                        "extrinsics": f.camera.extrinsics_rows().map(|r| r.map(round9)),
                    },
                    "params": f.params.to_json(),
                });
                if let Some(segmentation) = &f.segmentation {
                    frame["segmentation"] = json!(path_string(segmentation));
                }
                if let Some(depth) = &f.depth {
                    frame["depth"] = json!(path_string(depth));
                }
                frame
            })
            .collect();
        // A dataset shown over another colour is written as it is on disk.
        let background = match self.matting {
            Matting::Reshown { files_over } => files_over,
            _ => self.background,
        };
        let mut doc = json!({
            "format": FORMAT,
            "version": VERSION,
            "background": background.map(|c| round9(c as f64)),
            "matting": self.matting.name(),
            "subjects": subjects,
            "frames": frames,
        });
        if self.masks != Masks::Matte {
            doc["masks"] = json!(self.masks.name());
        }
        doc
    }

    /// Writes `root/dataset.json` atomically (temp file + rename): a crash never leaves a
    /// half-written index.
    pub fn save_index(&self) -> Result<(), DatasetError> {
        let text =
            serde_json::to_string_pretty(&self.to_json()).expect("a JSON value always serialises");
        write_atomic(&self.root.join(INDEX_FILE), text.as_bytes())
    }
}

/// Writes `bytes` to `path` atomically ([`crate::atomic::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    crate::atomic::write_atomic(path, bytes).map_err(|source| DatasetError::Io {
        file: path.to_path_buf(),
        source,
    })
}

fn path_string(p: &Path) -> String {
    // Forward slashes on every platform: the file is shared between machines.
    p.components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

fn round9(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}
