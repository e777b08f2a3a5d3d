//! Hostile files against the readers of this crate that `loader_properties` (dataset.json),
//! `motion_properties` (AMASS and JSON motions) and the pickle reader's own properties do
//! not already cover: `.npy` and `.npz` (arbitrary bytes, damaged archives, headers and
//! members claiming absurd sizes), the SMPL-X model file, BEAT2 motions, the frames' PNG
//! images, masks and labels. No reader panics, none
//! allocates what a header claims before checking it (this binary's allocator refuses any
//! single allocation over [`ALLOCATION_LIMIT`], which aborts the run), and whatever is
//! accepted is finite and within the documented limits.
//!
//! 64 cases per property from a fixed seed; `PROPTEST_CASES=N` runs more (see
//! docs/results.md for the 20 000-case run) and `PROPTEST_RNG_SEED=S` picks another seed.
#![allow(unsafe_code)] // the capped allocator below

#[path = "support/damaged_bytes.rs"]
mod damaged_bytes;
#[path = "support/proptest_config.rs"]
mod proptest_config;

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use damaged_bytes::damage;
use image::{GrayImage, RgbImage};
use proptest::prelude::*;
use proptest_config::config;
use talkin_data::array::{ArrayData, NdArray};
use talkin_data::dataset::{Dataset, Frame, Matting, Split, Subject};
use talkin_data::motion::{MotionLayout, read_motion};
use talkin_data::npz::{MAX_ELEMENTS, Npz, NpzWriter, parse_npy, raw_npy_bytes};
use talkin_data::smplx_model::SmplxModel;
use talkin_human::body::{FrameParams, N_JOINTS, PARENTS, Skeleton};
use talkin_human::camera::Camera;

/// The largest single allocation this binary allows: every fixture here is a few
/// kilobytes, so anything near this comes from trusting a size a file claims.
const ALLOCATION_LIMIT: usize = 256 << 20;

/// The system allocator, refusing allocations over [`ALLOCATION_LIMIT`] (Rust then aborts
/// with "memory allocation of N bytes failed", naming the size).
struct Capped;

// SAFETY: every call is forwarded unchanged to the system allocator, or refused with a
// null pointer, which `GlobalAlloc` allows.
unsafe impl GlobalAlloc for Capped {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Capped = Capped;

/// A fresh path per call under one directory per process (properties run in parallel).
fn temp(ext: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!("talkin_hostile_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(format!("{}.{ext}", NEXT.fetch_add(1, Ordering::Relaxed)))
}

/// Writes `bytes` to a fresh file, hands it to `read` and removes it.
fn with_file<T>(bytes: &[u8], ext: &str, read: impl FnOnce(&Path) -> T) -> T {
    let file = temp(ext);
    std::fs::write(&file, bytes).unwrap();
    let out = read(&file);
    let _ = std::fs::remove_file(&file);
    out
}

/// An `.npz` written by [`NpzWriter`] from `(name, array)` pairs, as bytes.
fn npz_bytes(arrays: &[(&str, NdArray)]) -> Vec<u8> {
    let file = temp("npz");
    let mut w = NpzWriter::create(&file).unwrap();
    for (name, a) in arrays {
        w.array(name, a).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&file).unwrap();
    let _ = std::fs::remove_file(&file);
    bytes
}

// ---------------------------------------------------------------------------------------
// .npy and .npz

/// A `.npy` header (version 1) for `descr`, `shape` and order, padded as numpy pads it
/// (`npz::raw_npy_bytes`), followed by `data`.
fn npy_with_header(descr: &str, shape: &[u64], fortran: bool, data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(u64::to_string).collect();
    let shape = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let order = if fortran { "True" } else { "False" };
    raw_npy_bytes(
        &format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': {shape}, }}"),
        data,
    )
}

/// Sizes a header may claim: none, small, and far beyond memory.
fn absurd_dim() -> impl Strategy<Value = u64> {
    prop_oneof![
        Just(0),
        Just(1),
        Just(3),
        Just(1 << 20),
        Just(1 << 31),
        Just(1 << 40),
        Just(u64::MAX / 2),
        Just(u64::MAX),
        0u64..64,
    ]
}

fn descr() -> impl Strategy<Value = &'static str> {
    prop::sample::select(vec![
        "<f8",
        ">f8",
        "<f4",
        "<f2",
        "|b1",
        "<i8",
        "|i1",
        "|u1",
        "<u4",
        "<U0",
        "|S0",
        "<U1",
        "|S3",
        "<U1000000000",
        "|V8",
        "<c16",
        "|O",
        "<M8[s]",
        "",
        "<f8<f8",
    ])
}

/// An accepted array is what its header says: as many elements as its shape, at most
/// [`MAX_ELEMENTS`].
fn assert_consistent(a: &NdArray) {
    let count = a.shape().iter().product::<usize>();
    assert!(count <= MAX_ELEMENTS, "accepted {count} elements");
    assert_eq!(a.data().len(), count);
}

proptest! {
    #![proptest_config(config(0x4f57_11e5))]

    #[test]
    fn npy_arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        if let Ok(a) = parse_npy(&bytes, Path::new("x.npy"), "x") {
            assert_consistent(&a);
        }
        let mut magic = b"\x93NUMPY\x01\x00".to_vec();
        magic.extend(&bytes);
        if let Ok(a) = parse_npy(&magic, Path::new("x.npy"), "x") {
            assert_consistent(&a);
        }
    }

