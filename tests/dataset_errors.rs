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

#[test]
fn a_byte_order_mark_is_accepted() {
    let dir = common::temp_dir("bom");
    common::write_tiny_dataset(&dir);
    let f = dir.join("dataset.json");
    let text = std::fs::read_to_string(&f).unwrap();
    std::fs::write(&f, format!("\u{feff}{text}")).unwrap();
    assert_eq!(Dataset::load(&dir).unwrap().frames.len(), 2);
}

#[test]
fn an_8_bit_background_gets_a_hint() {
    check(
        "background_255",
        |d| edit_json(d, |v| v["background"] = serde_json::json!([255, 255, 255])),
        &["background", "divide them by 255"],
    );
}

#[test]
fn an_absurd_pose_names_its_element() {
    check(
        "pose_1e300",
        |d| {
            edit_json(d, |v| {
                v["frames"][1]["params"]["body_pose"][3][0] = 1e300.into()
            })
        },
        &["frames[1].params.body_pose[3][0]", "within"],
    );
}

#[test]
fn rgba_images_are_composited_over_the_background() {
    let dir = common::temp_dir("rgba");
    let dataset = common::write_tiny_dataset(&dir);
    // A transparent pixel where the person is, and a half-transparent red one.
    let mut rgba = image::RgbaImage::from_pixel(24, 32, image::Rgba([0, 0, 0, 0]));
    rgba.put_pixel(3, 3, image::Rgba([255, 0, 0, 128]));
    rgba.save(dir.join("images/00000.png")).unwrap();
    let images = dataset.images(0).unwrap();
    assert_eq!(images.rgb.get_pixel(10, 10).0, [255, 255, 255]);
    assert_eq!(images.rgb.get_pixel(3, 3).0, [255, 127, 127]);
}

/// Without a segmentation file the labels are derived from the mask and the posed
/// capsules, and `inspect` says which frames had them derived.
#[test]
fn frames_without_segmentation_get_derived_labels() {
    let dir = common::temp_dir("no_segmentation");
    common::write_tiny_dataset(&dir);
    edit_json(&dir, |v| {
        v["frames"][1]
            .as_object_mut()
            .unwrap()
            .remove("segmentation");
    });
    let dataset = Dataset::load(&dir).unwrap();
    assert!(dataset.frames[1].segmentation.is_none());
    let derived = dataset.images(1).unwrap();
    assert!(derived.labels_derived && !dataset.images(0).unwrap().labels_derived);
    // Every person pixel gets a part, every other pixel none.
    for (m, s) in derived.mask.pixels().zip(derived.segmentation.pixels()) {
        assert_eq!(m.0[0] >= 128, s.0[0] > 0);
    }
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .arg("inspect")
        .arg(&dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("labels were derived") && stdout.contains(": 1\n"),
        "{stdout}"
    );
    // The rewritten index keeps the frame without a segmentation.
    dataset.save_index().unwrap();
    assert!(
        Dataset::load(&dir).unwrap().frames[1]
            .segmentation
            .is_none()
    );
}

/// Runs `talkin eval`, `train` and `adapt` on `dir` (eval and adapt with a run that does
/// not exist): the dataset's checks come first, before any work, and nothing is written.
fn every_command_refuses(dir: &Path, needles: &[&str]) {
    let out_dir = dir.join("refused_out");
    let commands: [Vec<std::ffi::OsString>; 3] = [
        vec![
            "eval".into(),
            "--run".into(),
            "/nonexistent/run".into(),
            "--split".into(),
            "test_same".into(),
            "--json".into(),
            dir.join("eval.json").into(),
        ],
        vec![
            "train".into(),
            "--out".into(),
            out_dir.clone().into(),
            "--steps".into(),
            "1".into(),
        ],
        vec![
            "adapt".into(),
            "--run".into(),
            "/nonexistent/run".into(),
            "--subject".into(),
            "a".into(),
            "--out".into(),
            out_dir.clone().into(),
        ],
    ];
    for args in commands {
        let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(&args)
            .arg("--data")
            .arg(dir)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        for n in needles {
            assert!(stderr.contains(n), "{args:?}: {stderr:?} lacks {n:?}");
        }
        assert!(!stderr.contains("loading run"), "{stderr}");
        assert!(!dir.join("eval.json").exists(), "{args:?} wrote a report");
        assert!(
            std::fs::read_dir(&out_dir).map_or(true, |mut d| d.next().is_none()),
            "{args:?} wrote into {}",
            out_dir.display()
        );
    }
}

