//! HumanNeRF (chungyiweng/humannerf), both of its layouts:
//!
//! - the wild-video input: `images/`, `masks/` and `metadata.json`, an object keyed by
//!   frame name with SMPL `poses` (72), `betas` (10), `cam_intrinsics` (3x3) and
//!   `cam_extrinsics` (4x4, world to camera, OpenCV). There is no translation: the body is
//!   SMPL's with `transl = 0`, and the extrinsics place it. Rest joints need the model file.
//! - the prepared layout its scripts write (`tools/prepare_wild`, `tools/prepare_zju_mocap`):
//!   `images/*.png`, `masks/*.png`, `cameras.pkl` (per frame `intrinsics`, `extrinsics`,
//!   optional `distortions`) and `mesh_infos.pkl` (per frame `Rh`, `Th`, `poses` (72) with
//!   the root in `Rh`, `tpose_joints` (24, 3)). A body point `x_b` of SMPL(`poses`) on the
//!   given `tpose_joints` lies in the world at `R(Rh) x_b + Th` (`apply_global_tfm_to_camera`);
//!   the wild script centres the joints on the pelvis, ZJU's does not, and both are read
//!   with the same formula. The frames are the sorted `images/*.png`, as HumanNeRF lists them.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::error::{json_numbers, pickle_array};
use super::{
    ImportError, ImportOptions, MaskFile, Source, SourceFrame, body, load_model, mask_for, mat3,
    mat4, params_from_smpl,
};
use crate::pickle::{Value, read_pickle};
use talkin_data::array::Dim;
use talkin_human::body::{
    FrameParams, N_BODY_JOINTS, N_JOINTS, axis_angle_from_rotation, rotation_from_axis_angle,
};

/// Reads whichever of the two layouts `opts.src` holds.
pub fn read(opts: &ImportOptions) -> Result<Source, ImportError> {
    let src = &opts.src;
    if src.join("cameras.pkl").exists() || src.join("mesh_infos.pkl").exists() {
        read_prepared(opts)
    } else if src.join("metadata.json").exists() {
        read_wild(opts)
    } else {
        Err(ImportError::file(
            src,
            "not a HumanNeRF folder: expected cameras.pkl and mesh_infos.pkl (prepared) or metadata.json (wild-video input)",
        ))
    }
}

fn frame_images(
    opts: &ImportOptions,
) -> Result<std::collections::BTreeMap<String, std::path::PathBuf>, ImportError> {
    let dir = opts
        .images
        .clone()
        .unwrap_or_else(|| opts.src.join("images"));
    if !dir.is_dir() {
        return Err(ImportError::file(&dir, "missing: the frames' folder"));
    }
    let images = super::images_by_stem(&dir)?;
    if images.is_empty() {
        return Err(ImportError::file(&dir, "holds no .png or .jpg frames"));
    }
    Ok(images)
}

fn default_mask(opts: &ImportOptions, stem: &str) -> Option<MaskFile> {
    Some(MaskFile::Image(
        opts.src.join("masks").join(format!("{stem}.png")),
    ))
}

fn v3(x: &[f64]) -> DVec3 {
    DVec3::new(x[0], x[1], x[2])
}

/// What both layouts give of a frame besides its body: its name, image and camera.
struct FrameCamera {
    stem: String,
    image: std::path::PathBuf,
    /// Intrinsics, 3x3 row-major.
    k: Vec<f64>,
    /// World to camera, 4x4 row-major.
    e: Vec<f64>,
    /// OpenCV k1, k2, p1, p2, k3, where the layout has them.
    d: Option<Vec<f64>>,
}

/// Frame `index` of the sequence: `camera` with its mask (`--masks` or
/// `masks/<stem>.png`), its time at `--fps` and its body `params`.
fn source_frame(
    opts: &ImportOptions,
    index: usize,
    camera: FrameCamera,
    params: FrameParams,
) -> Result<SourceFrame, ImportError> {
    let mask = mask_for(opts, &camera.stem, default_mask(opts, &camera.stem))?;
    Ok(SourceFrame {
        name: camera.stem,
        time: index as f64 / opts.fps(),
        split: None,
        image: camera.image,
        mask,
        intrinsics: mat3(&camera.k),
        extrinsics: rigid(&mat4(&camera.e)),
        distortion: camera.d.map(|d| [d[0], d[1], d[2], d[3], d[4]]),
        params,
    })
}

/// One frame of the prepared layout, as its pickles hold it.
struct Raw {
    camera: FrameCamera,
    rh: DVec3,
    th: DVec3,
    poses: Vec<f64>,
    tpose: Vec<f64>,
}

