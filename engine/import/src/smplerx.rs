//! SMPLer-X (caizhongang/SMPLer-X, `main/inference.py`): per detected person per frame,
//! `smplx/{frame:05}_{bbox_id}.npz` (`global_orient` (1, 3) in the OpenCV camera frame,
//! `body_pose` (21, 3), `left_hand_pose`/`right_hand_pose` (15, 3) relative to the model's
//! mean hand, `jaw_pose`, `leye_pose`, `reye_pose` (1, 3), `betas` (1, 10), `expression`
//! (1, 10), `transl` (1, 3) in metres) and `meta/{frame:05}_{bbox_id}.json` (`focal`,
//! `princpt`, `bbox`). Frame numbers start at 1 and match the demo's `%06d.jpg` frames.
//!
//! SMPLer-X's camera is a virtual one per crop (focal 5000/192 x the box width, centred on
//! the box), so a person sits tens of metres away. The import replaces it with one real
//! camera for the whole video (`--focal`, default [`DEFAULT_FOCAL_OF_LONGER_SIDE`] x the
//! longer image side, principal point at the image centre, at the world origin) and
//! re-solves each frame's translation so that the 55 joints project, in least squares,
//! where SMPLer-X's camera put them ([`solve_translation`]). Rotations are kept: the world
//! is the camera frame (y down), as SMPLer-X's is.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};

use super::{
    ImportError, ImportOptions, Skipped, Source, SourceFrame, body::solve, load_model, mask_for,
};
use talkin_data::array::Dim;
use talkin_data::npz::Npz;
use talkin_data::smplx_model::SmplxModel;
use talkin_human::body::{FrameParams, N_HAND_JOINTS, N_JOINTS, Skeleton};

/// The default focal length as a fraction of the longer image side: a phone's main camera
/// (about 26 mm equivalent on a 36 mm wide frame).
pub const DEFAULT_FOCAL_OF_LONGER_SIDE: f64 = 26.0 / 36.0;

/// One person's files in one frame.
struct Detection {
    npz: PathBuf,
    meta: PathBuf,
    area: f64,
}

/// The model file, the frames and the masks SMPLer-X's results need beside them.
fn required_inputs(opts: &ImportOptions) -> Result<(SmplxModel, &Path), ImportError> {
    let model = load_model(opts)?.ok_or_else(|| {
        ImportError::Usage(
            "smplerx needs --body-model SMPLX_NEUTRAL.npz: the rest joints come from its betas and its hands are relative to the model's mean hand".into(),
        )
    })?;
    let images_dir = opts.images.as_ref().ok_or_else(|| {
        ImportError::Usage("smplerx needs --images DIR: the %06d.jpg frames SMPLer-X ran on".into())
    })?;
    if opts.masks.is_none() {
        return Err(ImportError::Usage(
            "smplerx needs --masks DIR: SMPLer-X writes no masks; give one 8-bit PNG per frame from a matting tool (same stem as the frame)".into(),
        ));
    }
    Ok((model, images_dir))
}

