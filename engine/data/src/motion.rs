//! Motion files: pose sequences to drive a subject (`talkin synth --motion`, rendering).
//!
//! Two formats, chosen by extension:
//! - `.json`: a list of `params` objects as in dataset.json (or of objects carrying one
//!   under `"params"`), parsed by [`FrameParams::from_json`]; errors name `[i].field`.
//! - `.npz` (a zip of `.npy` arrays, as numpy writes it): SMPL-X `poses` (N x 165:
//!   global_orient 3, body 63, jaw 3, left eye 3, right eye 3, left hand 45, right hand
//!   45), optional `expressions` (or `expression`; N x >= 10, the first 10 are used,
//!   missing = zeros) and optional `trans` (or `transl`; N x 3, missing = zeros). dtype
//!   `<f4` or `<f8`, C order. NaN and infinities are rejected.

use std::io::Read;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde_json::Value;

use crate::json_shape::ShapeError;
use crate::params_json::ParamsJson;
use talkin_human::body::{FrameParams, N_BODY_JOINTS, N_EXPRESSION, N_HAND_JOINTS};

/// Columns of the SMPL-X `poses` array.
pub const POSE_COLUMNS: usize = 3 * (1 + (N_BODY_JOINTS - 1) + 3 + 2 * N_HAND_JOINTS);

/// Why a motion file was rejected. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: malformed JSON: {message}", file.display())]
    Json { file: PathBuf, message: String },
    #[error("{}: {source}", file.display())]
    Shape {
        file: PathBuf,
        #[source]
        source: ShapeError,
    },
    #[error("{}: array `{array}`: {problem}", file.display())]
    Array {
        file: PathBuf,
        array: String,
        problem: String,
    },
    #[error("{}: {problem}", file.display())]
    Format { file: PathBuf, problem: String },
}

/// Loads a motion file (`.json` or `.npz`).
pub fn load_motion(path: impl AsRef<Path>) -> Result<Vec<FrameParams>, MotionError> {
    let file = path.as_ref().to_path_buf();
    let ext = file
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("json") => load_json(&file),
        Some("npz") => load_npz(&file),
        _ => Err(MotionError::Format {
            file,
            problem: "expected a .json or .npz motion file".into(),
        }),
    }
}

fn load_json(file: &Path) -> Result<Vec<FrameParams>, MotionError> {
    let text = std::fs::read_to_string(file).map_err(|source| MotionError::Io {
        file: file.into(),
        source,
    })?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| MotionError::Json {
        file: file.into(),
        message: e.to_string(),
    })?;
    let Some(list) = doc.as_array().filter(|a| !a.is_empty()) else {
        return Err(MotionError::Format {
            file: file.into(),
            problem: "expected a non-empty JSON list of params objects".into(),
        });
    };
    list.iter()
        .enumerate()
        .map(|(i, v)| {
            let (v, path) = match v.get("params") {
                Some(p) => (p, format!("[{i}].params")),
                None => (v, format!("[{i}]")),
            };
            FrameParams::from_json(v, &path).map_err(|source| MotionError::Shape {
                file: file.into(),
                source,
            })
        })
        .collect()
}

/// A parsed .npy array: shape and values as f64.
#[derive(Debug)]
struct Npy {
    shape: Vec<usize>,
    data: Vec<f64>,
}