/// Every frame's camera and body from `cameras.pkl` and `mesh_infos.pkl`.
fn read_prepared_frames(
    opts: &ImportOptions,
    (cam_file, cameras): (&Path, &Value),
    (mesh_file, meshes): (&Path, &Value),
) -> Result<Vec<Raw>, ImportError> {
    let images = frame_images(opts)?;
    let mut raws = Vec::with_capacity(images.len());
    for (stem, image) in &images {
        let cam = lookup(
            cameras,
            cam_file,
            stem,
            "{'intrinsics': (3, 3), 'extrinsics': (4, 4)}",
        )?;
        let mesh = lookup(
            meshes,
            mesh_file,
            stem,
            "{'Rh': (3,), 'Th': (3,), 'poses': (72,), 'tpose_joints': (24, 3)}",
        )?;
        let d = match cam.get("distortions") {
            None | Some(Value::None) => None,
            Some(_) => Some(pickle_array(
                cam,
                cam_file,
                stem,
                "distortions",
                &[Dim::Is(5)],
            )?),
        };
        raws.push(Raw {
            camera: FrameCamera {
                stem: stem.clone(),
                image: image.clone(),
                k: pickle_array(cam, cam_file, stem, "intrinsics", &[Dim::Is(3), Dim::Is(3)])?,
                e: pickle_array(cam, cam_file, stem, "extrinsics", &[Dim::Is(4), Dim::Is(4)])?,
                d,
            },
            rh: v3(&pickle_array(mesh, mesh_file, stem, "Rh", &[Dim::Is(3)])?),
            th: v3(&pickle_array(mesh, mesh_file, stem, "Th", &[Dim::Is(3)])?),
            poses: pickle_array(mesh, mesh_file, stem, "poses", &[Dim::Is(72)])?,
            tpose: pickle_array(
                mesh,
                mesh_file,
                stem,
                "tpose_joints",
                &[Dim::Is(24), Dim::Is(3)],
            )?,
        });
    }
    Ok(raws)
}

fn read_prepared(opts: &ImportOptions) -> Result<Source, ImportError> {
    let cam_file = opts.src.join("cameras.pkl");
    let mesh_file = opts.src.join("mesh_infos.pkl");
    let cameras = read_pickle(&cam_file)?;
    let meshes = read_pickle(&mesh_file)?;
    for (file, v) in [(&cam_file, &cameras), (&mesh_file, &meshes)] {
        if v.as_dict().is_none() {
            return Err(ImportError::file(
                file,
                format!("expected a dict keyed by frame name, found a {}", v.kind()),
            ));
        }
    }
    let raws = read_prepared_frames(opts, (&cam_file, &cameras), (&mesh_file, &meshes))?;
    // One skeleton per subject: the mean of the frames' T-pose joints (one body shape in
    // practice; the wild script recomputes them per frame).
    let body: [DVec3; N_BODY_JOINTS] = std::array::from_fn(|j| {
        raws.iter().map(|r| v3(&r.tpose[3 * j..])).sum::<DVec3>() / raws.len() as f64
    });
    let mut notes = Vec::new();
    let (rest_joints, body_shape) = match load_model(opts)? {
        Some(model) => {
            let (rest, betas, rms) = body::fit_body_joints(&model, &body)?;
            (
                rest,
                format!(
                    "body joints 0..21 from mesh_infos.pkl tpose_joints; jaw, eyes and fingers from {} with betas fitted to them (RMS {:.1} mm, betas {:?})",
                    model.file().display(),
                    rms * 1e3,
                    betas.iter().map(|b| (b * 1e3).round() / 1e3).collect::<Vec<_>>()
                ),
            )
        }
        None => (
            body::complete_from_body(&body),
            "body joints 0..21 from mesh_infos.pkl tpose_joints; jaw, eyes and fingers from the built-in template scaled to the subject's bones (give --body-model to fit them instead)".to_string(),
        ),
    };
    notes
        .push("SMPL poses: joints 0..21 as given; hands, jaw, eyes and expression are zero".into());
    let j0 = rest_joints[0];
    let mut frames = Vec::with_capacity(raws.len());
    for (i, r) in raws.into_iter().enumerate() {
        let r_h = rotation_from_axis_angle(r.rh);
        let mut params = params_from_smpl(&r.poses, DVec3::ZERO);
        params.global_orient =
            axis_angle_from_rotation(r_h * rotation_from_axis_angle(params.global_orient));
        // SMPL turns the root about the frame's rest pelvis J0f; the world pelvis is then
        // R(Rh) J0f + Th, which the dataset writes as J0 + transl.
        let j0f = v3(&r.tpose[0..3]);
        params.transl = r_h * j0f + r.th - j0;
        frames.push(source_frame(opts, i, r.camera, params)?);
    }
    check_masks_exist(&frames)?;
    Ok(Source {
        rest_joints,
        body_shape,
        frames,
        skipped: Vec::new(),
        notes,
    })
}