pub fn read(opts: &ImportOptions) -> Result<Source, ImportError> {
    let (model, images_dir) = required_inputs(opts)?;
    let smplx_dir = opts.src.join("smplx");
    let meta_dir = opts.src.join("meta");
    for d in [&smplx_dir, &meta_dir] {
        if !d.is_dir() {
            return Err(ImportError::file(
                d,
                "missing: not a SMPLer-X results folder (smplx/ and meta/)",
            ));
        }
    }
    let detections = detections(&smplx_dir, &meta_dir)?;
    let images = numbered_images(images_dir, &detections)?;
    let fps = opts.fps();
    let (raws, skipped) = detected_frames(&model, images, &detections)?;
    if raws.is_empty() {
        return Err(ImportError::file(&smplx_dir, "no frame has a detection"));
    }
    // One skeleton: the model's joints for the mean betas.
    let mean_betas: Vec<f64> = (0..10)
        .map(|c| raws.iter().map(|r| r.3.betas[c]).sum::<f64>() / raws.len() as f64)
        .collect();
    let skeleton = model.skeleton(&mean_betas)?;
    let (w, h) = image_size(&raws[0].2)?;
    let f = opts
        .focal
        .unwrap_or(DEFAULT_FOCAL_OF_LONGER_SIDE * w.max(h) as f64);
    let k = [
        [f, 0.0, w as f64 / 2.0 - 0.5],
        [0.0, f, h as f64 / 2.0 - 0.5],
        [0.0, 0.0, 1.0],
    ];
    let identity = std::array::from_fn(|r| std::array::from_fn(|c| f64::from(r == c)));
    let mut frames = Vec::with_capacity(raws.len());
    let mut worst = 0.0f64;
    for (n, stem, image, raw) in raws {
        let size = image_size(&image)?;
        if size != (w, h) {
            return Err(ImportError::file(
                &image,
                format!(
                    "is {}x{}, the first frame {w}x{h}: frames must share a size",
                    size.0, size.1
                ),
            ));
        }
        let (params, rms) = in_one_camera(&skeleton, &k, &raw);
        worst = worst.max(rms);
        let mask = mask_for(opts, &stem, None)?;
        frames.push(SourceFrame {
            name: stem,
            time: (n.saturating_sub(1)) as f64 / fps,
            split: None,
            image,
            mask,
            intrinsics: k,
            extrinsics: identity,
            distortion: None,
            params,
        });
    }
    let notes = vec![
        format!(
            "one camera for the video: focal {f:.1} px{} at the image centre, at the world origin (the world is SMPLer-X's camera frame: y down, z forward); translations re-solved, worst RMS reprojection change {worst:.2} px",
            if opts.focal.is_some() {
                ""
            } else {
                " (default: 0.72 x the longer side; give --focal)"
            }
        ),
        "hand poses: the model's hands_mean added (SMPLer-X's are relative to it)".into(),
    ];
    Ok(Source {
        rest_joints: skeleton.rest_joints,
        body_shape: format!(
            "{} with the mean of SMPLer-X's betas over {} frames",
            model.file().display(),
            frames.len()
        ),
        frames,
        skipped,
        notes,
    })
}

/// A numbered frame with its detection: number, stem, image file, what SMPLer-X fitted.
type DetectedFrame = (u64, String, PathBuf, Raw);

/// Each numbered frame's detection read, in order; the frames without one are skipped.
fn detected_frames(
    model: &SmplxModel,
    images: Vec<(u64, String, PathBuf)>,
    detections: &BTreeMap<u64, Detection>,
) -> Result<(Vec<DetectedFrame>, Vec<Skipped>), ImportError> {
    let mut skipped = Vec::new();
    let mut raws = Vec::new();
    for (n, stem, image) in images {
        let Some(d) = detections.get(&n) else {
            skipped.push(Skipped {
                frame: stem,
                reason: "SMPLer-X detected no person (no smplx/ file)".into(),
            });
            continue;
        };
        let raw = read_detection(model, d)?;
        raws.push((n, stem, image, raw));
    }
    Ok((raws, skipped))
}

/// A detection's parameters in the video's one camera `k` with the shared `skeleton`:
/// the translation re-solved so that the joints land where SMPLer-X's own camera put
/// them (its body, its betas); returns them and the RMS reprojection change in pixels.
fn in_one_camera(skeleton: &Skeleton, k: &[[f64; 3]; 3], raw: &Raw) -> (FrameParams, f64) {
    let own = Skeleton {
        rest_joints: raw.rest_joints,
    }
    .pose(&raw.params)
    .joints();
    let targets: Vec<DVec2> = own.iter().map(|p| project(&raw.k, *p)).collect();
    let mut params = raw.params.clone();
    params.transl = DVec3::ZERO;
    let at_zero = skeleton.pose(&params).joints();
    let f = k[0][0];
    let (t, rms) = solve_translation(k, &at_zero, &targets, raw.params.transl * f / raw.k[0][0]);
    params.transl = t;
    (params, rms)
}

/// The numbered frames in `images_dir` (`%06d.jpg`), sorted; every detection must have
/// its frame.
fn numbered_images(
    images_dir: &Path,
    detections: &BTreeMap<u64, Detection>,
) -> Result<Vec<(u64, String, PathBuf)>, ImportError> {
    let mut images: Vec<(u64, String, PathBuf)> = super::images_by_stem(images_dir)?
        .into_iter()
        .filter_map(|(stem, path)| stem.parse::<u64>().ok().map(|n| (n, stem, path)))
        .collect();
    images.sort();
    if images.is_empty() {
        return Err(ImportError::file(
            images_dir,
            "holds no numbered frames (%06d.jpg)",
        ));
    }
    let numbers: std::collections::HashSet<u64> = images.iter().map(|i| i.0).collect();
    if let Some((n, d)) = detections.iter().find(|(n, _)| !numbers.contains(n)) {
        return Err(ImportError::file(
            &images_dir.join(format!("{n:06}.jpg")),
            format!(
                "missing: {} has a detection for frame {n} but --images has no such frame",
                d.npz.display()
            ),
        ));
    }
    Ok(images)
}

