//! Rendering and evaluation end to end on a tiny synthetic scene trained for a few steps:
//! the eval JSON and its renders, metrics on synthetic images, crops, `talkin render`'s
//! frames and contact sheet, and bad input named without a panic.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use talkin::avatar::Avatar;
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::SamplerKind;
use talkin::human::body::joint;
use talkin::render::avatar::RENDER_CHUNK_SAMPLES;
use talkin::render::avatar::RenderFrame;
use talkin::render::eval::{
    self, CropKind, EvalOptions, HAND_TILE, HANDS_SHEET, LpipsScorer, PSNR_CAP_DB, Rect, evaluate,
    frame_crops, rescore_png,
};
use talkin::render::sequence::split_frames;
use talkin::train::train;

/// A two-identity scene (40x48 px) and a run trained on it for a few steps, made once.
fn scene() -> &'static (PathBuf, PathBuf) {
    static SCENE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let dataset = common::synthetic_scene("render_eval_data", 2, 48, 5);
        let data = dataset.root.clone();
        let run = common::temp_dir("render_eval_run");
        let opts = common::small_train_opts(SamplerKind::Accelerated, 6);
        train(&dataset, &run, &opts, &mut |_| {}).unwrap();
        (data, run)
    })
}

/// Where every command looks for the LPIPS weights (`talkin lpips-weights` writes there).
fn lpips_dir() -> PathBuf {
    talkin::nets::loss::lpips_weights_dir()
}

fn talkin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(args)
        .output()
        .unwrap()
}