fn lookup<'a>(
    dict: &'a Value,
    file: &Path,
    stem: &str,
    expected: &str,
) -> Result<&'a Value, ImportError> {
    let v = dict.get(stem).ok_or_else(|| {
        ImportError::field(
            file,
            format!("['{stem}']"),
            format!("missing: frame {stem} has an image but no entry here (expected {expected})"),
        )
    })?;
    if v.as_dict().is_none() {
        return Err(ImportError::field(
            file,
            format!("['{stem}']"),
            format!("expected a dict {expected}, found a {}", v.kind()),
        ));
    }
    Ok(v)
}

/// The extrinsics as stored, with float32 rounding of the rotation re-orthonormalised
/// (the dataset checks rotations to 1e-4; fitters store f4).
fn rigid(e: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let col = |c: usize| DVec3::new(e[0][c], e[1][c], e[2][c]);
    let m = DMat3::from_cols(col(0), col(1), col(2));
    let err = (m.transpose() * m - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, x| a.max(x.abs()));
    if err > 1e-3 || m.determinant() <= 0.0 {
        // Not a rotation: leave it for the camera check to reject with its message.
        return *e;
    }
    let r = rotation_from_axis_angle(axis_angle_from_rotation(m));
    let mut out = *e;
    for row in 0..3 {
        for c in 0..3 {
            out[row][c] = r.col(c)[row];
        }
    }
    out
}

fn check_masks_exist(frames: &[SourceFrame]) -> Result<(), ImportError> {
    for f in frames {
        let path = match &f.mask {
            MaskFile::Image(p) | MaskFile::Npy(p) => p,
        };
        if !path.is_file() {
            return Err(ImportError::file(
                path,
                format!(
                    "missing: the mask of frame {} (masks are required, one per frame; see --masks)",
                    f.name
                ),
            ));
        }
    }
    Ok(())
}

fn read_wild(opts: &ImportOptions) -> Result<Source, ImportError> {
    let file = opts.src.join("metadata.json");
    let text = std::fs::read_to_string(&file).map_err(ImportError::io(&file))?;
    let doc: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
        ImportError::file(&file, format!("malformed JSON at line {}: {e}", e.line()))
    })?;
    let entries = doc
        .as_object()
        .ok_or_else(|| ImportError::file(&file, "expected an object keyed by frame name"))?;
    let model = load_model(opts)?.ok_or_else(|| {
        ImportError::Usage(
            "humannerf's metadata.json gives betas, not joints: --body-model SMPLX_NEUTRAL.npz is required to build the rest joints".into(),
        )
    })?;
    let images = frame_images(opts)?;
    struct Raw {
        camera: FrameCamera,
        poses: Vec<f64>,
        betas: Vec<f64>,
    }
    let mut raws = Vec::new();
    for (stem, image) in &images {
        let entry = entries.get(stem).ok_or_else(|| {
            ImportError::field(
                &file,
                stem,
                "missing: the frame has an image but no entry (expected poses (72,), betas (10,), cam_intrinsics (3, 3), cam_extrinsics (4, 4))",
            )
        })?;
        raws.push(Raw {
            poses: json_numbers(entry, &file, stem, "poses", &[72])?,
            betas: json_numbers(entry, &file, stem, "betas", &[10])?,
            camera: FrameCamera {
                stem: stem.clone(),
                image: image.clone(),
                k: json_numbers(entry, &file, stem, "cam_intrinsics", &[3, 3])?,
                e: json_numbers(entry, &file, stem, "cam_extrinsics", &[4, 4])?,
                d: None,
            },
        });
    }
    let mean_betas: Vec<f64> = (0..10)
        .map(|c| raws.iter().map(|r| r.betas[c]).sum::<f64>() / raws.len() as f64)
        .collect();
    let rest_joints: [DVec3; N_JOINTS] = model.rest_joints(&mean_betas)?;
    let j0 = rest_joints[0];
    let mut frames = Vec::new();
    for (i, r) in raws.into_iter().enumerate() {
        // SMPL with transl = 0 puts the pelvis at the frame's own J0(betas).
        let j0f = model.rest_joints(&r.betas)?[0];
        let params = params_from_smpl(&r.poses, j0f - j0);
        frames.push(source_frame(opts, i, r.camera, params)?);
    }
    check_masks_exist(&frames)?;
    Ok(Source {
        rest_joints,
        body_shape: format!(
            "{} with the mean of metadata.json's betas (SMPL betas read as SMPL-X's first 10)",
            model.file().display()
        ),
        frames,
        skipped: Vec::new(),
        notes: vec![
            "SMPL poses: joints 0..21 as given; hands, jaw, eyes and expression are zero".into(),
        ],
    })
}
