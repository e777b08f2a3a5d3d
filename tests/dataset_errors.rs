//! Bad input: every kind of damaged dataset gives a clear error naming the file, frame and
//! field, through the library and through the `talkin inspect` binary (exit 1, no panic).

mod common;

use std::path::Path;
use std::process::Command;

use talkin::data::dataset::{Dataset, DatasetError};

fn edit_json(dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let file = dir.join("dataset.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(&file, serde_json::to_string(&v).unwrap()).unwrap();
}

/// Runs `talkin inspect dir`; returns (exit code, stderr).
fn inspect(dir: &Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .arg("inspect")
        .arg(dir)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Damages a fresh tiny dataset with `damage`, then checks the library error and the CLI.
fn check(name: &str, damage: impl FnOnce(&Path), expect_in_message: &[&str]) -> DatasetError {
    let dir = common::temp_dir(name);
    common::write_tiny_dataset(&dir);
    damage(&dir);
    let err = match Dataset::load(&dir) {
        Err(e) => e,
        // Pixel-level damage is found when the pixels are decoded.
        Ok(d) => (0..d.frames.len())
            .find_map(|i| d.images(i).err())
            .expect("damage must be detected"),
    };
    let message = err.to_string();
    for needle in expect_in_message {
        assert!(
            message.contains(needle),
            "{name}: {message:?} lacks {needle:?}"
        );
    }
    let (code, stderr) = inspect(&dir);
    assert_eq!(code, 1, "{name}: {stderr}");
    assert!(!stderr.contains("panicked"), "{name}: {stderr}");
    for needle in expect_in_message {
        assert!(
            stderr.contains(needle),
            "{name}: stderr {stderr:?} lacks {needle:?}"
        );
    }
    err
}

#[test]
fn the_undamaged_dataset_round_trips_and_inspects() {
    let dir = common::temp_dir("round_trip");
    let written = common::write_tiny_dataset(&dir);
    let loaded = Dataset::load(&dir).unwrap();
    // Written numbers are rounded to 1e-9; a second round trip is exact.
    assert_eq!(loaded.frames.len(), written.frames.len());
    for (a, b) in loaded.subjects[0]
        .skeleton
        .rest_joints
        .iter()
        .zip(&written.subjects[0].skeleton.rest_joints)
    {
        assert!((*a - *b).length() < 1e-8);
    }
    assert_eq!(loaded.frames[1].params, written.frames[1].params);
    loaded.save_index().unwrap();
    assert_eq!(Dataset::load(&dir).unwrap(), loaded);
    let images = loaded.images(1).unwrap();
    assert_eq!(images.rgb.dimensions(), (24, 32));
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .arg("inspect")
        .arg(&dir)
        .arg("--sheet")
        .arg(dir.join("sheet.png"))
        .arg("--joints-json")
        .arg(dir.join("joints.json"))
        .output()
        .unwrap();
    // The block is not where the skeleton projects, so inspect may complain about
    // alignment; it must not fail on validity.
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("valid talkin dataset, 2 frames"),
        "{stdout}"
    );
    assert!(dir.join("sheet.png").exists());
    let joints: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("joints.json")).unwrap()).unwrap();
    assert_eq!(joints[0]["joints_3d"].as_array().unwrap().len(), 55);
}

#[test]
fn truncated_png() {
    check(
        "truncated_png",
        |d| {
            let f = d.join("images/00001.png");
            let bytes = std::fs::read(&f).unwrap();
            std::fs::write(&f, &bytes[..bytes.len() / 2]).unwrap();
        },
        &["images/00001.png", "cannot decode PNG"],
    );
}

#[test]
fn not_a_png() {
    check(
        "not_a_png",
        |d| std::fs::write(d.join("masks/00000.png"), b"hello").unwrap(),
        &["masks/00000.png"],
    );
}

#[test]
fn nan_parameter() {
    // Python's json writes NaN as a bare token, which is not JSON.
    check(
        "nan_parameter",
        |d| {
            let f = d.join("dataset.json");
            let text = std::fs::read_to_string(&f).unwrap();
            let text = text.replacen("\"jaw_pose\": [\n", "\"jaw_pose\": [\n NaN, ", 1);
            let text = text.replacen("\"jaw_pose\":[", "\"jaw_pose\":[NaN,", 1);
            std::fs::write(&f, text).unwrap();
        },
        &["dataset.json", "malformed JSON at line"],
    );
    // A non-numeric entry where a number belongs.
    check(
        "nan_string_parameter",
        |d| edit_json(d, |v| v["frames"][1]["params"]["transl"][2] = "nan".into()),
        &["dataset.json", "frames[1].params.transl[2]", "a number"],
    );
}

#[test]
fn wrong_shaped_parameter() {
    check(
        "wrong_shape",
        |d| {
            edit_json(d, |v| {
                v["frames"][1]["params"]["body_pose"] =
                    serde_json::to_value(vec![[0.0f64; 3]; 20]).unwrap()
            })
        },
        &["frames[1].params.body_pose", "21 x 3"],
    );
    check(
        "wrong_joints",
        |d| {
            edit_json(d, |v| {
                v["subjects"][0]["rest_joints"] =
                    serde_json::to_value(vec![[0.0f64; 2]; 55]).unwrap()
            })
        },
        &["subjects[0].rest_joints", "55 x 3"],
    );
}

#[test]
fn missing_file() {
    check(
        "missing_file",
        |d| std::fs::remove_file(d.join("segmentation/00001.png")).unwrap(),
        &["segmentation/00001.png"],
    );
    check(
        "missing_index",
        |d| std::fs::remove_file(d.join("dataset.json")).unwrap(),
        &["dataset.json"],
    );
}

#[test]
fn bad_subject_index() {
    check(
        "bad_subject",
        |d| edit_json(d, |v| v["frames"][0]["subject"] = 3.into()),
        &["frames[0].subject", "out of range"],
    );
}

#[test]
fn malformed_json() {
    check(
        "malformed_json",
        |d| {
            let f = d.join("dataset.json");
            let text = std::fs::read_to_string(&f).unwrap();
            std::fs::write(&f, &text[..text.len() - 10]).unwrap();
        },
        &["dataset.json", "malformed JSON"],
    );
}

#[test]
fn singular_intrinsics() {
    check(
        "singular_intrinsics",
        |d| {
            edit_json(d, |v| {
                v["frames"][1]["camera"]["intrinsics"][1][1] = 0.0.into()
            })
        },
        &["frames[1].camera", "intrinsics", "singular"],
    );
}

#[test]
fn wrong_image_size_and_labels() {
    check(
        "wrong_size",
        |d| {
            image::GrayImage::new(10, 10)
                .save(d.join("masks/00001.png"))
                .unwrap()
        },
        &["masks/00001.png", "10x10"],
    );
    check(
        "bad_label",
        |d| {
            image::GrayImage::from_pixel(24, 32, image::Luma([7]))
                .save(d.join("segmentation/00000.png"))
                .unwrap()
        },
        &["segmentation/00000.png", "label 7"],
    );
}

#[test]
fn paths_may_not_escape_the_dataset() {
    check(
        "escaping_path",
        |d| edit_json(d, |v| v["frames"][0]["image"] = "../../etc/passwd".into()),
        &["frames[0].image", "relative path inside the dataset"],
    );
}

#[test]
fn wrong_format_or_version() {
    check(
        "wrong_version",
        |d| edit_json(d, |v| v["version"] = 2.into()),
        &["version", "found 2"],
    );
}