/// `talkin ARGS` run from `cwd`: what an installed binary sees outside the repository.
fn talkin_in(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_talkin"))
        .current_dir(cwd)
        .args(args)
        .output()
        .unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn eval_json_has_the_keys_and_renders_that_rescore_the_same() {
    let (data, run) = scene();
    let out = common::temp_dir("render_eval_eval");
    let json = out.join("eval.json");
    let lpips = lpips_dir();
    // From a directory outside the repository and without --lpips-dir: the weights are
    // found where `talkin lpips-weights` put them.
    let res = talkin_in(
        &out,
        &[
            "eval",
            "--run",
            s(run),
            "--data",
            s(data),
            "--split",
            "test_cross",
            "--json",
            s(&json),
        ],
    );
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    let table = String::from_utf8_lossy(&res.stdout);
    assert!(table.contains("PSNR") && table.contains("hands"), "{table}");

    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for key in [
        "psnr",
        "ssim",
        "lpips",
        "psnr_person",
        "ssim_person",
        "lpips_person",
        "psnr_face",
        "ssim_face",
        "lpips_face",
        "psnr_hands",
        "ssim_hands",
        "lpips_hands",
        "person_inside",
        "person_outline",
        "person_around",
        "frames_evaluated",
        "split",
        "frames",
    ] {
        assert!(report.get(key).is_some(), "missing `{key}` in {report}");
    }
    assert_eq!(report["split"], "test_cross");
    let dataset = Dataset::load(data).unwrap();
    let expected = dataset.split_indices(Split::TestCross).len();
    assert_eq!(report["frames_evaluated"], expected);
    let frames = report["frames"].as_array().unwrap();
    assert_eq!(frames.len(), expected);
    // LPIPS is a number with the weights and null (with a note) without: never faked.
    let has_weights = lpips.join("alex.safetensors").exists();
    assert_eq!(report["lpips"].is_number(), has_weights, "{report}");
    assert_eq!(report["lpips_face"].is_number(), has_weights, "{report}");
    if !has_weights {
        eprintln!("SKIPPED (LPIPS part): no weights in {}", lpips.display());
        assert!(report["notes"].to_string().contains("LPIPS"), "{report}");
    }
    let psnr = report["psnr"].as_f64().unwrap();
    assert!(
        psnr.is_finite() && psnr > 3.0 && psnr < PSNR_CAP_DB,
        "{psnr}"
    );
    let ssim = report["ssim"].as_f64().unwrap();
    assert!((-1.0..1.0).contains(&ssim), "{ssim}");
    for f in frames {
        let index = f["frame"].as_u64().unwrap() as usize;
        assert_eq!(dataset.frames[index].split, Split::TestCross);
        let png = PathBuf::from(f["render"].as_str().unwrap());
        assert!(png.exists(), "{}", png.display());
        // Next to the JSON by default.
        assert_eq!(png.parent().unwrap(), out.join("eval_renders"));
        let again = rescore_png(&dataset, index, &png).unwrap();
        // The same score; JSON's shortest decimal form may move the last bit.
        let recorded = f["psnr"].as_f64().unwrap();
        assert!(
            (again - recorded).abs() <= 1e-12 * recorded.abs(),
            "frame {index}: {again} vs {recorded}"
        );
    }
    // The person box split by the mask: its regions tile the box, their errors add up
    // to the box's, and the shares to 1.
    for f in frames {
        let person = f["crops"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["kind"] == "person")
            .expect("a person box");
        let rect = &person["rect"];
        let area = rect["width"].as_f64().unwrap() * rect["height"].as_f64().unwrap();
        let regions = &f["person_regions"];
        let (mut pixels, mut share, mut se) = (0.0, 0.0, 0.0);
        for name in ["inside", "outline", "around"] {
            let r = &regions[name];
            let (n, p) = (r["pixels"].as_f64().unwrap(), r["psnr"].as_f64().unwrap());
            assert!(p < PSNR_CAP_DB, "{regions}");
            pixels += n;
            share += r["error_share"].as_f64().unwrap();
            se += n * 10f64.powf(-p / 10.0);
            let a = r["opacity"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&a), "{regions}");
        }
        // Even a briefly trained person is more solid than what lies around it.
        let opacity = |name: &str| regions[name]["opacity"].as_f64().unwrap();
        assert!(opacity("inside") > opacity("around"), "{regions}");
        assert_eq!(pixels, area, "{regions}");
        assert!((share - 1.0).abs() < 1e-9, "{regions}");
        let box_psnr = -10.0 * (se / area).log10();
        let recorded = person["psnr"].as_f64().unwrap();
        assert!(
            (box_psnr - recorded).abs() < 1e-6,
            "{box_psnr} vs {recorded}"
        );
    }
    assert!(table.contains("outline"), "{table}");
    let mean: f64 = frames
        .iter()
        .map(|f| f["psnr"].as_f64().unwrap())
        .sum::<f64>()
        / frames.len() as f64;
    assert!((mean - psnr).abs() < 1e-9);
    // The hands sheet: one truth | render | error row per scored hand crop, two rows side
    // by side beyond four.
    let hand_crops: usize = frames
        .iter()
        .map(|f| {
            f["crops"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|c| c["kind"].as_str().unwrap().ends_with("_hand"))
                .count()
        })
        .sum();
    assert!(hand_crops > 0);
    let sheet = image::open(out.join("eval_renders").join(HANDS_SHEET))
        .unwrap()
        .to_rgb8();
    let (per_row, tile) = (if hand_crops > 4 { 2 } else { 1 }, HAND_TILE + 2);
    assert_eq!(sheet.width(), per_row * 3 * tile + 2);
    assert_eq!(
        sheet.height(),
        (hand_crops as u32).div_ceil(per_row) * tile + 2
    );
    assert!(
        std::fs::read_dir(&out)
            .unwrap()
            .all(|e| { !e.unwrap().file_name().to_string_lossy().ends_with(".tmp") })
    );
}

