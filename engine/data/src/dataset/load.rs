//! Parsing and validating dataset.json, and checking every referenced image's header.

use std::collections::HashSet;
use std::path::{Component, Path, PathBuf};

use glam::DVec3;
use serde_json::Value;

use super::{
    Dataset, DatasetError, FORMAT, Frame, INDEX_FILE, Masks, Matting, Split, Subject, VERSION,
};
use crate::json_shape::{self, ShapeError};
use crate::params_json::ParamsJson;
use talkin_human::body::{FrameParams, N_JOINTS, Skeleton};
use talkin_human::camera::Camera;

impl Dataset {
    /// Loads and validates `dir/dataset.json` and checks that every image, mask and
    /// segmentation file exists with a PNG header of the camera's size. Pixels are not
    /// decoded here.
    pub fn load(dir: impl AsRef<Path>) -> Result<Dataset, DatasetError> {
        let root = dir.as_ref().to_path_buf();
        let file = root.join(INDEX_FILE);
        let text =
            std::fs::read_to_string(&file).map_err(|source| DatasetError::Io { file, source })?;
        let dataset = Dataset::from_json_str(&text, &root)?;
        dataset.check_image_headers()?;
        Ok(dataset)
    }

    /// Parses and validates the JSON text of a dataset rooted at `root` (no file access).
    pub fn from_json_str(text: &str, root: &Path) -> Result<Dataset, DatasetError> {
        let r = Reader {
            file: root.join(INDEX_FILE),
        };
        // RFC 8259 lets a parser ignore a byte order mark, and editors on Windows write one.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let doc: Value = serde_json::from_str(text).map_err(|e| DatasetError::Json {
            file: r.file.clone(),
            line: e.line(),
            column: e.column(),
            message: e.to_string(),
        })?;
        let background = r.header(&doc)?;
        let matting = r.matting(&doc)?;
        let masks = r.masks(&doc)?;
        let subjects = r.subjects(&doc)?;
        let frames_json = json_shape::member(&doc, "", "frames").map_err(|e| r.shape(e))?;
        let Some(frames_json) = frames_json.as_array().filter(|a| !a.is_empty()) else {
            return Err(r.invalid("frames", "expected a non-empty array of frames".into()));
        };
        let frames = frames_json
            .iter()
            .enumerate()
            .map(|(i, f)| r.frame(f, &format!("frames[{i}]"), subjects.len()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Dataset {
            root: root.to_path_buf(),
            background,
            matting,
            masks,
            subjects,
            frames,
        })
    }

    /// Every referenced PNG exists and its header says the camera's size.
    fn check_image_headers(&self) -> Result<(), DatasetError> {
        for frame in &self.frames {
            for rel in [&frame.image, &frame.mask]
                .into_iter()
                .chain(&frame.segmentation)
                .chain(&frame.depth)
            {
                let file = self.root.join(rel);
                let reader = super::images::open_png(&file)?;
                let (w, h) = reader.into_dimensions().map_err(|e| DatasetError::Image {
                    file: file.clone(),
                    problem: format!("unreadable PNG header: {e}"),
                })?;
                if (w, h) != (frame.camera.width, frame.camera.height) {
                    return Err(DatasetError::Image {
                        file,
                        problem: format!(
                            "is {w}x{h} but its frame's camera is {}x{}",
                            frame.camera.width, frame.camera.height
                        ),
                    });
                }
            }
        }
        Ok(())
    }
}

/// The camera object at `path` of `file` (a dataset.json or a poses file), with errors
/// naming the file and field.
pub fn camera_field(v: &Value, path: &str, file: &Path) -> Result<Camera, DatasetError> {
    parse_camera(v, path).map_err(|e| match e {
        Ok(source) => DatasetError::Camera {
            file: file.to_path_buf(),
            field: path.to_string(),
            source,
        },
        Err(source) => DatasetError::Shape {
            file: file.to_path_buf(),
            source,
        },
    })
}

