//! Pose refinement end to end: a refining run learns corrections, records them in its
//! checkpoint and resumes them exactly, renders its training frames in the refined pose
//! (held-out frames as fitted), and `talkin export-poses` writes them in the dataset's
//! layout; a run that trusted its fits has nothing to export and says so.
//!
//! Its own test binary: one trainer at a time in the process (see tests/resume.rs).

mod common;

use std::process::Command;

use talkin::avatar::Avatar;
use talkin::grids::SamplerKind;
use talkin::render::sequence::shots_from_frames;
use talkin::train::refine::{RefineMode, RefineOptions};
use talkin::train::{Trainer, train};

#[test]
fn refinement_learns_resumes_exactly_renders_and_exports() {
    let dataset = common::synthetic_scene("refine_scene", 1, 48, 1);
    let mut opts = common::small_train_opts(SamplerKind::Accelerated, 8);
    opts.refine = RefineOptions {
        refine_poses: RefineMode::On,
        pose_warmup: 2,
        ..RefineOptions::default()
    };
    let run = common::temp_dir("refine_run");
    let mut t = Trainer::new(&dataset, &run, &opts).unwrap();
    for _ in 0..5 {
        t.step().unwrap();
    }
    t.save().unwrap();
    let saved = t.refiner().unwrap().state.clone();
    let moved = saved
        .delta
        .iter()
        .filter(|d| d.iter().any(|&v| v != 0.0))
        .count();
    assert!(
        moved >= 1,
        "no frame's correction moved in 3 refining steps"
    );
    assert!(saved.delta.iter().flatten().all(|v| v.is_finite()));
    drop(t);

    // The checkpoint gives back the corrections and their optimizer to the bit.
    let resumed = Trainer::resume(&dataset, &run).unwrap();
    assert_eq!(resumed.refiner().unwrap().state, saved);
    resumed.run(&mut |_| {}).unwrap();

    // Training frames render refined, held-out frames as fitted.
    let avatar = Avatar::load(&run).unwrap();
    let refined = avatar
        .refined
        .as_ref()
        .expect("the avatar reads the corrections");
    let frames: Vec<usize> = (0..dataset.frames.len()).collect();
    let shots = shots_from_frames(&avatar, &dataset, &frames, None).unwrap();
    let mut changed = 0;
    for (i, shot) in shots.iter().enumerate() {
        let fit = &dataset.frames[i].params;
        if refined.delta.contains_key(&i) {
            changed += usize::from(shot.params != *fit);
        } else {
            assert_eq!(
                shot.params, *fit,
                "held-out frame {i} was not rendered as fitted"
            );
        }
    }
    assert!(changed >= 1);

    // export-poses: the dataset's layout, training frames refined.
    let out = run.join("refined.json");
    let status = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["export-poses", "--run"])
        .arg(&run)
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(&out).unwrap();
    let exported = talkin::data::dataset::Dataset::from_json_str(&text, &dataset.root).unwrap();
    assert_eq!(exported.frames.len(), dataset.frames.len());
    for (i, f) in exported.frames.iter().enumerate() {
        let want = refined
            .params(&dataset, &refined.dataset_sha256, i)
            .unwrap_or_else(|| dataset.frames[i].params.clone());
        let worst = talkin::human::body::FrameParams::local_rotations(&f.params)
            .iter()
            .zip(want.local_rotations().iter())
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0f64, f64::max);
        assert!(worst < 1e-6, "frame {i}: {worst}");
    }

    // A run that trusted its fits: a named error and a non-zero exit.
    let plain = common::temp_dir("refine_plain");
    let mut plain_opts = common::small_train_opts(SamplerKind::Accelerated, 2);
    plain_opts.refine.refine_poses = RefineMode::Off;
    train(&dataset, &plain, &plain_opts, &mut |_| {}).unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["export-poses", "--run"])
        .arg(&plain)
        .arg("--out")
        .arg(plain.join("refined.json"))
        .output()
        .unwrap();
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        err.contains("state.json") && err.contains("--refine-poses"),
        "{err}"
    );
    assert!(!plain.join("refined.json").exists());
}
