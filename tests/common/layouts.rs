//! A dataset's frames written in each fitter's exact layout, as `talkin import` reads
//! them: SMPLer-X's demo output, HumanNeRF's prepared and wild-video inputs,
//! InstantAvatar's PeopleSnapshot. Poses, cameras and rest joints come from the dataset;
//! the pixels from a [`Clip`], so the same writers serve the clean scene and camera-like
//! frames (`super::capture`). A small SMPL-X model file of the real layout, whose
//! regressor reproduces the dataset's rest joints, stands in for the licensed one.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec2, DVec3};
use image::{GrayImage, RgbImage};
use talkin::data::array::{ArrayData, NdArray};
use talkin::data::dataset::{Dataset, Frame};
use talkin::data::npz::NpzWriter;
use talkin::human::body::{
    FrameParams, N_JOINTS, PARENTS, axis_angle_from_rotation, rotation_from_axis_angle,
};
use talkin::human::camera::Camera;
use talkin::import::pickle::{Value, write_protocol4};
use talkin::import::undistort;

/// One frame's pixels as a camera and a matting tool hand them over.
#[derive(Clone, Debug)]
pub struct FramePixels {
    /// The frame as decoded.
    pub rgb: RgbImage,
    /// The frame's JPEG file when the camera stored it as one (`rgb` is its decoding);
    /// layouts of `%06d.jpg` frames write these bytes as they are.
    pub jpeg: Option<Vec<u8>>,
    /// 255 = person; soft values are kept where the layout stores 8-bit masks.
    pub mask: GrayImage,
}

impl FramePixels {
    /// The frame as a JPEG file: its own bytes, or `rgb` encoded at quality 100, as near
    /// its pixels as JPEG goes (a level or so), so a clean frame stays clean.
    pub fn jpeg_bytes(&self) -> Vec<u8> {
        if let Some(bytes) = &self.jpeg {
            return bytes.clone();
        }
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 100)
            .encode_image(&self.rgb)
            .unwrap();
        bytes
    }
}

/// What a writer writes: subject 0 of `ds` (its rest joints), the frames to write (their
/// poses and cameras) and each frame's pixels.
pub struct Clip<'a> {
    pub ds: &'a Dataset,
    pub frames: Vec<Frame>,
    pub pixels: Vec<FramePixels>,
}