/// The largest detection of every frame (as SMPLer-X's own render.py picks it).
fn detections(smplx_dir: &Path, meta_dir: &Path) -> Result<BTreeMap<u64, Detection>, ImportError> {
    let mut out: BTreeMap<u64, Detection> = BTreeMap::new();
    for entry in std::fs::read_dir(smplx_dir).map_err(ImportError::io(smplx_dir))? {
        let path = entry.map_err(ImportError::io(smplx_dir))?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        let Some(stem) = name.strip_suffix(".npz") else {
            continue;
        };
        let Some((frame, id)) = stem.split_once('_') else {
            continue;
        };
        let (Ok(frame), Ok(_)) = (frame.parse::<u64>(), id.parse::<u64>()) else {
            continue;
        };
        let meta = meta_dir.join(format!("{stem}.json"));
        let doc = read_meta(&meta)?;
        let bbox = super::error::json_numbers(&doc, &meta, "", "bbox", &[4])?;
        let area = bbox[2] * bbox[3];
        if out.get(&frame).is_none_or(|d| area > d.area) {
            out.insert(
                frame,
                Detection {
                    npz: path,
                    meta,
                    area,
                },
            );
        }
    }
    Ok(out)
}

fn read_meta(meta: &Path) -> Result<serde_json::Value, ImportError> {
    if !meta.is_file() {
        return Err(ImportError::file(
            meta,
            "missing: every smplx/*.npz needs its meta/*.json (focal, princpt, bbox)",
        ));
    }
    let text = std::fs::read_to_string(meta).map_err(ImportError::io(meta))?;
    serde_json::from_str(&text)
        .map_err(|e| ImportError::file(meta, format!("malformed JSON at line {}: {e}", e.line())))
}

struct Raw {
    params: FrameParams,
    betas: Vec<f64>,
    rest_joints: [DVec3; N_JOINTS],
    /// SMPLer-X's virtual camera, OpenCV pixels.
    k: [[f64; 3]; 3],
}

fn read_detection(model: &SmplxModel, d: &Detection) -> Result<Raw, ImportError> {
    let mut npz = Npz::open(&d.npz)?;
    let mut read = |key: &str, rows: usize, cols: usize| -> Result<Vec<f64>, ImportError> {
        let dims = [Dim::Is(rows), Dim::Is(cols)];
        Ok(super::error::npz_f64(&mut npz, key, &dims)?.0)
    };
    let v = |x: &[f64], j: usize| DVec3::new(x[3 * j], x[3 * j + 1], x[3 * j + 2]);
    let global = read("global_orient", 1, 3)?;
    let body = read("body_pose", 21, 3)?;
    let lhand = read("left_hand_pose", N_HAND_JOINTS, 3)?;
    let rhand = read("right_hand_pose", N_HAND_JOINTS, 3)?;
    let jaw = read("jaw_pose", 1, 3)?;
    let leye = read("leye_pose", 1, 3)?;
    let reye = read("reye_pose", 1, 3)?;
    let betas = read("betas", 1, 10)?;
    let expression = read("expression", 1, 10)?;
    let transl = read("transl", 1, 3)?;
    let (meanl, meanr) = model.hands_mean();
    let params = FrameParams {
        global_orient: v(&global, 0),
        body_pose: std::array::from_fn(|j| v(&body, j)),
        jaw_pose: v(&jaw, 0),
        leye_pose: v(&leye, 0),
        reye_pose: v(&reye, 0),
        left_hand_pose: std::array::from_fn(|j| v(&lhand, j) + meanl[j]),
        right_hand_pose: std::array::from_fn(|j| v(&rhand, j) + meanr[j]),
        expression: std::array::from_fn(|c| expression[c]),
        transl: v(&transl, 0),
    };
    let doc = read_meta(&d.meta)?;
    let focal = super::error::json_numbers(&doc, &d.meta, "", "focal", &[2])?;
    let princpt = super::error::json_numbers(&doc, &d.meta, "", "princpt", &[2])?;
    if focal.iter().any(|&f| f <= 0.0) {
        return Err(ImportError::field(
            &d.meta,
            ".focal",
            format!("expected 2 positive numbers, found {focal:?}"),
        ));
    }
    let rest_joints = model.rest_joints_with_expression(&betas, &expression)?;
    Ok(Raw {
        params,
        betas,
        rest_joints,
        k: [
            [focal[0], 0.0, princpt[0]],
            [0.0, focal[1], princpt[1]],
            [0.0, 0.0, 1.0],
        ],
    })
}