    /// Headers claiming any size of any dtype, with a little data: refused before
    /// anything of the claimed size is allocated, or accepted exactly as claimed.
    #[test]
    fn npy_absurd_headers_are_refused_before_allocating(
        descr in descr(),
        shape in prop::collection::vec(absurd_dim(), 0..4),
        fortran in any::<bool>(),
        data in prop::collection::vec(any::<u8>(), 0..64),
    ) {
        let bytes = npy_with_header(descr, &shape, fortran, &data);
        if let Ok(a) = parse_npy(&bytes, Path::new("x.npy"), "x") {
            assert_consistent(&a);
            let claimed: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
            prop_assert_eq!(a.shape(), &claimed[..]);
        }
    }

    #[test]
    fn npz_arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..1024)) {
        with_file(&bytes, "npz", |f| {
            if let Ok(mut npz) = Npz::open(f) {
                let _ = npz.read_all();
            }
        });
    }

    #[test]
    fn damaged_npz_never_panics(damage in damage(), compressed in any::<bool>()) {
        let bytes = if compressed { deflated_npz() } else { motion_npz(2) };
        with_file(&damage.apply(bytes), "npz", |f| {
            if let Ok(mut npz) = Npz::open(f)
                && let Ok(contents) = npz.read_all()
            {
                contents.arrays.values().for_each(assert_consistent);
            }
        });
    }
}