impl<'a> Clip<'a> {
    /// `frames` of `ds` with their own image and mask files.
    pub fn from_files(ds: &'a Dataset, frames: Vec<&Frame>) -> Clip<'a> {
        let pixels = frames
            .iter()
            .map(|f| FramePixels {
                rgb: image::open(ds.root.join(&f.image)).unwrap().to_rgb8(),
                jpeg: None,
                mask: image::open(ds.root.join(&f.mask)).unwrap().to_luma8(),
            })
            .collect();
        let frames = frames.into_iter().cloned().collect();
        Clip { ds, frames, pixels }
    }

    /// Every frame of subject 0, with its own files.
    pub fn subject0(ds: &'a Dataset) -> Clip<'a> {
        Clip::from_files(ds, ds.frames.iter().filter(|f| f.subject == 0).collect())
    }

    /// The same frames with other pixels, of the cameras' size.
    pub fn with_pixels(&self, pixels: Vec<FramePixels>) -> Clip<'a> {
        assert_eq!(pixels.len(), self.frames.len());
        for (f, px) in self.frames.iter().zip(&pixels) {
            let size = (f.camera.width, f.camera.height);
            assert_eq!(px.rgb.dimensions(), size, "pixels of the camera's size");
            assert_eq!(px.mask.dimensions(), size, "a mask of the camera's size");
        }
        Clip {
            ds: self.ds,
            frames: self.frames.clone(),
            pixels,
        }
    }

    pub fn rest(&self) -> [DVec3; N_JOINTS] {
        self.ds.subjects[0].skeleton.rest_joints
    }
}

/// K with OpenCV's pixel centres (integers), as the tools store it.
pub fn opencv_k(c: &Camera) -> [[f64; 3]; 3] {
    let mut k = c.intrinsics_rows();
    k[0][2] -= 0.5;
    k[1][2] -= 0.5;
    k
}

pub fn f32_array(shape: &[usize], v: impl IntoIterator<Item = f64>) -> Value {
    Value::array(NdArray::f32(shape, v.into_iter().map(|x| x as f32).collect()).unwrap())
}

pub fn f64_array(shape: &[usize], v: impl IntoIterator<Item = f64>) -> Value {
    Value::array(NdArray::f64(shape, v.into_iter().collect()).unwrap())
}

fn rows<const N: usize>(m: [[f64; N]; N]) -> Vec<f64> {
    m.iter().flatten().copied().collect()
}

/// SMPL's 24 joints of a 55-joint SMPL-X skeleton: 0..21, then the hands (middle knuckles).
fn smpl24(j: &[DVec3; N_JOINTS]) -> Vec<f64> {
    (0..22)
        .chain([28, 43])
        .flat_map(|i| j[i].to_array())
        .collect()
}

/// SMPL's 72 pose numbers: the root, joints 1..21, zero hands.
fn smpl72(params: &FrameParams, root: DVec3) -> Vec<f64> {
    let mut v: Vec<f64> = root.to_array().to_vec();
    for r in &params.body_pose {
        v.extend(r.to_array());
    }
    v.extend([0.0; 6]);
    v
}

const BETAS: [f64; 10] = [0.8, -0.5, 0.3, 0.2, -0.1, 0.6, -0.4, 0.1, 0.05, -0.2];

/// An SMPL-X model file of the real layout (v1.0: 10 shape and 10 expression columns)
/// whose 55 "vertices" regress one to one onto the joints, shaped so that [`BETAS`] give
/// the rest joints `rest`.
pub fn write_model(file: &Path, rest: &[DVec3; N_JOINTS]) {
    const S: usize = 20;
    let mut seed = 11u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    // Expression columns (10..20) are zero: SMPLer-X's expressions then leave the joints
    // where the scene has them.
    let shapedirs: Vec<f64> = (0..N_JOINTS * 3 * S)
        .map(|i| if i % S < 10 { 0.02 * rnd() } else { 0.0 })
        .collect();
    let mut v_template = Vec::with_capacity(N_JOINTS * 3);
    for (j, r) in rest.iter().enumerate() {
        for k in 0..3 {
            let offset: f64 = (0..10)
                .map(|c| shapedirs[(j * 3 + k) * S + c] * BETAS[c])
                .sum();
            v_template.push(r[k] - offset);
        }
    }
    let mut regressor = vec![0.0; N_JOINTS * N_JOINTS];
    for j in 0..N_JOINTS {
        regressor[j * N_JOINTS + j] = 1.0;
    }
    let mut kintree: Vec<i64> = PARENTS.iter().map(|&p| i64::from(p)).collect();
    kintree.extend(0..N_JOINTS as i64);
    let mut w = NpzWriter::create(file).unwrap();
    w.array(
        "v_template",
        &NdArray::f64(&[N_JOINTS, 3], v_template).unwrap(),
    )
    .unwrap()
    .array(
        "shapedirs",
        &NdArray::f64(&[N_JOINTS, 3, S], shapedirs).unwrap(),
    )
    .unwrap()
    .array(
        "J_regressor",
        &NdArray::f64(&[N_JOINTS, N_JOINTS], regressor).unwrap(),
    )
    .unwrap()
    .array(
        "kintree_table",
        &NdArray::new(vec![2, N_JOINTS], ArrayData::I64(kintree)).unwrap(),
    )
    .unwrap()
    .array(
        "hands_meanl",
        &NdArray::f64(&[45], hands_mean(1.0)).unwrap(),
    )
    .unwrap()
    .array(
        "hands_meanr",
        &NdArray::f64(&[45], hands_mean(-1.0)).unwrap(),
    )
    .unwrap();
    w.finish().unwrap();
}

fn hands_mean(side: f64) -> Vec<f64> {
    (0..45)
        .map(|i| match i % 3 {
            0 => 0.1 + 0.002 * i as f64,
            _ => side * 0.05 * ((i % 7) as f64 - 3.0) / 3.0,
        })
        .collect()
}

fn camera_rotation(c: &Camera) -> DMat3 {
    c.camera_from_world.matrix3
}

/// A frame's root rotation seen from its camera.
pub fn root_in_camera(f: &Frame) -> DVec3 {
    axis_angle_from_rotation(
        camera_rotation(&f.camera) * rotation_from_axis_angle(f.params.global_orient),
    )
}

fn save_png<P: image::PixelWithColorType>(
    img: &image::ImageBuffer<P, Vec<P::Subpixel>>,
    file: &Path,
) where
    [P::Subpixel]: image::EncodableLayout,
{
    img.save_with_format(file, image::ImageFormat::Png).unwrap();
}

// ---------------------------------------------------------------------------------------
// HumanNeRF, prepared layout

/// Writes the clip as HumanNeRF's prepare scripts do: ZJU's (raw joints, `distortions`)
/// or the wild script's (pelvis-centred joints), PNG frames and masks. Returns the folder.
pub fn write_humannerf_prepared(
    clip: &Clip,
    name: &str,
    centred: bool,
    distortion: Option<[f64; 5]>,
) -> PathBuf {
    let dir = super::temp_dir(name);
    for d in ["images", "masks"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    let skeleton = &clip.ds.subjects[0].skeleton;
    let s = skeleton.rest_joints;
    let s0 = s[0];
    let origin = if centred { s0 } else { DVec3::ZERO };
    let tpose: Vec<f64> = smpl24(&s.map(|j| j - origin));
    let mut cameras = Vec::new();
    let mut meshes = Vec::new();
    for (i, (f, px)) in clip.frames.iter().zip(&clip.pixels).enumerate() {
        let stem = format!("frame_{i:06}");
        let (image, mask) = (
            dir.join(format!("images/{stem}.png")),
            dir.join(format!("masks/{stem}.png")),
        );
        match distortion {
            None => {
                save_png(&px.rgb, &image);
                save_png(&px.mask, &mask);
            }
            Some(d) => {
                // What the lens recorded: each stored pixel shows the undistorted scene
                // where the distortion sends it.
                let k = opencv_k(&f.camera);
                let (rgb, m) = (&px.rgb, &px.mask);
                let (w, h) = rgb.dimensions();
                let at = |x: u32, y: u32| {
                    undistort::undistort_point(&k, &d, DVec2::new(x as f64, y as f64))
                };
                let distorted = RgbImage::from_fn(w, h, |x, y| {
                    let q = at(x, y).round();
                    let (qx, qy) = (
                        q.x.clamp(0.0, w as f64 - 1.0),
                        q.y.clamp(0.0, h as f64 - 1.0),
                    );
                    *rgb.get_pixel(qx as u32, qy as u32)
                });
                save_png(&distorted, &image);
                let distorted = GrayImage::from_fn(w, h, |x, y| {
                    let q = at(x, y).round();
                    if q.x < 0.0 || q.y < 0.0 || q.x > w as f64 - 1.0 || q.y > h as f64 - 1.0 {
                        return image::Luma([0]);
                    }
                    *m.get_pixel(q.x as u32, q.y as u32)
                });
                save_png(&distorted, &mask);
            }
        }
        let g = f.params.global_orient;
        let r = rotation_from_axis_angle(g);
        let mut rootless = f.params.clone();
        rootless.global_orient = DVec3::ZERO;
        rootless.transl = DVec3::ZERO;
        let posed = skeleton.pose(&rootless).joints();
        // x_world = R(Rh) x_body + Th; x_body is SMPL without the root (pelvis at S0).
        let th = if centred {
            s0 + f.params.transl
        } else {
            s0 + f.params.transl - r * s0
        };
        let mut cam = vec![
            ("intrinsics", f32_array(&[3, 3], rows(opencv_k(&f.camera)))),
            (
                "extrinsics",
                f64_array(&[4, 4], rows(f.camera.extrinsics_rows())),
            ),
        ];
        if let Some(d) = distortion {
            cam.push(("distortions", f32_array(&[5], d)));
        }
        cameras.push((stem.clone(), Value::dict(cam)));
        meshes.push((
            stem,
            Value::dict([
                ("Rh", f32_array(&[3], g.to_array())),
                ("Th", f64_array(&[3], th.to_array())),
                ("poses", f32_array(&[72], smpl72(&f.params, DVec3::ZERO))),
                (
                    "joints",
                    f64_array(&[24, 3], smpl24(&posed.map(|j| j - origin))),
                ),
                ("tpose_joints", f64_array(&[24, 3], tpose.clone())),
            ]),
        ));
    }
    let write = |file: &str, v: Value| std::fs::write(dir.join(file), write_protocol4(&v)).unwrap();
    write("cameras.pkl", Value::dict(cameras));
    write("mesh_infos.pkl", Value::dict(meshes));
    write(
        "canonical_joints.pkl",
        Value::dict([("joints", f64_array(&[24, 3], smpl24(&s)))]),
    );
    dir
}

// ---------------------------------------------------------------------------------------
// SMPLer-X

fn npz_f32(w: &mut NpzWriter, key: &str, shape: &[usize], v: Vec<f64>) {
    w.array(
        key,
        &NdArray::f32(shape, v.iter().map(|&x| x as f32).collect()).unwrap(),
    )
    .unwrap();
}

fn flat(v: &[DVec3]) -> Vec<f64> {
    v.iter().flat_map(|x| x.to_array()).collect()
}

/// Where [`write_smplerx`] put SMPLer-X's results and what they need beside them.
pub struct SmplerxFixture {
    pub results: PathBuf,
    pub images: PathBuf,
    pub masks: PathBuf,
    pub model: PathBuf,
}

/// Writes the clip as SMPLer-X's demo leaves it: `%06d.jpg` frames from 1, one
/// `smplx/{frame:05}_{id}.npz` and `meta/...json` per person in its virtual crop camera
/// (plus a smaller second person in frame 1), a last frame without a detection, and PNG
/// masks from a "matting tool".
pub fn write_smplerx(clip: &Clip, name: &str) -> SmplerxFixture {
    let dir = super::temp_dir(name);
    let results = dir.join("results");
    let (images, masks) = (dir.join("images"), dir.join("masks"));
    for d in [
        results.join("smplx"),
        results.join("meta"),
        images.clone(),
        masks.clone(),
    ] {
        std::fs::create_dir_all(d).unwrap();
    }
    let model = dir.join("SMPLX_NEUTRAL.npz");
    let s = clip.rest();
    write_model(&model, &s);
    let skeleton = &clip.ds.subjects[0].skeleton;
    for (i, (f, px)) in clip.frames.iter().zip(&clip.pixels).enumerate() {
        let n = i + 1;
        std::fs::write(images.join(format!("{n:06}.jpg")), px.jpeg_bytes()).unwrap();
        save_png(&px.mask, &masks.join(format!("{n:06}.png")));
        // The body in the camera frame, as SMPLer-X predicts it.
        let re = camera_rotation(&f.camera);
        let te = f.camera.camera_from_world.translation;
        let mut cam = f.params.clone();
        cam.global_orient = root_in_camera(f);
        cam.transl = re * (s[0] + f.params.transl) + te - s[0];
        let posed = skeleton.pose(&f.params).joints();
        let truth: Vec<DVec2> = posed
            .iter()
            .map(|p| f.camera.project(*p).unwrap().truncate() - DVec2::splat(0.5))
            .collect();
        // process_bbox: the joints' box, widened to 3:4 and enlarged 1.25x.
        let (lo, hi) = truth
            .iter()
            .fold((DVec2::splat(1e9), DVec2::splat(-1e9)), |(a, b), p| {
                (a.min(*p), b.max(*p))
            });
        let c = (lo + hi) / 2.0;
        let (mut bw, mut bh) = (hi.x - lo.x, hi.y - lo.y);
        if bw > 0.75 * bh {
            bh = bw / 0.75;
        } else {
            bw = bh * 0.75;
        }
        let (bw, bh) = (bw * 1.25, bh * 1.25);
        let bbox = [c.x - bw / 2.0, c.y - bh / 2.0, bw, bh];
        let kv = [
            [5000.0 / 192.0 * bw, 0.0, c.x],
            [0.0, 5000.0 / 256.0 * bh, c.y],
            [0.0, 0.0, 1.0],
        ];
        // The network's transl: the joints land where the true camera shows them.
        let mut at_zero = cam.clone();
        at_zero.transl = DVec3::ZERO;
        let pts = skeleton.pose(&at_zero).joints();
        let (tv, _) = talkin::import::smplerx::solve_translation(&kv, &pts, &truth, cam.transl);
        let people: &[(usize, f64)] = if i == 0 {
            &[(0, 1.0), (1, 0.5)]
        } else {
            &[(0, 1.0)]
        };
        for &(id, shrink) in people {
            let stem = format!("{n:05}_{id}");
            let (ml, mr) = (hands_mean(1.0), hands_mean(-1.0));
            let mut w = NpzWriter::create(results.join(format!("smplx/{stem}.npz"))).unwrap();
            npz_f32(
                &mut w,
                "global_orient",
                &[1, 3],
                cam.global_orient.to_array().to_vec(),
            );
            npz_f32(&mut w, "body_pose", &[21, 3], flat(&cam.body_pose));
            let rel = |h: &[DVec3], m: &[f64]| -> Vec<f64> {
                flat(h).iter().zip(m).map(|(a, b)| a - b).collect()
            };
            npz_f32(
                &mut w,
                "left_hand_pose",
                &[15, 3],
                rel(&cam.left_hand_pose, &ml),
            );
            npz_f32(
                &mut w,
                "right_hand_pose",
                &[15, 3],
                rel(&cam.right_hand_pose, &mr),
            );
            npz_f32(
                &mut w,
                "jaw_pose",
                &[1, 3],
                cam.jaw_pose.to_array().to_vec(),
            );
            w.array(
                "leye_pose",
                &NdArray::f64(&[1, 3], cam.leye_pose.to_array().to_vec()).unwrap(),
            )
            .unwrap();
            w.array(
                "reye_pose",
                &NdArray::f64(&[1, 3], cam.reye_pose.to_array().to_vec()).unwrap(),
            )
            .unwrap();
            npz_f32(&mut w, "betas", &[1, 10], BETAS.to_vec());
            npz_f32(&mut w, "expression", &[1, 10], cam.expression.to_vec());
            npz_f32(
                &mut w,
                "transl",
                &[1, 3],
                (tv * (2.0 - shrink)).to_array().to_vec(),
            );
            w.finish().unwrap();
            let b = [bbox[0], bbox[1], bbox[2] * shrink, bbox[3] * shrink];
            let meta = serde_json::json!({
                "focal": [kv[0][0] * shrink, kv[1][1] * shrink],
                "princpt": [kv[0][2], kv[1][2]],
                "bbox": b,
                "bbox_mmdet": b,
                "bbox_id": id,
                "img_path": format!("../demo/images/clip/{n:06}.jpg"),
            });
            std::fs::write(
                results.join(format!("meta/{stem}.json")),
                serde_json::to_string_pretty(&meta).unwrap(),
            )
            .unwrap();
        }
    }
    // A last frame where the detector found nobody: no npz, no json.
    let n = clip.frames.len() + 1;
    std::fs::copy(
        images.join("000001.jpg"),
        images.join(format!("{n:06}.jpg")),
    )
    .unwrap();
    std::fs::copy(masks.join("000001.png"), masks.join(format!("{n:06}.png"))).unwrap();
    SmplerxFixture {
        results,
        images,
        masks,
        model,
    }
}

/// `talkin import smplerx` of a fixture into `out`, with the frames' focal length.
pub fn smplerx_args<'a>(fx: &'a SmplerxFixture, out: &'a Path, focal: &'a str) -> Vec<&'a str> {
    let p = super::cli::p;
    vec![
        "import",
        "smplerx",
        p(&fx.results),
        "--out",
        p(out),
        "--images",
        p(&fx.images),
        "--masks",
        p(&fx.masks),
        "--body-model",
        p(&fx.model),
        "--focal",
        focal,
        "--fps",
        "25",
    ]
}

