//! Poses files: `{"frames": [{"params": {...}, "camera": {...}}, ...]}`, where `params` and
//! `camera` are exactly dataset.json's frame objects (same parsers, same errors, naming
//! the file and field path such as `frames[3].params.body_pose`). Other members of a
//! frame (e.g. `time`, `subject`) are ignored, so a dataset.json is itself a poses file.

use std::path::Path;

use serde_json::Value;

use talkin_data::dataset::{DatasetError, camera_field};
use talkin_data::json_shape;
use talkin_data::params_json::ParamsJson;
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;

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
