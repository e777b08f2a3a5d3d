//! Test fixtures: a plausible T-pose skeleton and a tiny hand-made dataset, independent of
//! the synthetic generator so that loader tests do not depend on it; the fitters' layouts
//! (`layouts`), camera-like frames (`capture`), running the binary (`cli`) and headless Chromium
//! (`browser`).
#![allow(dead_code)]

pub mod browser;
pub mod capture;
pub mod cli;
pub mod layouts;

use std::path::Path;

use glam::DVec3;
use talkin::data::dataset::{Dataset, Frame, Split, Subject};
use talkin::human::body::{FrameParams, N_JOINTS, PARENTS, Skeleton};
use talkin::human::camera::Camera;

/// A 1.7 m adult-ish T-pose skeleton in SMPL-X conventions (y up, facing +z, +x left).
pub fn t_pose_skeleton() -> Skeleton {
    let mut offset = [DVec3::ZERO; N_JOINTS];
    let v = DVec3::new;
    offset[0] = v(0.0, 0.95, 0.0);
    for side in [1.0, -1.0] {
        let (hip, knee, ankle, foot, collar, shoulder, elbow, wrist) = if side > 0.0 {
            (1, 4, 7, 10, 13, 16, 18, 20)
        } else {
            (2, 5, 8, 11, 14, 17, 19, 21)
        };
        offset[hip] = v(0.09 * side, -0.08, 0.0);
        offset[knee] = v(0.0, -0.4, 0.0);
        offset[ankle] = v(0.0, -0.4, 0.0);
        offset[foot] = v(0.0, -0.05, 0.12);
        offset[collar] = v(0.07 * side, 0.15, 0.0);
        offset[shoulder] = v(0.12 * side, 0.02, 0.0);
        offset[elbow] = v(0.26 * side, 0.0, 0.0);
        offset[wrist] = v(0.25 * side, 0.0, 0.0);
        let first = if side > 0.0 { 25 } else { 40 };
        // index, middle, pinky, ring, thumb knuckles relative to the wrist.
        let knuckles = [
            v(0.09, 0.0, 0.03),
            v(0.095, 0.0, 0.01),
            v(0.08, 0.0, -0.03),
            v(0.09, 0.0, -0.01),
            v(0.03, -0.01, 0.04),
        ];
        for (f, k) in knuckles.iter().enumerate() {
            offset[first + 3 * f] = v(k.x * side, k.y, k.z);
            offset[first + 3 * f + 1] = v(0.03 * side, 0.0, 0.0);
            offset[first + 3 * f + 2] = v(0.025 * side, 0.0, 0.0);
        }
    }
    offset[3] = v(0.0, 0.1, 0.0);
    offset[6] = v(0.0, 0.13, 0.0);
    offset[9] = v(0.0, 0.05, 0.0);
    offset[12] = v(0.0, 0.22, 0.0);
    offset[15] = v(0.0, 0.1, 0.0);
    offset[22] = v(0.0, -0.02, 0.05);
    offset[23] = v(0.03, 0.05, 0.08);
    offset[24] = v(-0.03, 0.05, 0.08);
    let mut rest = [DVec3::ZERO; N_JOINTS];
    for j in 0..N_JOINTS {
        rest[j] = offset[j]
            + if j == 0 {
                DVec3::ZERO
            } else {
                rest[PARENTS[j] as usize]
            };
    }
    Skeleton { rest_joints: rest }
}

/// A frontal camera 3 m in front of the subject.
pub fn frontal_camera(width: u32, height: u32) -> Camera {
    Camera::look_at(
        width,
        height,
        1.2 * height as f64,
        DVec3::new(0.0, 1.1, 3.0),
        DVec3::new(0.0, 1.1, 0.0),
        DVec3::Y,
    )
    .expect("a valid camera")
}

