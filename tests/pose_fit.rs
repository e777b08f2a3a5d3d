//! The test-time pose fit (`talkin eval --pose-fit`, InstantAvatar's evaluation of novel
//! poses): a held-out frame whose fit was moved 4 cm sideways before training is pulled
//! back toward the body by a fit with the model frozen, the run is left as it was, and
//! `eval` reports the refitted score beside the plain one.
//!
//! Its own test binary: one trainer at a time in the process (see tests/resume.rs).

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use talkin::avatar::Avatar;
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::SamplerKind;
use talkin::render::eval::{EvalOptions, evaluate};
use talkin::render::sequence::split_frames;
use talkin::train::{FitPosesOptions, fit_held_out_poses, train};

/// Every file under `dir` with its bytes.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.insert(path.clone(), std::fs::read(&path).unwrap());
            }
        }
    }
    out
}

#[test]
fn a_displaced_held_out_fit_is_pulled_back_with_the_model_frozen() {
    // The scene, its test_same frame's fit moved 4 cm along x, then trained (training
    // never sees that frame).
    let scene = common::synthetic_scene("pose_fit_data", 1, 64, 5);
    let data = scene.root.clone();
    let index = data.join("dataset.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&index).unwrap()).unwrap();
    let held_out = split_frames(&scene, Split::TestSame).unwrap();
    assert_eq!(held_out.len(), 1);
    let x = &mut json["frames"][held_out[0]]["params"]["transl"][0];
    *x = serde_json::json!(x.as_f64().unwrap() + 0.04);
    std::fs::write(&index, serde_json::to_string_pretty(&json).unwrap()).unwrap();
    let dataset = Dataset::load(&data).unwrap();
    let run = common::temp_dir("pose_fit_run");
    let opts = common::small_train_opts(SamplerKind::Accelerated, 300);
    train(&dataset, &run, &opts, &mut |_| {}).unwrap();
    let before = files(&run);

    let fit_opts = FitPosesOptions {
        steps_per_frame: 60,
        lr: 3e-3,
    };
    let scratch = common::temp_dir("pose_fit_scratch");
    let mut heard = 0;
    let fitted = fit_held_out_poses(
        &dataset,
        &run,
        &held_out,
        &fit_opts,
        &scratch,
        &mut |done, total| {
            assert!(done <= total);
            heard += 1;
        },
    )
    .unwrap();
    assert_eq!((fitted.steps, heard), (60, 60));
    // The run is as it was: the field, its grids, its log.
    assert!(files(&run) == before, "the pose fit wrote into the run");

    // The correction moves the body back along x (by at least a quarter of the 4 cm)...
    let delta = &fitted.fits.delta[&held_out[0]];
    let dx = delta[delta.len() - 3];
    assert!(dx < -0.01, "x correction {dx} m");
    assert!(fitted.translation_mean_m > 0.01 && fitted.rotation_rms_deg.is_finite());
    // ...and the frame scores better at its fitted pose.
    let mut avatar = Avatar::load(&run).unwrap();
    let eval_opts = EvalOptions {
        renders_dir: None,
        lpips_dir: None,
        smooth: false,
        anchors: false,
    };
    let plain = evaluate(&avatar, &dataset, &held_out, &eval_opts).unwrap();
    avatar.refined = Some(fitted.fits.clone());
    let refit = evaluate(&avatar, &dataset, &held_out, &eval_opts).unwrap();
    assert!(
        refit.psnr > plain.psnr + 2.0,
        "{} -> {} dB",
        plain.psnr,
        refit.psnr
    );

    // `talkin eval --pose-fit`: the plain score as without it, the fit's beside it.
    let talkin = |json: &Path, extra: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
            .args(["eval", "--run", run.to_str().unwrap(), "--data"])
            .args([data.to_str().unwrap(), "--split", "test_same", "--json"])
            .arg(json)
            .args(["--lpips-dir", "/nonexistent"])
            .args(extra)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        (out.status.code(), stdout, stderr)
    };
    let report = |json: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap()
    };
    let out = common::temp_dir("pose_fit_eval");
    let (plain_json, fit_json) = (out.join("plain.json"), out.join("fit.json"));
    let (code, _, err) = talkin(&plain_json, &[]);
    assert_eq!(code, Some(0), "{err}");
    let (code, stdout, err) = talkin(&fit_json, &["--pose-fit", "5"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(stdout.contains("after a test-time pose fit"), "{stdout}");
    let (plain, fit) = (report(&plain_json), report(&fit_json));
    assert!(plain.get("pose_fit").is_none());
    assert_eq!(plain["psnr"], fit["psnr"]);
    let pose_fit = &fit["pose_fit"];
    assert_eq!(pose_fit["steps_per_frame"], 5);
    let key = held_out[0].to_string();
    assert!(pose_fit["corrections"][&key].as_array().unwrap().len() > 3);
    assert_eq!(pose_fit["report"]["frames_evaluated"], 1);
    let render = pose_fit["report"]["frames"][0]["render"].as_str().unwrap();
    assert!(Path::new(render).is_file(), "{render}");
    // Again into the same report: the renders are replaced, not refused.
    let (code, _, err) = talkin(&fit_json, &["--pose-fit", "5"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(files(&run) == before, "eval --pose-fit wrote into the run");

    // A rate that is not a positive number is named.
    let (code, _, err) = talkin(&fit_json, &["--pose-fit", "5", "--pose-fit-lr", "0"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("--pose-fit-lr"), "{err}");
}