/// Found by `npy_absurd_headers_are_refused_before_allocating`: the whole product is 0,
/// but npyz's strides multiply 2^31 by 2^40 and overflowed (a panic).
#[test]
fn regression_a_zero_dim_does_not_hide_strides_that_overflow() {
    for fortran in [false, true] {
        let bytes = npy_with_header("<f8", &[0, 1 << 31, 1 << 40], fortran, &[]);
        let e = parse_npy(&bytes, Path::new("x.npy"), "x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("too large"), "{e}");
    }
}

/// An `.npz` as `np.savez_compressed` writes it: one deflated member.
fn deflated_npz() -> Vec<u8> {
    use std::io::Write;
    let mut out = std::io::Cursor::new(Vec::new());
    let mut zip = zip::ZipWriter::new(&mut out);
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    zip.start_file("poses.npy", options).unwrap();
    let poses = NdArray::f64(&[2, 165], (0..330).map(|k| 0.001 * k as f64).collect()).unwrap();
    zip.write_all(&talkin_data::npz::npy_bytes(&poses).unwrap())
        .unwrap();
    zip.finish().unwrap();
    out.into_inner()
}

/// A member whose central directory claims 4 GiB of data is refused before it is read.
#[test]
fn an_npz_member_claiming_gigabytes_is_refused_before_reading() {
    let mut bytes = deflated_npz();
    let central = bytes
        .windows(4)
        .position(|w| w == b"PK\x01\x02")
        .expect("a central directory entry");
    // The uncompressed size, 24 bytes into the entry.
    bytes[central + 24..central + 28].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let e = with_file(&bytes, "npz", |f| {
        Npz::open(f).and_then(|mut npz| npz.read("poses"))
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("poses") && e.contains("larger than"), "{e}");
}

// ---------------------------------------------------------------------------------------
// The SMPL-X model file

/// A valid model file of 55 vertices (one per joint, the identity regressor), 20 shape
/// and expression columns, as `SmplxModel::load` reads it.
fn model_npz() -> Vec<u8> {
    const S: usize = 20;
    let v_template: Vec<f64> = (0..N_JOINTS * 3).map(|k| 0.01 * k as f64).collect();
    let shapedirs: Vec<f64> = (0..N_JOINTS * 3 * S)
        .map(|k| 0.001 * (k % 13) as f64)
        .collect();
    let mut regressor = vec![0.0; N_JOINTS * N_JOINTS];
    for j in 0..N_JOINTS {
        regressor[j * N_JOINTS + j] = 1.0;
    }
    let mut kintree: Vec<i64> = PARENTS.iter().map(|&p| i64::from(p)).collect();
    kintree.extend(0..N_JOINTS as i64);
    let hand = NdArray::f64(&[45], vec![0.1; 45]).unwrap();
    npz_bytes(&[
        (
            "v_template",
            NdArray::f64(&[N_JOINTS, 3], v_template).unwrap(),
        ),
        (
            "shapedirs",
            NdArray::f64(&[N_JOINTS, 3, S], shapedirs).unwrap(),
        ),
        (
            "J_regressor",
            NdArray::f64(&[N_JOINTS, N_JOINTS], regressor).unwrap(),
        ),
        (
            "kintree_table",
            NdArray::new(vec![2, N_JOINTS], ArrayData::I64(kintree)).unwrap(),
        ),
        ("hands_meanl", hand.clone()),
        ("hands_meanr", hand),
    ])
}

/// A loaded model gives finite rest joints for any finite betas.
fn assert_model_sound(model: &SmplxModel) {
    let betas = vec![1.0; model.n_shape()];
    let joints = model.rest_joints(&betas).unwrap();
    assert!(joints.iter().all(|j| j.is_finite()));
    let (l, r) = model.hands_mean();
    assert!(l.iter().chain(&r).all(|j| j.is_finite()));
}

proptest! {
    #![proptest_config(config(0x4f57_11e5))]

    #[test]
    fn damaged_model_files_never_panic(damage in damage()) {
        with_file(&damage.apply(model_npz()), "npz", |f| {
            if let Ok(model) = SmplxModel::load(f) {
                assert_model_sound(&model);
            }
        });
    }

    #[test]
    fn model_files_of_arbitrary_bytes_never_panic(
        bytes in prop::collection::vec(any::<u8>(), 0..1024),
    ) {
        with_file(&bytes, "npz", |f| {
            if let Ok(model) = SmplxModel::load(f) {
                assert_model_sound(&model);
            }
        });
    }
}

#[test]
fn the_model_fixture_loads() {
    with_file(&model_npz(), "npz", |f| {
        assert_model_sound(&SmplxModel::load(f).unwrap());
    });
}

// ---------------------------------------------------------------------------------------
// BEAT2 motions

/// A BEAT2 motion of `n` frames: `poses` (N, 165), `trans`, `expressions` (N, 100),
/// `betas` (300,) and `mocap_frame_rate`.
fn motion_npz(n: usize) -> Vec<u8> {
    npz_bytes(&[
        (
            "poses",
            NdArray::f64(&[n, 165], (0..n * 165).map(|k| 0.002 * k as f64).collect()).unwrap(),
        ),
        (
            "trans",
            NdArray::f64(&[n, 3], (0..n * 3).map(|k| 0.1 * k as f64).collect()).unwrap(),
        ),
        (
            "expressions",
            NdArray::f64(&[n, 100], vec![0.25; n * 100]).unwrap(),
        ),
        ("betas", NdArray::f64(&[300], vec![0.5; 300]).unwrap()),
        ("mocap_frame_rate", NdArray::f64(&[], vec![30.0]).unwrap()),
    ])
}

proptest! {
    #![proptest_config(config(0x4f57_11e5))]

    #[test]
    fn damaged_beat2_motions_never_panic(damage in damage(), n in 1usize..4, forced in any::<bool>()) {
        let layout = forced.then_some(MotionLayout::Beat2);
        with_file(&damage.apply(motion_npz(n)), "npz", |f| {
            if let Ok(m) = read_motion(f, layout) {
                assert!(m.frames.iter().all(FrameParams::is_finite));
                assert!(m.betas.iter().all(|b| b.is_finite()));
                if let Some(fps) = m.fps {
                    assert!(fps.is_finite() && fps > 0.0, "accepted fps {fps}");
                }
            }
        });
    }
}

#[test]
fn the_beat2_fixture_reads() {
    let m = with_file(&motion_npz(3), "npz", |f| read_motion(f, None)).unwrap();
    assert_eq!((m.layout, m.frames.len()), (MotionLayout::Beat2, 3));
}

// ---------------------------------------------------------------------------------------
// Frame images, masks and labels

const W: u32 = 8;
const H: u32 = 6;

fn png(img: image::DynamicImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// The image, mask and labels of one valid frame, as PNG bytes.
fn frame_pngs() -> [Vec<u8>; 3] {
    let rgb = RgbImage::from_fn(W, H, |x, y| image::Rgb([x as u8 * 30, y as u8 * 40, 90]));
    let mask = GrayImage::from_fn(W, H, |x, _| image::Luma([if x > 2 { 255 } else { 0 }]));
    let labels = GrayImage::from_fn(W, H, |x, y| image::Luma([((x + y) % 5) as u8]));
    [png(rgb.into()), png(mask.into()), png(labels.into())]
}

/// `png` with its header claiming `width` x `height` (the chunk's CRC fixed up, so that
/// the decoder believes it).
fn claiming_size(mut png: Vec<u8>, width: u32, height: u32) -> Vec<u8> {
    png[16..20].copy_from_slice(&width.to_be_bytes());
    png[20..24].copy_from_slice(&height.to_be_bytes());
    let crc = crc32fast::hash(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    png
}

/// A one-frame dataset in a fresh directory whose image, mask and labels are `files`;
/// decodes the frame, and checks what an accepted frame holds.
fn decode_frame(files: &[Vec<u8>; 3]) -> Result<(), String> {
    let root = temp("frame");
    std::fs::create_dir_all(&root).unwrap();
    for (name, bytes) in ["image.png", "mask.png", "labels.png"].iter().zip(files) {
        std::fs::write(root.join(name), bytes).unwrap();
    }
    let camera = Camera::look_at(
        W,
        H,
        10.0,
        glam::DVec3::new(0.0, 1.0, 3.0),
        glam::DVec3::new(0.0, 1.0, 0.0),
        glam::DVec3::Y,
    )
    .unwrap();
    let dataset = Dataset {
        root: root.clone(),
        background: [1.0, 1.0, 1.0],
        matting: Matting::ByMask,
        masks: Default::default(),
        subjects: vec![Subject {
            name: "ada".into(),
            skeleton: Skeleton {
                rest_joints: [glam::DVec3::ZERO; N_JOINTS],
            },
        }],
        frames: vec![Frame {
            subject: 0,
            split: Split::Train,
            time: 0.0,
            image: "image.png".into(),
            mask: "mask.png".into(),
            segmentation: Some("labels.png".into()),
            depth: None,
            camera,
            params: FrameParams::default(),
        }],
    };
    let decoded = dataset.images(0).map_err(|e| e.to_string());
    let _ = std::fs::remove_dir_all(&root);
    let images = decoded?;
    assert_eq!(images.rgb.dimensions(), (W, H));
    assert_eq!(images.mask.dimensions(), (W, H));
    assert_eq!(images.segmentation.dimensions(), (W, H));
    assert!(images.segmentation.pixels().all(|p| p.0[0] < 5));
    Ok(())
}

proptest! {
    #![proptest_config(config(0x4f57_11e5))]

    #[test]
    fn frame_files_of_arbitrary_bytes_are_refused(
        which in 0usize..3,
        bytes in prop::collection::vec(any::<u8>(), 0..512),
    ) {
        let mut files = frame_pngs();
        files[which] = bytes;
        let _ = decode_frame(&files);
    }

    #[test]
    fn damaged_frame_files_never_panic(which in 0usize..3, damage in damage()) {
        let mut files = frame_pngs();
        files[which] = damage.apply(std::mem::take(&mut files[which]));
        let _ = decode_frame(&files);
    }

    /// A header claiming any size other than the camera's is refused by it, before the
    /// pixels are decoded: a 60000 x 60000 claim allocates nothing.
    #[test]
    fn frame_files_claiming_absurd_sizes_are_refused(
        which in 0usize..3,
        width in prop_oneof![Just(0u32), Just(W), 1u32..64, Just(10_000), Just(60_000), Just(u32::MAX)],
        height in prop_oneof![Just(0u32), Just(H), 1u32..64, Just(10_000), Just(60_000), Just(u32::MAX)],
    ) {
        let mut files = frame_pngs();
        files[which] = claiming_size(std::mem::take(&mut files[which]), width, height);
        let decoded = decode_frame(&files);
        if (width, height) != (W, H) {
            prop_assert!(decoded.is_err());
        }
    }
}

#[test]
fn the_frame_fixture_decodes() {
    decode_frame(&frame_pngs()).unwrap();
    // 10000 x 10000 RGB (300 MB) is within the image crate's own 512 MB limit: only the
    // header's size, checked first, keeps it from being allocated.
    for side in [10_000, 60_000] {
        let [rgb, mask, labels] = frame_pngs();
        let e = decode_frame(&[claiming_size(rgb, side, side), mask, labels]).unwrap_err();
        let expected = format!("is {side}x{side} but the frame's camera is 8x6");
        assert!(e.contains(&expected), "{e}");
    }
}
