//! What `talkin render --poses`/`--motion` reads, through one reader
//! ([`read_pose_source`]):
//!
//! - poses files: `{"frames": [{"params": {...}, "camera": {...}}, ...]}`, where `params`
//!   and `camera` are exactly dataset.json's frame objects (same parsers, same errors,
//!   naming the file and field path such as `frames[3].params.body_pose`). Other members
//!   of a frame (e.g. `time`, `subject`) are ignored, so a dataset.json is itself a poses
//!   file;
//! - motion files without cameras: a JSON list of `params` objects, or a BEAT2 or AMASS
//!   `.npz` ([`talkin_data::motion`]), to be seen through one camera ([`motion_poses`]).

use std::path::{Path, PathBuf};

use serde_json::Value;

use talkin_data::dataset::{DatasetError, camera_field};
use talkin_data::json_shape;
use talkin_data::motion::{
    Hands, Motion, MotionError, MotionLayout, UpAxis, parse_json, read_motion,
};
use talkin_data::params_json::ParamsJson;
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;

/// What a poses or motion file holds.
#[derive(Clone, Debug)]
pub enum PoseSource {
    /// Poses, each with its camera.
    Posed(Vec<PosedCamera>),
    /// A motion: poses only, in its file's conventions.
    Motion(Motion),
}

/// Why a poses or motion file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum PoseSourceError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Motion(#[from] MotionError),
}

/// Reads a poses file (JSON with `frames`) or a motion file (a JSON list of params, or
/// an `.npz`; `layout` forces the `.npz` layout).
pub fn read_pose_source(
    file: &Path,
    layout: Option<MotionLayout>,
) -> Result<PoseSource, PoseSourceError> {
    let is_json = file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if !is_json {
        return Ok(PoseSource::Motion(read_motion(file, layout)?));
    }
    let text = std::fs::read_to_string(file).map_err(|source| DatasetError::Io {
        file: file.to_path_buf(),
        source,
    })?;
    // A list is a motion; anything else must be a poses file.
    if text.trim_start().starts_with('[') {
        let doc: Value = serde_json::from_str(&text).map_err(|e| MotionError::Json {
            file: file.to_path_buf(),
            message: e.to_string(),
        })?;
        return Ok(PoseSource::Motion(Motion {
            file: PathBuf::from(file),
            layout: MotionLayout::Params,
            frames: parse_json(&doc, file)?,
            fps: None,
            betas: Vec::new(),
            gender: None,
            up: UpAxis::Y,
            hands: Hands::Absolute,
        }));
    }
    Ok(PoseSource::Posed(parse_poses(&text, file)?))
}

/// Every frame of a motion seen through `camera`.
pub fn motion_poses(frames: &[FrameParams], camera: Camera) -> Vec<PosedCamera> {
    frames
        .iter()
        .map(|p| PosedCamera {
            params: p.clone(),
            camera,
        })
        .collect()
}

/// A pose and the camera to see it through.
#[derive(Clone, Debug, PartialEq)]
pub struct PosedCamera {
    pub params: FrameParams,
    pub camera: Camera,
}

/// Reads and validates a poses file.
pub fn read_poses_file(file: &Path) -> Result<Vec<PosedCamera>, DatasetError> {
    let text = std::fs::read_to_string(file).map_err(|source| DatasetError::Io {
        file: file.to_path_buf(),
        source,
    })?;
    parse_poses(&text, file)
}

/// Parses the text of poses file `file` (named in errors).
pub fn parse_poses(text: &str, file: &Path) -> Result<Vec<PosedCamera>, DatasetError> {
    let doc: Value = serde_json::from_str(text).map_err(|e| DatasetError::Json {
        file: file.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: format!("{e}{}", non_json_number_hint(text, e.line(), e.column())),
    })?;
    let shape = |source| DatasetError::Shape {
        file: file.to_path_buf(),
        source,
    };
    let frames = json_shape::member(&doc, "", "frames").map_err(shape)?;
    let Some(frames) = frames.as_array().filter(|a| !a.is_empty()) else {
        return Err(DatasetError::Invalid {
            file: file.to_path_buf(),
            field: "frames".into(),
            problem: "expected a non-empty array of {\"params\", \"camera\"} objects".into(),
        });
    };
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let path = format!("frames[{i}]");
            let params = FrameParams::from_json(
                json_shape::member(f, &path, "params").map_err(shape)?,
                &format!("{path}.params"),
            )
            .map_err(shape)?;
            let camera = camera_field(
                json_shape::member(f, &path, "camera").map_err(shape)?,
                &format!("{path}.camera"),
                file,
            )?;
            Ok(PosedCamera { params, camera })
        })
        .collect()
}