/// `eval --background`: truth and render both over the colour. Were the truth left on the
/// dataset's white while the field renders over black, every background pixel would be
/// off by 1 and the frame would score a few dB (a matted dataset with a matte is refused:
/// `bad_input_exits_1_naming_the_file_and_field`). `synth`'s own matted frames, whose
/// masks are coverage, score over black as their copy composited by the masks does.
#[test]
fn eval_over_black_composites_the_truth_and_the_render() {
    let (matted, run) = scene();
    let out = common::temp_dir("render_eval_eval_black");
    // The scene's frames as camera frames composited by their masks (what `import` writes).
    let data = out.join("by_mask");
    common::copy_as_capture(matted, &data);
    let report = |name: &str, extra: &[&str]| {
        let json = out.join(format!("{name}.json"));
        let mut args = vec![
            "eval",
            "--run",
            s(run),
            "--data",
            s(&data),
            "--split",
            "test_same",
        ];
        args.extend(["--json", s(&json)]);
        args.extend_from_slice(extra);
        let res = talkin(&args);
        assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
        serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(json).unwrap()).unwrap()
    };
    let white = report("white", &["--background", "declared"]);
    let black = report("black", &["--background", "0,0,0"]);
    assert_eq!(white["background"], serde_json::json!([1.0, 1.0, 1.0]));
    assert_eq!(black["background"], serde_json::json!([0.0, 0.0, 0.0]));
    // Such a dataset is scored over black unless told otherwise, and the report says so.
    let default = report("default", &[]);
    assert_eq!(default["background"], black["background"]);
    assert_eq!(default["psnr_person"], black["psnr_person"]);
    let says = |r: &serde_json::Value| r["notes"].to_string().contains("scored over black");
    assert!(
        says(&default) && !says(&black) && !says(&white),
        "{}",
        default["notes"]
    );
    for report in [&white, &black] {
        let psnr = report["psnr"].as_f64().unwrap();
        assert!(psnr > 8.0 && psnr < PSNR_CAP_DB, "{report}");
    }
    // A capture is also scored by the anchors' protocol: the whole frame's PSNR, SSIM at
    // scikit-image 0.19's float range (above the engine's range-1 SSIM on the same
    // frames), LPIPS-VGG where its weights are installed; off on request.
    let anchors = &default["anchors"];
    assert_eq!(anchors["psnr"], default["psnr"]);
    assert_eq!(anchors["ssim_data_range"], 2.0);
    let ssim = anchors["ssim"].as_f64().unwrap();
    assert!(
        ssim > default["ssim"].as_f64().unwrap() - 0.05 && ssim <= 1.0,
        "{anchors}"
    );
    if lpips_dir().join("vgg.safetensors").exists() {
        assert!(anchors["lpips_vgg"].as_f64().unwrap() > 0.0, "{anchors}");
    }
    let off = report("anchors_off", &["--anchors", "off"]);
    assert!(off["anchors"].is_null() && off["frames"][0]["anchors"].is_null());
    let png = image::open(black["frames"][0]["render"].as_str().unwrap())
        .unwrap()
        .to_rgb8();
    assert_eq!(png[(0, 0)].0, [0; 3]);
    // The matted original, shown over black by its coverage: the same truth but on the
    // outline, where the copy read as camera frames keeps a share of the white (the
    // synth test checks the recomposited pixels themselves).
    let json = out.join("matted_black.json");
    let mut args = vec!["eval", "--run", s(run), "--data", s(matted)];
    args.extend(["--split", "test_same", "--json", s(&json)]);
    let res = talkin(&[args, vec!["--background", "0,0,0"]].concat());
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    let matted_black: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    let (a, b) = (
        matted_black["psnr_person"].as_f64().unwrap(),
        black["psnr_person"].as_f64().unwrap(),
    );
    assert_eq!(matted_black["background"], black["background"]);
    assert!((a - b).abs() < 1.0, "matted {a} by_mask {b}");
}

#[test]
fn renders_in_small_chunks_match_and_bound_the_samples_per_forward() {
    let (data, run) = scene();
    let dataset = Dataset::load(data).unwrap();
    let avatar = Avatar::load(run).unwrap();
    let frame = &dataset.frames[split_frames(&dataset, Split::TestSame).unwrap()[0]];
    let (subject, _) = avatar
        .subject(&dataset.subjects[frame.subject].name)
        .unwrap();
    for sampler in [SamplerKind::Dense, SamplerKind::Accelerated] {
        let whole = avatar
            .render(subject, &frame.params, &frame.camera, Some(sampler))
            .unwrap();
        // A dense ray has 128 samples: 300 forces chunks of two rays, some of one.
        let small = avatar
            .render_chunked(subject, &frame.params, &frame.camera, Some(sampler), 300)
            .unwrap();
        assert_eq!(whole.samples, small.samples, "{sampler:?}");
        assert_eq!(whole.labels, small.labels, "{sampler:?}");
        let worst = whole
            .rgb
            .iter()
            .chain(&whole.opacity)
            .zip(small.rgb.iter().chain(&small.opacity))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // The cap holds: a dense ray has 128 samples, so two fit under 300.
        assert!(small.largest_forward <= 300, "{}", small.largest_forward);
        assert!(whole.largest_forward <= RENDER_CHUNK_SAMPLES);
        assert!(
            worst < 1e-4,
            "{sampler:?}: chunks changed a pixel by {worst}"
        );
    }
    // The default cap splits this frame's dense chunk (1920 rays x 128 samples).
    let dense = avatar
        .render(
            subject,
            &frame.params,
            &frame.camera,
            Some(SamplerKind::Dense),
        )
        .unwrap();
    assert!(dense.samples > RENDER_CHUNK_SAMPLES, "{}", dense.samples);
    assert!(
        dense.largest_forward <= RENDER_CHUNK_SAMPLES,
        "{}",
        dense.largest_forward
    );
}