/// A dataset `camera` object at `path` (frames, poses files, the render server):
/// `Err(Ok(_))` for a well-shaped but degenerate camera, `Err(Err(_))` for a shape problem.
pub fn parse_camera(
    v: &Value,
    path: &str,
) -> Result<Camera, Result<talkin_human::camera::CameraError, ShapeError>> {
    let get = |k: &str| json_shape::member(v, path, k).map_err(Err);
    let side = |k: &str| -> Result<u32, Result<_, ShapeError>> {
        let n = json_shape::index(get(k)?, &format!("{path}.{k}")).map_err(Err)?;
        u32::try_from(n).map_err(|_| {
            Err(ShapeError {
                field: format!("{path}.{k}"),
                expected: "a pixel count".into(),
                found: n.to_string(),
            })
        })
    };
    let width = side("width")?;
    let height = side("height")?;
    let k =
        json_shape::matrix(get("intrinsics")?, &format!("{path}.intrinsics"), 3, 3).map_err(Err)?;
    let e =
        json_shape::matrix(get("extrinsics")?, &format!("{path}.extrinsics"), 4, 4).map_err(Err)?;
    let k: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| k[3 * r + c]));
    let e: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| e[4 * r + c]));
    Camera::new(width, height, k, e).map_err(Ok)
}

/// Reads the parts of one dataset.json; errors name it.
struct Reader {
    file: PathBuf,
}

impl Reader {
    fn shape(&self, source: ShapeError) -> DatasetError {
        DatasetError::Shape {
            file: self.file.clone(),
            source,
        }
    }

    fn invalid(&self, field: &str, problem: String) -> DatasetError {
        DatasetError::Invalid {
            file: self.file.clone(),
            field: field.to_string(),
            problem,
        }
    }

    /// Checks `format` and `version`; returns the background colour.
    fn header(&self, doc: &Value) -> Result<[f32; 3], DatasetError> {
        let shape = |e| self.shape(e);
        let format = json_shape::string(
            json_shape::member(doc, "", "format").map_err(shape)?,
            "format",
        )
        .map_err(shape)?;
        if format != FORMAT {
            return Err(self.invalid("format", format!("expected \"{FORMAT}\", found {format:?}")));
        }
        let version = json_shape::index(
            json_shape::member(doc, "", "version").map_err(shape)?,
            "version",
        )
        .map_err(shape)?;
        if version as u64 != VERSION {
            return Err(self.invalid(
                "version",
                format!("this build reads version {VERSION}, found {version}"),
            ));
        }
        let bg = json_shape::vector(
            json_shape::member(doc, "", "background").map_err(shape)?,
            "background",
            3,
        )
        .map_err(shape)?;
        if bg.iter().any(|c| !(0.0..=1.0).contains(c)) {
            let hint = if bg.iter().all(|c| (0.0..=255.0).contains(c)) {
                " (8-bit values? divide them by 255)"
            } else {
                ""
            };
            return Err(self.invalid(
                "background",
                format!("expected 3 numbers in [0, 1], found {bg:?}{hint}"),
            ));
        }
        Ok([bg[0] as f32, bg[1] as f32, bg[2] as f32])
    }

    /// `matting`: absent (matted, as every dataset before the field), "matted" or "by_mask".
    fn matting(&self, doc: &Value) -> Result<Matting, DatasetError> {
        let Some(v) = doc.get("matting") else {
            return Ok(Matting::Matted);
        };
        let name = json_shape::string(v, "matting").map_err(|e| self.shape(e))?;
        Matting::from_name(name).ok_or_else(|| {
            self.invalid(
                "matting",
                format!(
                    "expected \"matted\" (the images show the person over `background`) or \"by_mask\" (camera frames, composited by their masks), found {name:?}"
                ),
            )
        })
    }

    /// `masks`: absent (a matte, as every dataset before the field), "matte" or "coverage".
    fn masks(&self, doc: &Value) -> Result<Masks, DatasetError> {
        let Some(v) = doc.get("masks") else {
            return Ok(Masks::Matte);
        };
        let name = json_shape::string(v, "masks").map_err(|e| self.shape(e))?;
        Masks::from_name(name).ok_or_else(|| {
            self.invalid(
                "masks",
                format!(
                    "expected \"matte\" (a matting tool's or your masks) or \"coverage\" (each pixel's exact covered fraction, what `synth` writes), found {name:?}"
                ),
            )
        })
    }