// ---------------------------------------------------------------------------------------
// HumanNeRF, wild-video input

/// Writes the clip as HumanNeRF's wild-video input: PNG frames and masks, SMPL without
/// translation, which the extrinsics carry instead. Returns the folder and a model file.
pub fn write_humannerf_wild(clip: &Clip, name: &str) -> (PathBuf, PathBuf) {
    let dir = super::temp_dir(name);
    for d in ["images", "masks"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    let mut meta = serde_json::Map::new();
    for (i, (f, px)) in clip.frames.iter().zip(&clip.pixels).enumerate() {
        let stem = format!("{i:06}");
        save_png(&px.rgb, &dir.join(format!("images/{stem}.png")));
        save_png(&px.mask, &dir.join(format!("masks/{stem}.png")));
        let mut e = f.camera.extrinsics_rows();
        let t = camera_rotation(&f.camera) * f.params.transl;
        for r in 0..3 {
            e[r][3] += t[r];
        }
        meta.insert(
            stem,
            serde_json::json!({
                "poses": smpl72(&f.params, f.params.global_orient),
                "betas": BETAS,
                "cam_intrinsics": opencv_k(&f.camera),
                "cam_extrinsics": e,
            }),
        );
    }
    std::fs::write(
        dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta).unwrap(),
    )
    .unwrap();
    let model = dir.join("SMPLX_NEUTRAL.npz");
    write_model(&model, &clip.rest());
    (dir, model)
}