#[test]
fn library_eval_matches_identities_by_name_and_smooths() {
    let (data, run) = scene();
    let dataset = Dataset::load(data).unwrap();
    let avatar = Avatar::load(run).unwrap();
    let frames = split_frames(&dataset, Split::TestOod).unwrap();
    let plain = evaluate(&avatar, &dataset, &frames, &EvalOptions::default()).unwrap();
    assert_eq!(plain.frames_evaluated, frames.len());
    assert!(plain.lpips.is_none() && plain.lpips_note.is_some());
    for f in &plain.frames {
        assert_eq!(f.subject, f.rendered_as, "identity matched by name");
        assert!(f.render.is_none());
        assert!(f.crops.len() + f.skipped_crops.len() == CropKind::ALL.len());
    }
    let smooth = EvalOptions {
        smooth: true,
        ..EvalOptions::default()
    };
    let smoothed = evaluate(&avatar, &dataset, &frames, &smooth).unwrap();
    assert!(smoothed.smooth && smoothed.psnr.is_finite());
    assert!(
        plain
            .frames
            .iter()
            .zip(&smoothed.frames)
            .any(|(a, b)| a.psnr != b.psnr),
        "smoothing changed no render"
    );
    assert!(matches!(
        evaluate(&avatar, &dataset, &[], &EvalOptions::default()),
        Err(eval::EvalError::NoFrames)
    ));
    let e = evaluate(&avatar, &dataset, &[10_000], &EvalOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("10000") && e.contains("out of range"), "{e}");
}

#[test]
fn perfect_and_noisy_images_score_as_they_must() {
    let (data, _) = scene();
    let dataset = Dataset::load(data).unwrap();
    let truth = dataset.images(0).unwrap().rgb;
    let full = Rect::full(&truth);
    assert_eq!(eval::psnr(&truth, &truth, full), PSNR_CAP_DB);
    assert!((eval::ssim(&truth, &truth, full).unwrap() - 1.0).abs() < 1e-12);
    // Seeded +-10 noise on every value that stays in range: PSNR = 20 log10(255 / 10).
    let mut noisy = truth.clone();
    let mut state = 7u32;
    for p in noisy.pixels_mut() {
        for v in p.0.iter_mut() {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let up = (state >> 16) & 1 == 1;
            *v = if (up && *v <= 245) || *v < 10 {
                *v + 10
            } else {
                *v - 10
            };
        }
    }
    let got = eval::psnr(&truth, &noisy, full);
    let want = 20.0 * (255.0f64 / 10.0).log10();
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    let s = eval::ssim(&truth, &noisy, full).unwrap();
    assert!(s < 0.99 && s > 0.3, "{s}");
    if let Ok(scorer) =
        LpipsScorer::from_dir(Some(&lpips_dir()), &burn::prelude::Device::flex()).unwrap()
    {
        let same = scorer.distance(&truth, &truth, full).unwrap();
        let diff = scorer.distance(&truth, &noisy, full).unwrap();
        assert!(same.abs() < 1e-6 && diff > 1e-3, "{same} {diff}");
    }
    let missing = LpipsScorer::from_dir(
        Some(Path::new("/nonexistent")),
        &burn::prelude::Device::flex(),
    )
    .unwrap();
    assert!(missing.err().unwrap().contains("/nonexistent"));
}

#[test]
fn crops_lie_inside_and_contain_the_head_and_wrists() {
    let (data, _) = scene();
    let dataset = Dataset::load(data).unwrap();
    let mut checked = 0;
    for f in &dataset.frames {
        let skeleton = &dataset.subjects[f.subject].skeleton;
        let posed = skeleton.pose(&f.params);
        for (kind, crop) in frame_crops(skeleton, &f.params, &f.camera) {
            let r = crop.unwrap_or_else(|why| panic!("{kind:?}: {why}"));
            assert!(r.is_inside(f.camera.width, f.camera.height), "{r:?}");
            assert!(r.width >= eval::MIN_CROP.min(f.camera.width.min(f.camera.height)));
            if kind != CropKind::Person {
                assert_eq!(r.width, r.height);
            }
            let j = match kind {
                CropKind::Person => joint::PELVIS,
                CropKind::Face => joint::HEAD,
                CropKind::LeftHand => joint::LEFT_WRIST,
                CropKind::RightHand => joint::RIGHT_WRIST,
            };
            let p = f.camera.project(posed.joint(j)).unwrap();
            let in_image = p.x >= 0.0
                && p.y >= 0.0
                && p.x < f.camera.width as f64
                && p.y < f.camera.height as f64;
            if in_image {
                assert!(r.contains(p.x, p.y), "{kind:?} {r:?} misses {p:?}");
                checked += 1;
            }
        }
    }
    assert!(checked >= dataset.frames.len() * 2, "{checked}");
}