fn image_size(path: &Path) -> Result<(u32, u32), ImportError> {
    if !path.is_file() {
        return Err(ImportError::file(path, "missing"));
    }
    image::image_dimensions(path)
        .map_err(|e| ImportError::file(path, format!("cannot read the image size: {e}")))
}

/// OpenCV projection of a camera-frame point.
fn project(k: &[[f64; 3]; 3], p: DVec3) -> DVec2 {
    DVec2::new(
        k[0][0] * p.x / p.z + k[0][1] * p.y / p.z + k[0][2],
        k[1][1] * p.y / p.z + k[1][2],
    )
}

/// The translation `t` that makes the camera-frame points `p + t` project under `k` onto
/// `targets` in least squares, and the RMS reprojection error in pixels. It starts from
/// the linear (algebraic) solution, `fx (X + tx) - (u - cx)(Z + tz) = 0` and its y twin for
/// every point, which is exact when the targets are exact, then refines the reprojection
/// error by Gauss-Newton. `guess` is used if the linear system is singular.
pub fn solve_translation(
    k: &[[f64; 3]; 3],
    points: &[DVec3],
    targets: &[DVec2],
    guess: DVec3,
) -> (DVec3, f64) {
    let (fx, fy, cx, cy) = (k[0][0], k[1][1], k[0][2], k[1][2]);
    let mut ata = vec![vec![0.0; 3]; 3];
    let mut atb = vec![0.0; 3];
    let mut add = |row: [f64; 3], rhs: f64| {
        for r in 0..3 {
            atb[r] += row[r] * rhs;
            for c in 0..3 {
                ata[r][c] += row[r] * row[c];
            }
        }
    };
    for (p, u) in points.iter().zip(targets) {
        let (du, dv) = (u.x - cx, u.y - cy);
        add([fx, 0.0, -du], du * p.z - fx * p.x);
        add([0.0, fy, -dv], dv * p.z - fy * p.y);
    }
    let mut t = solve(ata, atb).map_or(guess, |x| DVec3::new(x[0], x[1], x[2]));
    let k0 = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]];
    for _ in 0..10 {
        let mut ata = vec![vec![0.0; 3]; 3];
        let mut atb = vec![0.0; 3];
        for (p, u) in points.iter().zip(targets) {
            let q = *p + t;
            if q.z <= 1e-9 {
                continue;
            }
            let r = project(&k0, q) - *u;
            let jx = [fx / q.z, 0.0, -fx * q.x / (q.z * q.z)];
            let jy = [0.0, fy / q.z, -fy * q.y / (q.z * q.z)];
            for (jrow, res) in [(jx, r.x), (jy, r.y)] {
                for a in 0..3 {
                    atb[a] -= jrow[a] * res;
                    for b in 0..3 {
                        ata[a][b] += jrow[a] * jrow[b];
                    }
                }
            }
        }
        match solve(ata, atb) {
            Some(step) => {
                let step = DVec3::new(step[0], step[1], step[2]);
                t += step;
                if step.length() < 1e-12 {
                    break;
                }
            }
            None => break,
        }
    }
    let sq: f64 = points
        .iter()
        .zip(targets)
        .map(|(p, u)| (project(&k0, *p + t) - *u).length_squared())
        .sum();
    (t, (sq / points.len().max(1) as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn translation_is_recovered_from_exact_projections() {
        let k = [[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]];
        let points: Vec<DVec3> = (0..20)
            .map(|i| {
                DVec3::new(
                    (i % 5) as f64 * 0.1,
                    (i / 5) as f64 * 0.2 - 0.3,
                    (i % 3) as f64 * 0.05,
                )
            })
            .collect();
        let t = DVec3::new(0.3, -0.2, 4.0);
        let targets: Vec<DVec2> = points.iter().map(|p| project(&k, *p + t)).collect();
        let (got, rms) = solve_translation(&k, &points, &targets, DVec3::new(0.0, 0.0, 1.0));
        assert!((got - t).length() < 1e-9, "{got}");
        assert!(rms < 1e-9);
    }
}