/// Python's `json.dump` writes NaN and Infinity, which are not JSON: say so.
fn non_json_number_hint(text: &str, line: usize, column: usize) -> &'static str {
    let Some(l) = text.lines().nth(line.saturating_sub(1)) else {
        return "";
    };
    let from = column.saturating_sub(2).min(l.len());
    let near = l.get(from..).unwrap_or("");
    if ["NaN", "Infinity", "-Infinity", "aN", "nfinity"]
        .iter()
        .any(|t| near.trim_start_matches([',', '[', ' ']).starts_with(t))
    {
        " (NaN and Infinity are not JSON: every pose and camera value must be a finite number)"
    } else {
        ""
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use serde_json::json;

    fn frame() -> Value {
        let cam =
            Camera::look_at(32, 48, 60.0, DVec3::new(0.0, 1.0, 3.0), DVec3::Y, DVec3::Y).unwrap();
        json!({
            "params": FrameParams::default().to_json(),
            "camera": {
                "width": cam.width, "height": cam.height,
                "intrinsics": cam.intrinsics_rows(), "extrinsics": cam.extrinsics_rows(),
            },
        })
    }

    #[test]
    fn one_reader_for_poses_files_and_motions() {
        let dir = std::env::temp_dir().join(format!("talkin_pose_source_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let poses = dir.join("poses.json");
        std::fs::write(&poses, json!({"frames": [frame()]}).to_string()).unwrap();
        assert!(matches!(read_pose_source(&poses, None), Ok(PoseSource::Posed(p)) if p.len() == 1));
        let list = dir.join("motion.json");
        std::fs::write(&list, json!([FrameParams::default().to_json()]).to_string()).unwrap();
        let Ok(PoseSource::Motion(m)) = read_pose_source(&list, None) else {
            panic!("a list is a motion")
        };
        assert_eq!((m.frames.len(), m.layout), (1, MotionLayout::Params));
        let npz = dir.join("motion.npz");
        let mut w = talkin_data::npz::NpzWriter::create(&npz).unwrap();
        w.array(
            "poses",
            &talkin_data::array::NdArray::f32(&[2, 165], vec![0.0; 330]).unwrap(),
        )
        .unwrap();
        w.finish().unwrap();
        let Ok(PoseSource::Motion(m)) = read_pose_source(&npz, None) else {
            panic!("an npz is a motion")
        };
        assert_eq!((m.frames.len(), m.layout), (2, MotionLayout::Beat2));
        let cam = Camera::look_at(8, 8, 8.0, DVec3::Z, DVec3::ZERO, DVec3::Y).unwrap();
        assert_eq!(motion_poses(&m.frames, cam)[1].camera, cam);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn reads_frames_and_names_bad_fields() {
        let file = Path::new("poses.json");
        let good = json!({"frames": [frame(), frame()]}).to_string();
        let poses = parse_poses(&good, file).unwrap();
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[1].camera.width, 32);

        let mut bad = json!({"frames": [frame(), frame(), frame(), frame()]});
        bad["frames"][3]["params"]["body_pose"] = json!([[0, 0, 0]]);
        let e = parse_poses(&bad.to_string(), file).unwrap_err().to_string();
        assert!(
            e.contains("poses.json") && e.contains("frames[3].params.body_pose"),
            "{e}"
        );

        let mut bad = json!({"frames": [frame()]});
        bad["frames"][0]["camera"]["intrinsics"][1][1] = json!(0.0);
        let e = parse_poses(&bad.to_string(), file).unwrap_err().to_string();
        assert!(e.contains("frames[0].camera") && e.contains("focal"), "{e}");

        let mut bad = json!({"frames": [frame()]});
        bad["frames"][0]["params"]["jaw_pose"][2] = json!("nan");
        let e = parse_poses(&bad.to_string(), file).unwrap_err().to_string();
        assert!(e.contains("frames[0].params.jaw_pose[2]"), "{e}");

        let e = parse_poses(r#"{"frames": []}"#, file)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`frames`"), "{e}");
        let e = parse_poses("{\"frames\": [\n  {\"params\": [NaN]}]}", file)
            .unwrap_err()
            .to_string();
        assert!(e.contains("poses.json") && e.contains("line 2"), "{e}");
        assert!(e.contains("NaN and Infinity are not JSON"), "{e}");
    }
}