#[test]
fn render_writes_frames_and_a_contact_sheet() {
    let (data, run) = scene();
    // test_ood of the scene, smoothed, into `out`, with `extra` flags.
    let render_ood = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "render",
            "--run",
            s(run),
            "--data",
            s(data),
            "--split",
            "test_ood",
            "--out",
            s(out),
            "--smooth",
        ];
        args.extend_from_slice(extra);
        let res = talkin(&args);
        assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    };
    let out = common::temp_dir("render_eval_render");
    render_ood(&out, &[]);
    let dataset = Dataset::load(data).unwrap();
    let n = dataset.split_indices(Split::TestOod).len();
    for k in 0..n {
        let img = image::open(out.join(format!("frame_{k:04}.png"))).unwrap();
        assert_eq!((img.width(), img.height()), (40, 48));
    }
    assert!(!out.join(format!("frame_{n:04}.png")).exists());
    // Over black: the same frame, its corner (no capsule reaches it) black, not white.
    let black = common::temp_dir("render_eval_render_black");
    render_ood(&black, &["--background", "0,0,0"]);
    let corner = |dir: &Path| image::open(dir.join("frame_0000.png")).unwrap().to_rgb8()[(0, 0)].0;
    assert_eq!(corner(&out), [255; 3]);
    assert_eq!(corner(&black), [0; 3]);
    let sheet = image::open(out.join("contact_sheet.png")).unwrap();
    // Three tiles a frame (two triplets a row beyond four frames), 2 px gaps.
    let (cols, rows) = if n > 4 { (6, n.div_ceil(2)) } else { (3, n) };
    assert_eq!(sheet.width(), cols * (40 + 2) + 2);
    assert_eq!(sheet.height() as usize, rows * (48 + 2) + 2);

    // The poses of one subject rendered as the other, from a poses file (dataset.json's
    // frame objects, so the dataset itself is a valid poses file): no ground truth, no sheet.
    let poses_out = common::temp_dir("render_eval_render_poses");
    let poses = poses_out.join("poses.json");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("dataset.json")).unwrap()).unwrap();
    let ada: Vec<_> = doc["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["subject"] == 0)
        .take(3)
        .map(|f| serde_json::json!({"params": f["params"], "camera": f["camera"]}))
        .collect();
    std::fs::write(&poses, serde_json::json!({ "frames": ada }).to_string()).unwrap();
    let frames_dir = poses_out.join("frames");
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--poses",
        s(&poses),
        "--subject",
        "ben",
        "--out",
        s(&frames_dir),
        "--smooth",
    ]);
    assert_eq!(res.status.code(), Some(0), "{}", stderr(&res));
    assert!(frames_dir.join("frame_0002.png").exists());
    assert!(!frames_dir.join("contact_sheet.png").exists());
    // Two trained subjects: --poses must say which.
    let res = talkin(&[
        "render",
        "--run",
        s(run),
        "--poses",
        s(&poses),
        "--out",
        s(&frames_dir),
    ]);
    assert_eq!(res.status.code(), Some(1));
    assert!(stderr(&res).contains("ada, ben"), "{}", stderr(&res));
}