// ---------------------------------------------------------------------------------------
// PeopleSnapshot (InstantAvatar)

fn npz_scalar(w: &mut NpzWriter, key: &str, v: i64) {
    w.array(key, &NdArray::new(vec![], ArrayData::I64(vec![v])).unwrap())
        .unwrap();
}

/// Writes the clip as InstantAvatar's processed PeopleSnapshot: PNG frames, 0/1 uint8
/// masks as .npy (a soft mask is cut at 128), every frame's pose in `poses.npz`, and
/// train, val and test poses whose ranges overlap as InstantAvatar's do (val's one frame
/// is also test's first). The folder's name is no PeopleSnapshot subject: the rows are
/// found in `poses.npz`. Returns the folder and a model file.
pub fn write_peoplesnapshot(clip: &Clip, name: &str) -> (PathBuf, PathBuf) {
    let dir = super::temp_dir(name);
    for d in ["images", "masks", "poses"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    let frames = &clip.frames;
    let c = &frames[0].camera;
    let mut w = NpzWriter::create(dir.join("cameras.npz")).unwrap();
    w.array(
        "intrinsic",
        &NdArray::f64(&[3, 3], rows(opencv_k(c))).unwrap(),
    )
    .unwrap()
    .array(
        "extrinsic",
        &NdArray::f64(&[4, 4], rows(c.extrinsics_rows())).unwrap(),
    )
    .unwrap();
    npz_scalar(&mut w, "height", c.height as i64);
    npz_scalar(&mut w, "width", c.width as i64);
    w.finish().unwrap();
    for (i, (f, px)) in frames.iter().zip(&clip.pixels).enumerate() {
        assert_eq!(f.camera, *c, "one camera per identity");
        save_png(&px.rgb, &dir.join(format!("images/image_{i:04}.png")));
        let (mw, mh) = px.mask.dimensions();
        let bits: Vec<u8> = px.mask.pixels().map(|p| u8::from(p[0] >= 128)).collect();
        let bytes = talkin::data::npz::npy_bytes(
            &NdArray::new(vec![mh as usize, mw as usize], ArrayData::U8(bits)).unwrap(),
        )
        .unwrap();
        std::fs::write(dir.join(format!("masks/mask_{i:04}.npy")), bytes).unwrap();
    }
    let n = frames.len();
    let mut w = NpzWriter::create(dir.join("poses.npz")).unwrap();
    npz_f32(&mut w, "betas", &[10], BETAS.to_vec());
    npz_f32(
        &mut w,
        "thetas",
        &[n, 72],
        frames
            .iter()
            .flat_map(|f| smpl72(&f.params, f.params.global_orient))
            .collect(),
    );
    npz_f32(
        &mut w,
        "transl",
        &[n, 3],
        frames
            .iter()
            .flat_map(|f| f.params.transl.to_array())
            .collect(),
    );
    w.finish().unwrap();
    let splits = [
        ("train", 0..n - 2),
        ("val", n - 2..n - 1),
        ("test", n - 2..n),
    ];
    for (split, range) in splits {
        let fs = &frames[range];
        let mut w = NpzWriter::create(dir.join(format!("poses/anim_nerf_{split}.npz"))).unwrap();
        npz_f32(&mut w, "betas", &[1, 10], BETAS.to_vec());
        npz_f32(
            &mut w,
            "global_orient",
            &[fs.len(), 3],
            fs.iter()
                .flat_map(|f| f.params.global_orient.to_array())
                .collect(),
        );
        npz_f32(
            &mut w,
            "body_pose",
            &[fs.len(), 69],
            fs.iter()
                .flat_map(|f| smpl72(&f.params, DVec3::ZERO)[3..].to_vec())
                .collect(),
        );
        npz_f32(
            &mut w,
            "transl",
            &[fs.len(), 3],
            fs.iter().flat_map(|f| f.params.transl.to_array()).collect(),
        );
        w.finish().unwrap();
    }
    let model = dir.join("SMPLX_NEUTRAL.npz");
    write_model(&model, &clip.rest());
    (dir, model)
}
