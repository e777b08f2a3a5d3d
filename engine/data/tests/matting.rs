//! The mask defines the person: a `by_mask` dataset's frames are composited over the
//! background when decoded; a `matted` one is taken as it is unless a frame's
//! surroundings contradict its background, which is composited, listed and failed by
//! `inspect`.

use std::path::Path;

use talkin_data::dataset::{Composited, Dataset, Frame, Masks, Matting, Split, Subject};
use talkin_data::inspect::summarize;
use talkin_human::body::{FrameParams, Skeleton};
use talkin_human::camera::Camera;

const W: u32 = 40;
const H: u32 = 40;
const PERSON: [u8; 3] = [200, 40, 30];

/// A 40x40 frame: a 10x10 person at (15, 15) over `around`, and its exact mask.
fn write_frame(dir: &Path, i: usize, around: [u8; 3]) {
    let mut rgb = image::RgbImage::from_pixel(W, H, image::Rgb(around));
    let mut mask = image::GrayImage::new(W, H);
    for y in 15..25 {
        for x in 15..25 {
            rgb.put_pixel(x, y, image::Rgb(PERSON));
            mask.put_pixel(x, y, image::Luma([255]));
        }
    }
    rgb.save(dir.join(format!("images/{i}.png"))).unwrap();
    mask.save(dir.join(format!("masks/{i}.png"))).unwrap();
}

/// Two frames, the first over `first`, the second over white; saved with `matting`.
fn dataset(dir: &Path, matting: Matting, first: [u8; 3]) -> Dataset {
    for sub in ["images", "masks"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    write_frame(dir, 0, first);
    write_frame(dir, 1, [255, 255, 255]);
    let mut rest = [glam::DVec3::ZERO; 55];
    for (j, r) in rest.iter_mut().enumerate() {
        *r = glam::DVec3::new(0.01 * j as f64, 0.02 * j as f64, 0.0);
    }
    rest[12] = glam::DVec3::new(0.0, 0.55, 0.0);
    let camera = Camera::look_at(
        W,
        H,
        40.0,
        glam::DVec3::new(0.0, 0.3, 3.0),
        glam::DVec3::new(0.0, 0.3, 0.0),
        glam::DVec3::Y,
    )
    .unwrap();
    let frame = |i: usize| Frame {
        subject: 0,
        split: Split::Train,
        time: i as f64 * 0.04,
        image: format!("images/{i}.png").into(),
        mask: format!("masks/{i}.png").into(),
        segmentation: None,
        depth: None,
        camera,
        params: FrameParams::default(),
    };
    let d = Dataset {
        root: dir.to_path_buf(),
        background: [1.0, 1.0, 1.0],
        matting,
        masks: Default::default(),
        subjects: vec![Subject {
            name: "ada".into(),
            skeleton: Skeleton { rest_joints: rest },
        }],
        frames: vec![frame(0), frame(1)],
    };
    d.save_index().unwrap();
    Dataset::load(dir).unwrap()
}

#[test]
fn by_mask_frames_are_composited_and_the_file_stays_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let studio = [20, 22, 25];
    let d = dataset(dir.path(), Matting::ByMask, studio);
    assert_eq!(d.matting, Matting::ByMask);
    let images = d.images(0).unwrap();
    assert_eq!(images.composited, Composited::Declared);
    assert_eq!(images.rgb.get_pixel(0, 0).0, [255, 255, 255]);
    assert_eq!(images.rgb.get_pixel(20, 20).0, PERSON);
    assert_eq!(d.file_rgb(0).unwrap().get_pixel(0, 0).0, studio);
    assert!(d.contradicting_frames(&[0, 1]).unwrap().is_empty());
    let summary = summarize(&d, &|_| {}).unwrap();
    assert!(summary.contradicting_frames.is_empty());
    assert!(summary.frames[0].composited);
    assert!(
        !summary
            .problems()
            .iter()
            .any(|p| p.field == "matting" && p.fatal)
    );
}