/// Writes a 2-frame dataset of 24x32 images into `dir`: a grey person-shaped block with
/// segmentation labels and an exact mask.
pub fn write_tiny_dataset(dir: &Path) -> Dataset {
    let (w, h) = (24, 32);
    for sub in ["images", "masks", "segmentation"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    let mut frames = Vec::new();
    for i in 0..2 {
        let mut rgb = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
        let mut mask = image::GrayImage::new(w, h);
        let mut seg = image::GrayImage::new(w, h);
        for y in 4..30 {
            for x in 8..16 {
                let label = if y < 9 { 4 } else { 1 };
                rgb.put_pixel(x, y, image::Rgb([120, 100 + 10 * i as u8, 90]));
                mask.put_pixel(x, y, image::Luma([255]));
                seg.put_pixel(x, y, image::Luma([label]));
            }
        }
        for (x, y) in [(5, 14), (18, 14)] {
            seg.put_pixel(x, y, image::Luma([3]));
            mask.put_pixel(x, y, image::Luma([255]));
        }
        let name = format!("{i:05}.png");
        rgb.save(dir.join("images").join(&name)).unwrap();
        mask.save(dir.join("masks").join(&name)).unwrap();
        seg.save(dir.join("segmentation").join(&name)).unwrap();
        let mut params = FrameParams::default();
        params.jaw_pose.x = 0.1 * i as f64;
        params.expression[0] = 0.5;
        frames.push(Frame {
            subject: 0,
            split: if i == 0 {
                Split::Train
            } else {
                Split::TestSame
            },
            time: i as f64 / 25.0,
            image: format!("images/{name}").into(),
            mask: format!("masks/{name}").into(),
            segmentation: Some(format!("segmentation/{name}").into()),
            depth: None,
            camera: frontal_camera(w, h),
            params,
        });
    }
    let dataset = Dataset {
        root: dir.to_path_buf(),
        background: [1.0, 1.0, 1.0],
        matting: talkin_data::dataset::Matting::Matted,
        masks: Default::default(),
        subjects: vec![Subject {
            name: "tiny".into(),
            skeleton: t_pose_skeleton(),
        }],
        frames,
    };
    dataset.save_index().unwrap();
    dataset
}

/// A fresh empty directory under the target dir's tmp, unique per test name.
pub fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small synthetic scene generated into `target/tmp/<name>` and loaded: `identities`
/// subjects, 4 training frames each, `size` px high, seeded.
pub fn synthetic_scene(name: &str, identities: usize, size: u32, seed: u64) -> Dataset {
    let data = temp_dir(name);
    let cfg = talkin::synth::SynthConfig {
        identities,
        frames: 4,
        size,
        seed,
        motion: None,
        capture: None,
        framing: None,
    };
    talkin::synth::generate(&cfg, &data, &mut |_, _| {}).unwrap();
    Dataset::load(&data).unwrap()
}

/// Training options for tiny test runs: `steps` steps of 256 rays, no perceptual term,
/// grid updates every 4 steps on a 32-cell grid, seed 3.
pub fn small_train_opts(
    sampler: talkin::grids::SamplerKind,
    steps: usize,
) -> talkin::train::TrainOptions {
    talkin::train::TrainOptions {
        sampler,
        budget: talkin::train::Budget::Steps(steps),
        seed: 3,
        batch_rays: 256,
        patches: 0,
        occ_every: 4,
        grid_resolution: 32,
        ..talkin::train::TrainOptions::default()
    }
}

/// A 0-d text array, as numpy stores `np.array("smplx2020")`.
pub fn npz_text(s: &str) -> talkin::data::array::NdArray {
    use talkin::data::array::{ArrayData, NdArray};
    NdArray::new(vec![], ArrayData::Str(vec![s.into()])).unwrap()
}

/// A BEAT2 motion file as BEAT2's own files store it (SynTalker's example layout): f4
/// `poses` (`n` rows of 165) and 300 `betas`, f8 `expressions` and `trans`, text `model`
/// and `gender`, an int32 `mocap_frame_rate` of 30.
pub fn write_beat2(file: &Path, n: usize, poses: Vec<f32>) {
    use talkin::data::array::{ArrayData, NdArray};
    use talkin::data::npz::NpzWriter;
    let t: Vec<f64> = (0..n).flat_map(|i| [0.01 * i as f64, 1.29, 0.0]).collect();
    let mut w = NpzWriter::create(file).unwrap();
    w.array("betas", &NdArray::f32(&[300], vec![0.05; 300]).unwrap())
        .unwrap()
        .array("poses", &NdArray::f32(&[n, 165], poses).unwrap())
        .unwrap()
        .array(
            "expressions",
            &NdArray::f64(&[n, 100], vec![0.1; n * 100]).unwrap(),
        )
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], t).unwrap())
        .unwrap()
        .array("model", &npz_text("smplx2020"))
        .unwrap()
        .array("gender", &npz_text("neutral"))
        .unwrap()
        .array(
            "mocap_frame_rate",
            &NdArray::new(vec![], ArrayData::I32(vec![30])).unwrap(),
        )
        .unwrap();
    w.finish().unwrap();
}

/// The candidate mask the sampler gives a point: the joints of the grown capsules that
/// hold it.
pub fn candidate_mask(grown: &[talkin::grids::Capsule], p: glam::Vec3) -> u64 {
    grown
        .iter()
        .filter(|c| talkin::grids::intersect::signed_distance(p, c) <= 0.0)
        .fold(0u64, |m, c| m | 1 << c.bone)
}

/// `points` mapped to canonical space by `volume` with each point's candidate `masks`
/// and the frame's `conditions`, read back.
pub fn skin(
    volume: &talkin::nets::skinning::BlendWeightVolume,
    points: &[[f32; 3]],
    masks: &[u64],
    conditions: &talkin::nets::FrameConditions,
) -> Vec<glam::Vec3> {
    use burn::prelude::*;
    let device = Device::flex();
    let warp = volume
        .inverse_lbs(
            points,
            masks,
            &conditions.canonical_from_posed,
            &conditions.bone_capsules,
            &device,
        )
        .unwrap();
    let x = warp.x_canonical.try_to_vec_as::<f32>().unwrap();
    x.chunks_exact(3).map(glam::Vec3::from_slice).collect()
}

/// Copies the dataset `matted` to `to`, declared `"matting": "by_mask"`: its frames as
/// camera frames composited by their masks (what `import` writes).
pub fn copy_as_capture(matted: &Path, to: &Path) {
    copy_dir(matted, to);
    let doc = to.join("dataset.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&doc).unwrap()).unwrap();
    v["matting"] = "by_mask".into();
    std::fs::write(&doc, v.to_string()).unwrap();
}

/// Copies the directory `from` to `to` (removed first), recursively.
pub fn copy_dir(from: &Path, to: &Path) {
    let _ = std::fs::remove_dir_all(to);
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}
