//! `manifest.json`: the size and SHA-256 of every other file of a checkpoint, written
//! last. Loading checks each file against it, so a flipped byte, a truncated file or a
//! file from another checkpoint is caught before anything is parsed or rendered.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::CheckpointError;

/// The manifest's file name inside a checkpoint directory.
pub const MANIFEST_FILE: &str = "manifest.json";
const FORMAT: &str = "talkin-checkpoint";
const VERSION: u32 = 1;

/// The lowercase hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    format!("{:x}", Sha256::digest(bytes))
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// File name -> its size and hash.
    pub files: BTreeMap<String, FileSum>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FileSum {
    pub bytes: u64,
    pub sha256: String,
}

impl Manifest {
    pub fn new() -> Manifest {
        Manifest {
            format: FORMAT.into(),
            version: VERSION,
            files: BTreeMap::new(),
        }
    }

    /// Records `bytes` as the content of `name`.
    pub fn add(&mut self, name: &str, bytes: &[u8]) {
        self.files.insert(
            name.to_string(),
            FileSum {
                bytes: bytes.len() as u64,
                sha256: sha256_hex(bytes),
            },
        );
    }

    pub fn to_json(&self) -> Result<Vec<u8>, serde_json::Error> {
        serde_json::to_vec_pretty(self)
    }

    /// The manifest of checkpoint `dir`: `Ok(None)` when it has none (a checkpoint
    /// written before manifests existed).
    pub fn read(dir: &Path) -> Result<Option<Manifest>, CheckpointError> {
        let file = dir.join(MANIFEST_FILE);
        let bytes = match std::fs::read(&file) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(CheckpointError::Io { file, source }),
        };
        let manifest: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| CheckpointError::format(&file, "manifest", e))?;
        if manifest.format != FORMAT || manifest.version != VERSION {
            return Err(CheckpointError::format(
                &file,
                "format",
                format!(
                    "expected `{FORMAT}` version {VERSION}, found `{}` version {}",
                    manifest.format, manifest.version
                ),
            ));
        }
        Ok(Some(manifest))
    }

    /// Checks that every file in `required` is listed and that every listed file in
    /// `dir` has its recorded size and hash; the error names the first file that does
    /// not.
    pub fn verify(&self, dir: &Path, required: &[&str]) -> Result<(), CheckpointError> {
        let manifest_file = dir.join(MANIFEST_FILE);
        if let Some(name) = required.iter().find(|n| !self.files.contains_key(**n)) {
            return Err(CheckpointError::format(
                &manifest_file,
                "files",
                format!("does not list `{name}`"),
            ));
        }
        for (name, sum) in &self.files {
            if name.contains(['/', '\\']) || name.starts_with('.') {
                return Err(CheckpointError::format(
                    &manifest_file,
                    "files",
                    format!("{name:?} is not a file name inside the checkpoint"),
                ));
            }
            let file = dir.join(name);
            let bytes = std::fs::read(&file).map_err(CheckpointError::io(&file))?;
            let found = sha256_hex(&bytes);
            if bytes.len() as u64 != sum.bytes || found != sum.sha256 {
                return Err(CheckpointError::Damaged {
                    file,
                    problem: format!(
                        "{} bytes with SHA-256 {found}, but {MANIFEST_FILE} recorded {} bytes \
                         with SHA-256 {}",
                        bytes.len(),
                        sum.bytes,
                        sum.sha256
                    ),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_changed_byte_or_length_is_caught_and_named() {
        let dir = std::env::temp_dir().join(format!("talkin_manifest_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Manifest::new();
        for (name, bytes) in [("a.bin", &b"hello"[..]), ("b.json", b"{}")] {
            std::fs::write(dir.join(name), bytes).unwrap();
            m.add(name, bytes);
        }
        std::fs::write(dir.join(MANIFEST_FILE), m.to_json().unwrap()).unwrap();
        let back = Manifest::read(&dir).unwrap().unwrap();
        assert_eq!(back, m);
        back.verify(&dir, &["a.bin"]).unwrap();
        let e = back.verify(&dir, &["c.bin"]).unwrap_err().to_string();
        assert!(e.contains("c.bin"), "{e}");
        std::fs::write(dir.join("a.bin"), b"hellp").unwrap();
        let e = back.verify(&dir, &[]).unwrap_err().to_string();
        assert!(e.contains("a.bin") && e.contains("SHA-256"), "{e}");
        std::fs::write(dir.join("a.bin"), b"hell").unwrap();
        let e = back.verify(&dir, &[]).unwrap_err().to_string();
        assert!(e.contains("a.bin") && e.contains("4 bytes"), "{e}");
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