#[test]
fn an_empty_mask_is_refused_by_inspect_and_by_every_command() {
    let dir = common::temp_dir("empty_mask");
    common::write_tiny_dataset(&dir);
    image::GrayImage::new(24, 32)
        .save(dir.join("masks/00001.png"))
        .unwrap();
    let (code, stderr) = inspect(&dir);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("frames[1].mask") && stderr.contains("empty"),
        "{stderr}"
    );
    every_command_refuses(&dir, &["frames[1].mask", "empty"]);
}

#[test]
fn a_body_off_screen_is_refused() {
    let dir = common::temp_dir("off_screen");
    common::write_tiny_dataset(&dir);
    edit_json(&dir, |v| {
        v["frames"][0]["params"]["transl"] = serde_json::json!([40.0, 0.0, 0.0])
    });
    let (code, stderr) = inspect(&dir);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("frames[0].camera") && stderr.contains("off-screen"),
        "{stderr}"
    );
    every_command_refuses(&dir, &["frames[0].camera", "off-screen"]);
}

/// The overlay check draws the fitted body on the frames, the flagged ones first.
#[test]
fn the_overlay_is_written() {
    let dir = common::temp_dir("overlay");
    common::write_tiny_dataset(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .arg("inspect")
        .arg(&dir)
        .arg("--overlay")
        .arg(dir.join("overlay.png"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("overlay:"), "{stdout}");
    let overlay = image::open(dir.join("overlay.png")).unwrap().to_rgb8();
    // Two 24x32 tiles side by side with 4 px gaps, drawn on.
    assert_eq!(overlay.dimensions(), (2 * 24 + 3 * 4, 32 + 2 * 4));
    let plain = image::open(dir.join("images/00000.png")).unwrap().to_rgb8();
    let tile = image::imageops::crop_imm(&overlay, 4, 4, 24, 32).to_image();
    assert_ne!(tile, plain, "nothing drawn on the frame");
}

/// Off a terminal, progress is an info line (the final count at least); `-q` hides it and
/// keeps the exit code.
#[test]
fn progress_is_a_log_line_off_a_terminal_and_quiet_hides_it() {
    let dir = common::temp_dir("quiet_progress");
    common::write_tiny_dataset(&dir);
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(args)
            .arg(&dir)
            .output()
            .unwrap()
    };
    // (The tiny dataset's joints miss its masks, so inspect exits 1 either way.)
    let loud = run(&["inspect"]);
    let stderr = String::from_utf8_lossy(&loud.stderr);
    assert!(
        stderr.contains("decoding: ") && stderr.contains(" frames ("),
        "{stderr}"
    );
    let quiet = run(&["-q", "inspect"]);
    let stderr = String::from_utf8_lossy(&quiet.stderr);
    assert_eq!(quiet.status.code(), loud.status.code(), "{stderr}");
    assert!(!stderr.contains("decoding"), "{stderr}");
}

/// More expression coefficients than the engine uses are accepted, and said.
#[test]
fn extra_expression_coefficients_are_accepted_with_a_note() {
    let dir = common::temp_dir("extra_expression");
    common::write_tiny_dataset(&dir);
    edit_json(&dir, |v| {
        v["frames"][1]["params"]["expression"] = serde_json::json!(vec![0.01; 50]);
    });
    // The first ten are read as given.
    assert_eq!(
        Dataset::load(&dir).unwrap().frames[1].params.expression,
        [0.01; talkin::human::body::N_EXPRESSION]
    );
    let (_, stderr) = inspect(&dir);
    assert!(
        stderr.contains("1 of 2 frames carry more than 10 expression coefficients (up to 50)"),
        "{stderr}"
    );
}