fn load_npz(file: &Path) -> Result<Vec<FrameParams>, MotionError> {
    let f = std::fs::File::open(file).map_err(|source| MotionError::Io {
        file: file.into(),
        source,
    })?;
    let mut zip = zip::ZipArchive::new(f).map_err(|e| MotionError::Format {
        file: file.into(),
        problem: format!("not an .npz (zip) archive: {e}"),
    })?;
    let mut read = |names: &[&str]| -> Result<Option<(String, Npy)>, MotionError> {
        for name in names {
            let entry = format!("{name}.npy");
            let mut bytes = Vec::new();
            match zip.by_name(&entry) {
                Ok(mut e) => {
                    e.read_to_end(&mut bytes)
                        .map_err(|source| MotionError::Io {
                            file: file.into(),
                            source,
                        })?;
                }
                Err(zip::result::ZipError::FileNotFound) => continue,
                Err(e) => {
                    return Err(MotionError::Format {
                        file: file.into(),
                        problem: format!("{entry}: {e}"),
                    });
                }
            }
            let npy = parse_npy(&bytes).map_err(|problem| MotionError::Array {
                file: file.into(),
                array: name.to_string(),
                problem,
            })?;
            if let Some(k) = npy.data.iter().position(|x| !x.is_finite()) {
                let cols = npy.shape.get(1).copied().unwrap_or(1).max(1);
                return Err(MotionError::Array {
                    file: file.into(),
                    array: name.to_string(),
                    problem: format!(
                        "non-finite value {} at [{}, {}]",
                        npy.data[k],
                        k / cols,
                        k % cols
                    ),
                });
            }
            return Ok(Some((name.to_string(), npy)));
        }
        Ok(None)
    };
    let Some((_, poses)) = read(&["poses"])? else {
        return Err(MotionError::Array {
            file: file.into(),
            array: "poses".into(),
            problem: format!("missing: an SMPL-X motion needs `poses` (N x {POSE_COLUMNS})"),
        });
    };
    let shape_err = |array: &str, expected: String, found: &[usize]| MotionError::Array {
        file: file.into(),
        array: array.into(),
        problem: format!("expected shape {expected}, found {found:?}"),
    };
    if poses.shape.len() != 2 || poses.shape[1] != POSE_COLUMNS || poses.shape[0] == 0 {
        return Err(shape_err(
            "poses",
            format!("(N >= 1, {POSE_COLUMNS})"),
            &poses.shape,
        ));
    }
    let n = poses.shape[0];
    let expressions = read(&["expressions", "expression"])?;
    if let Some((name, e)) = &expressions
        && (e.shape.len() != 2 || e.shape[0] != n || e.shape[1] < N_EXPRESSION)
    {
        return Err(shape_err(
            name,
            format!("({n}, >= {N_EXPRESSION}) to match poses"),
            &e.shape,
        ));
    }
    let trans = read(&["trans", "transl"])?;
    if let Some((name, t)) = &trans
        && (t.shape.len() != 2 || t.shape[0] != n || t.shape[1] != 3)
    {
        return Err(shape_err(
            name,
            format!("({n}, 3) to match poses"),
            &t.shape,
        ));
    }
    Ok((0..n)
        .map(|i| {
            let row = &poses.data[i * POSE_COLUMNS..(i + 1) * POSE_COLUMNS];
            let v = |k: usize| DVec3::new(row[3 * k], row[3 * k + 1], row[3 * k + 2]);
            let mut p = FrameParams {
                global_orient: v(0),
                ..Default::default()
            };
            for j in 0..N_BODY_JOINTS - 1 {
                p.body_pose[j] = v(1 + j);
            }
            p.jaw_pose = v(22);
            p.leye_pose = v(23);
            p.reye_pose = v(24);
            for j in 0..N_HAND_JOINTS {
                p.left_hand_pose[j] = v(25 + j);
                p.right_hand_pose[j] = v(40 + j);
            }
            if let Some((_, e)) = &expressions {
                let cols = e.shape[1];
                p.expression
                    .copy_from_slice(&e.data[i * cols..i * cols + N_EXPRESSION]);
            }
            if let Some((_, t)) = &trans {
                p.transl = DVec3::new(t.data[3 * i], t.data[3 * i + 1], t.data[3 * i + 2]);
            }
            p
        })
        .collect())
}

/// The text after `'key':` in a .npy header dict.
fn header_value<'h>(header: &'h str, key: &str) -> Result<&'h str, String> {
    let at = header
        .find(&format!("'{key}'"))
        .ok_or_else(|| format!("the .npy header has no '{key}'"))?;
    let rest = header[at + key.len() + 2..].trim_start();
    Ok(rest
        .strip_prefix(':')
        .ok_or_else(|| format!("malformed '{key}' in the .npy header"))?
        .trim_start())
}

/// Parses a .npy v1/v2/v3 file holding a little-endian f4 or f8 C-order array.
fn parse_npy(bytes: &[u8]) -> Result<Npy, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy array (bad magic)".into());
    }
    let major = bytes[6];
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(format!(".npy version {major} is not supported (1, 2 or 3)")),
    };
    let header = bytes
        .get(start..start + header_len)
        .ok_or("truncated .npy header")?;
    let header = std::str::from_utf8(header).map_err(|_| "the .npy header is not text")?;
    let value_of = |key: &str| header_value(header, key);
    let descr = value_of("descr")?;
    let width = if descr.starts_with("'<f4'") {
        4
    } else if descr.starts_with("'<f8'") {
        8
    } else {
        let d: String = descr.chars().take_while(|c| *c != ',').collect();
        return Err(format!(
            "dtype {d} is not supported (expected '<f4' or '<f8')"
        ));
    };
    if value_of("fortran_order")?.starts_with("True") {
        return Err("Fortran-order arrays are not supported (expected C order)".into());
    }
    let shape_text = value_of("shape")?;
    let inner = shape_text
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or("malformed 'shape' in the .npy header")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("malformed shape entry {s:?}"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &b| a.checked_mul(b))
        .ok_or("shape too large")?;
    let data = &bytes[start + header_len..];
    if data.len() != count * width {
        return Err(format!(
            "shape {shape:?} needs {} bytes of data, found {}",
            count * width,
            data.len()
        ));
    }
    let data = if width == 4 {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64)
            .collect()
    } else {
        data.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    };
    Ok(Npy { shape, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str, values: &[f64]) -> Vec<u8> {
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        let h = format!(
            "{{'descr': '{descr}', 'fortran_order': False, 'shape': ({},), }}",
            values.len()
        );
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        for v in values {
            b.extend(v.to_le_bytes());
        }
        b
    }

    #[test]
    fn npy_headers() {
        let b = npy("<f8", &[1.5, -2.0]);
        let a = parse_npy(&b).unwrap();
        assert_eq!(a.shape, vec![2]);
        assert_eq!(a.data, vec![1.5, -2.0]);
        assert!(parse_npy(&b[..b.len() - 1]).unwrap_err().contains("bytes"));
        assert!(
            parse_npy(&npy(">f8", &[1.0]))
                .unwrap_err()
                .contains("dtype")
        );
    }
}