#[test]
fn a_matted_dataset_showing_its_studio_is_composited_and_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dataset(dir.path(), Matting::Matted, [20, 22, 25]);
    let images = d.images(0).unwrap();
    assert_eq!(images.composited, Composited::Contradicted);
    assert_eq!(images.surroundings.off_share, 1.0);
    assert_eq!(images.rgb.get_pixel(0, 0).0, [255, 255, 255]);
    // The frame over white is taken as it is.
    assert_eq!(d.images(1).unwrap().composited, Composited::No);
    assert_eq!(d.contradicting_frames(&[0, 1]).unwrap(), vec![0]);
    let summary = summarize(&d, &|_| {}).unwrap();
    assert_eq!(summary.contradicting_frames, vec![0]);
    let problem = summary
        .problems()
        .into_iter()
        .find(|p| p.field == "matting")
        .expect("inspect names the matting");
    assert!(
        problem.fatal && problem.message.contains("by_mask"),
        "{problem:?}"
    );
    assert!(
        summary
            .to_string()
            .contains("1 frames are not over the background")
    );
}

#[test]
fn matting_is_optional_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path(), Matting::ByMask, [0, 0, 0]);
    let file = dir.path().join("dataset.json");
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.contains("\"matting\": \"by_mask\""));
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    doc.as_object_mut().unwrap().remove("matting");
    let absent = Dataset::from_json_str(&doc.to_string(), dir.path()).unwrap();
    assert_eq!(absent.matting, Matting::Matted);
    doc["matting"] = serde_json::json!("alpha");
    let err = Dataset::from_json_str(&doc.to_string(), dir.path())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("matting") && err.contains("by_mask") && err.contains("alpha"),
        "{err}"
    );
}

/// A matted dataset with coverage masks is shown over another colour exactly; one with a
/// matte is refused, naming the field.
#[test]
fn coverage_masks_show_a_matted_person_over_another_colour() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = dataset(dir.path(), Matting::Matted, [255, 255, 255]);
    // Frame 1's person pixel (15, 15) half covered: half person, half white.
    let mut rgb = image::open(dir.path().join("images/1.png"))
        .unwrap()
        .to_rgb8();
    let half: [u8; 3] = std::array::from_fn(|c| ((u16::from(PERSON[c]) + 255) / 2) as u8);
    rgb.put_pixel(15, 15, image::Rgb(half));
    rgb.save(dir.path().join("images/1.png")).unwrap();
    let mut mask = image::open(dir.path().join("masks/1.png"))
        .unwrap()
        .to_luma8();
    mask.put_pixel(15, 15, image::Luma([128]));
    mask.save(dir.path().join("masks/1.png")).unwrap();

    let err = d.clone().show_over([0.0; 3]).unwrap_err().to_string();
    assert!(err.contains("masks") && err.contains("coverage"), "{err}");
    d.masks = Masks::Coverage;
    d.save_index().unwrap();
    let mut d = Dataset::load(dir.path()).unwrap();
    assert_eq!(d.masks, Masks::Coverage);
    d.show_over([0.0; 3]).unwrap();
    let images = d.images(1).unwrap();
    assert_eq!(images.composited, Composited::Reshown);
    assert_eq!(images.rgb.get_pixel(0, 0).0, [0, 0, 0]);
    assert_eq!(images.rgb.get_pixel(20, 20).0, PERSON);
    let got = images.rgb.get_pixel(15, 15).0;
    for c in 0..3 {
        let want = f32::from(half[c]) - 127.0 / 255.0 * 255.0;
        assert!((f32::from(got[c]) - want).abs() <= 1.0, "{got:?} {half:?}");
    }
    // Written back, it is the dataset on disk: matted over white.
    let text = d.to_json().to_string();
    assert!(
        text.contains("\"matted\"") && text.contains("\"coverage\""),
        "{text}"
    );
    assert_eq!(
        Dataset::from_json_str(&text, dir.path())
            .unwrap()
            .background,
        [1.0; 3]
    );
}

#[test]
fn masks_are_optional_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    dataset(dir.path(), Matting::Matted, [255, 255, 255]);
    let text = std::fs::read_to_string(dir.path().join("dataset.json")).unwrap();
    assert!(
        !text.contains("\"masks\""),
        "a matte is the default, not written"
    );
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    doc["masks"] = serde_json::json!("exact");
    let err = Dataset::from_json_str(&doc.to_string(), dir.path())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("masks") && err.contains("coverage") && err.contains("exact"),
        "{err}"
    );
}