#[test]
fn bad_input_exits_1_naming_the_file_and_field() {
    let (data, run) = scene();
    let dir = common::temp_dir("render_eval_bad");
    let json = dir.join("eval.json");
    let check = |args: &[&str], needles: &[&str]| {
        let res = talkin(args);
        let err = stderr(&res);
        assert_eq!(res.status.code(), Some(1), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        for n in needles {
            assert!(err.contains(n), "{args:?}: `{n}` not in: {err}");
        }
    };
    // A background that is not three numbers in [0, 1].
    for bad in ["1,2", "0,0,2", "0,nan,0", "white"] {
        check(
            &[
                "render",
                "--run",
                s(run),
                "--data",
                s(data),
                "--split",
                "test_ood",
                "--out",
                s(&dir.join("never")),
                "--background",
                bad,
            ],
            &["--background", "R,G,B", bad],
        );
    }
    assert!(!dir.join("never").exists());
    let eval = |split: &str, extra: &[&str], needles: &[&str]| {
        let mut args = vec!["eval", "--run", s(run), "--data", s(data), "--split", split];
        args.extend(["--json", s(&json)]);
        args.extend_from_slice(extra);
        check(&args, needles);
        assert!(!json.exists(), "no report for a failed evaluation");
    };
    // Unknown split.
    eval("test_nope", &[], &["test_nope", "test_same"]);
    // Scored over another colour: a bad colour, and a matted dataset whose masks are a
    // matte (not `synth`'s coverage), which cannot take the white out of its edge pixels.
    eval(
        "test_same",
        &["--background", "0,0"],
        &["--background", "R,G,B"],
    );
    let matte = dir.join("matte");
    common::copy_dir(data, &matte);
    let doc = matte.join("dataset.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&doc).unwrap()).unwrap();
    assert_eq!(v["masks"], "coverage", "synth writes coverage masks");
    v.as_object_mut().unwrap().remove("masks");
    std::fs::write(&doc, v.to_string()).unwrap();
    let mut args = vec!["eval", "--run", s(run), "--data", s(&matte)];
    args.extend(["--split", "test_same", "--json", s(&json)]);
    args.extend(["--background", "0,0,0"]);
    check(&args, &["dataset.json", "masks", "coverage"]);
    assert!(!json.exists(), "no report for a failed evaluation");
    // Unknown subject.
    check(
        &[
            "render",
            "--run",
            s(run),
            "--data",
            s(data),
            "--split",
            "test_same",
            "--subject",
            "zed",
            "--out",
            s(&dir.join("f")),
        ],
        &["zed", "ada"],
    );
    // A poses file with a short body_pose in its fourth frame.
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("dataset.json")).unwrap()).unwrap();
    let frame = serde_json::json!({"params": doc["frames"][0]["params"], "camera": doc["frames"][0]["camera"]});
    let mut bad = serde_json::json!({"frames": [frame, frame, frame, frame]});
    bad["frames"][3]["params"]["body_pose"] = serde_json::json!([[0.0, 0.0, 0.0]]);
    let poses = dir.join("poses.json");
    std::fs::write(&poses, bad.to_string()).unwrap();
    let render = |p: &Path| {
        [
            "render".to_string(),
            "--run".into(),
            s(run).into(),
            "--poses".into(),
            s(p).into(),
            "--subject".into(),
            "ada".into(),
            "--out".into(),
            s(&dir.join("g")).into(),
        ]
    };
    let args = render(&poses);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    check(
        &args,
        &["poses.json", "frames[3].params.body_pose", "21 x 3"],
    );
    // NaN as Python writes it: not JSON, and the message says so.
    let mut zero_jaw = serde_json::json!({"frames": [frame, frame]});
    zero_jaw["frames"][1]["params"]["jaw_pose"] = serde_json::json!([0.0, 0.0, 0.0]);
    let text = zero_jaw.to_string();
    assert!(text.contains("\"jaw_pose\":[0.0,0.0,0.0]"), "{text}");
    let nan = dir.join("nan.json");
    std::fs::write(
        &nan,
        text.replace("\"jaw_pose\":[0.0,0.0,0.0]", "\"jaw_pose\":[NaN,0.0,0.0]"),
    )
    .unwrap();
    let args = render(&nan);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    check(&args, &["nan.json", "NaN and Infinity are not JSON"]);
    // A NaN that does parse (a string): the field is named.
    let mut bad = serde_json::json!({"frames": [frame]});
    bad["frames"][0]["params"]["expression"][4] = serde_json::json!("NaN");
    std::fs::write(&poses, bad.to_string()).unwrap();
    let args = render(&poses);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    check(&args, &["poses.json", "frames[0].params.expression[4]"]);
    // A missing poses file and a missing run.
    let args = render(&dir.join("absent.json"));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    check(&args, &["absent.json"]);
    check(
        &[
            "eval",
            "--run",
            s(&dir),
            "--data",
            s(data),
            "--split",
            "test_same",
            "--json",
            s(&json),
        ],
        &["no checkpoint"],
    );
}