    /// The subjects: unique names and human-sized rest skeletons.
    fn subjects(&self, doc: &Value) -> Result<Vec<Subject>, DatasetError> {
        let shape = |e| self.shape(e);
        let subjects_json = json_shape::member(doc, "", "subjects").map_err(shape)?;
        let Some(subjects_json) = subjects_json.as_array().filter(|a| !a.is_empty()) else {
            return Err(self.invalid("subjects", "expected a non-empty array of subjects".into()));
        };
        let mut subjects = Vec::with_capacity(subjects_json.len());
        let mut names = HashSet::new();
        for (i, s) in subjects_json.iter().enumerate() {
            let path = format!("subjects[{i}]");
            let name = json_shape::string(
                json_shape::member(s, &path, "name").map_err(shape)?,
                &format!("{path}.name"),
            )
            .map_err(shape)?;
            if name.is_empty() || !names.insert(name.to_string()) {
                return Err(self.invalid(
                    &format!("{path}.name"),
                    format!("must be non-empty and unique, found {name:?}"),
                ));
            }
            let field = format!("{path}.rest_joints");
            let j = json_shape::matrix(
                json_shape::member(s, &path, "rest_joints").map_err(shape)?,
                &field,
                N_JOINTS,
                3,
            )
            .map_err(shape)?;
            let rest_joints =
                std::array::from_fn(|k| DVec3::new(j[3 * k], j[3 * k + 1], j[3 * k + 2]));
            let skeleton = Skeleton { rest_joints };
            if !(skeleton.scale() > 0.05 && skeleton.scale() < 20.0) {
                return Err(self.invalid(
                    &field,
                    format!(
                        "pelvis-to-neck distance {:.4} m is not a human's (joints in metres?)",
                        skeleton.scale() * 0.55
                    ),
                ));
            }
            subjects.push(Subject {
                name: name.to_string(),
                skeleton,
            });
        }
        Ok(subjects)
    }

    /// The frame object `f` at `path`, of a dataset with `n_subjects` subjects.
    fn frame(&self, f: &Value, path: &str, n_subjects: usize) -> Result<Frame, DatasetError> {
        let shape = |e| self.shape(e);
        let get = |k: &str| json_shape::member(f, path, k).map_err(shape);
        let field = |k: &str| format!("{path}.{k}");
        let subject = json_shape::index(get("subject")?, &field("subject")).map_err(shape)?;
        if subject >= n_subjects {
            return Err(self.invalid(
                &field("subject"),
                format!("index {subject} out of range: the dataset has {n_subjects} subjects"),
            ));
        }
        let split_name = json_shape::string(get("split")?, &field("split")).map_err(shape)?;
        let split = split_name
            .parse::<Split>()
            .map_err(|e| self.invalid(&field("split"), e))?;
        let time = json_shape::number(get("time")?, &field("time")).map_err(shape)?;
        let relpath = |k: &str| -> Result<PathBuf, DatasetError> {
            let s = json_shape::string(get(k)?, &field(k)).map_err(shape)?;
            let p = PathBuf::from(s);
            let escapes = p
                .components()
                .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir));
            if s.is_empty() || escapes {
                return Err(self.invalid(
                    &field(k),
                    format!("expected a relative path inside the dataset, found {s:?}"),
                ));
            }
            Ok(p)
        };
        let image = relpath("image")?;
        let mask = relpath("mask")?;
        let optional = |k: &str| match f.get(k) {
            None | Some(Value::Null) => Ok(None),
            Some(_) => relpath(k).map(Some),
        };
        let segmentation = optional("segmentation")?;
        let depth = optional("depth")?;
        Ok(Frame {
            subject,
            split,
            time,
            image,
            mask,
            segmentation,
            depth,
            camera: camera_field(get("camera")?, &field("camera"), &self.file)?,
            params: FrameParams::from_json(get("params")?, &field("params")).map_err(shape)?,
        })
    }
}
