use std::path::PathBuf;

use serde_json::{Value, json};

use super::*;
use crate::DEFAULT_LPIPS_DIR;

/// `options` of a run's `state.json` as the last build without a recipe version wrote it:
/// `talkin train --steps 3 --batch 128 --patches 0 --grid-resolution 32 --seed 5
/// --frame-codes 8 --frame-code-deform on --mask-edge 1 --random-background on
/// --refine-poses on --pose-warmup 2 --hand-deform off --lr 0.02`.
const UNVERSIONED: &str = include_str!("../../../tests/fixtures/options-unversioned.json");

fn read(json: Value) -> Result<TrainOptions, String> {
    from_json(json)
}

#[test]
fn a_run_saved_before_versions_reads_as_it_trained() {
    let opts = read(serde_json::from_str(UNVERSIONED).unwrap()).unwrap();
    assert_eq!(
        opts,
        TrainOptions {
            budget: Budget::Steps(3),
            batch_rays: 128,
            patches: 0,
            grid_resolution: 32,
            seed: 5,
            frame_code_dim: 8,
            frame_code_deform: true,
            mask_edge_px: Some(1),
            random_background: true,
            lr: Some(0.02),
            perceptual: Some(PathBuf::from("/root/.cache/talkin/lpips")),
            ablation: Ablation {
                use_d_hands: false,
                ..Ablation::default()
            },
            refine: RefineOptions {
                refine_poses: RefineMode::On,
                pose_warmup: 2,
                ..RefineOptions::default()
            },
            ..TrainOptions::default()
        }
    );
}

/// Written and read back, every option survives, the recipe's version is written, and
/// the names on disk are the ones runs have always written.
#[test]
fn the_record_round_trips_and_keeps_its_names() {
    let opts = TrainOptions {
        identities: Identities::Named(vec!["ada".into()]),
        budget: Budget::Seconds(90.0),
        clip_seconds: Some(3.0),
        perceptual: Some(DEFAULT_LPIPS_DIR.clone()),
        mlp_fused: false,
        mlp_slice_rows: 0,
        ..TrainOptions::default()
    };
    let json = to_json(&opts).unwrap();
    assert_eq!(json["version"], RECIPE_VERSION);
    assert_eq!(json["preset"], "fast");
    assert_eq!(json["sampler"], "accelerated");
    assert_eq!(json["budget"], json!({"seconds": 90.0}));
    assert_eq!(json["identities"], json!(["ada"]));
    assert_eq!(json["skin_fingers"], "bones");
    assert_eq!(json["refine"]["refine_poses"], "auto");
    let unversioned: Value = serde_json::from_str(UNVERSIONED).unwrap();
    // Every name a run before versions wrote, and the fields added since (absent from
    // older records, which read as those runs trained: the next test).
    const ADDED: [&str; 6] = [
        "hash_levels",
        "hash_table_log2",
        "plan",
        "density",
        "hard_surface",
        "frame_code_dropout",
    ];
    let mut names: Vec<&str> = json
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    names.retain(|n| *n != "version" && !ADDED.contains(n));
    let old_names: Vec<&str> = unversioned
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(names, old_names);
    for added in ADDED {
        assert!(unversioned.get(added).is_none() && json.get(added).is_some());
    }
    assert_eq!(read(json).unwrap(), opts);
    let all = to_json(&TrainOptions::default()).unwrap();
    assert!(all["identities"].is_null());
}

#[cfg(unix)]
#[test]
fn a_lpips_path_that_is_not_utf8_round_trips() {
    use std::os::unix::ffi::OsStrExt;
    let dir = PathBuf::from(std::ffi::OsStr::from_bytes(b"/tmp/lp\xffips"));
    let opts = TrainOptions {
        perceptual: Some(dir),
        ..TrainOptions::default()
    };
    let json = to_json(&opts).unwrap();
    assert!(json["perceptual"].is_object());
    assert_eq!(read(json).unwrap(), opts);
}

/// What a field's absence means: what runs recorded before it existed did.
#[test]
fn absent_fields_read_as_the_runs_before_them_trained() {
    let mut json: Value = serde_json::from_str(UNVERSIONED).unwrap();
    let object = json.as_object_mut().unwrap();
    for field in [
        "device",
        "skin_fingers",
        "mlp_fused",
        "mlp_slice_rows",
        "lr",
        "mask_weight",
        "distortion",
        "frame_code_dim",
        "frame_code_deform",
        "random_background",
        "mask_edge_px",
        "non_rigid_lr_scale",
        "perceptual",
        "ablation",
        "clip_seconds",
        "refine",
    ] {
        object.remove(field);
    }
    let opts = read(json).unwrap();
    assert_eq!(opts.skin_fingers, FingerSkinning::Wrist);
    assert!(opts.mlp_fused);
    assert_eq!(opts.mlp_slice_rows, 256);
    assert_eq!(opts.lr, None);
    assert_eq!((opts.mask_weight, opts.distortion), (0.0, 0.0));
    assert_eq!((opts.frame_code_dim, opts.frame_code_deform), (0, false));
    assert_eq!(opts.frame_code_dropout, 0.0);
    assert!(!opts.random_background);
    assert_eq!(opts.mask_edge_px, Some(0));
    assert_eq!(opts.non_rigid_lr_scale, 1.0);
    assert_eq!(opts.perceptual, None);
    assert_eq!(opts.ablation, Ablation::default());
    assert_eq!(opts.clip_seconds, None);
    assert_eq!(opts.refine.refine_poses, RefineMode::Off);
    // Fields no version-0 record holds: the preset's grid, no plan, every part built,
    // softplus density and no hard-surface term.
    assert_eq!((opts.hash_levels, opts.hash_table_log2), (None, None));
    assert_eq!(
        (opts.density, opts.hard_surface),
        (talkin_nets::Density::Softplus, 0.0)
    );
    assert!(opts.plan.is_none());
    // Inside the refinement record, the jitter rate came last.
    let mut json: Value = serde_json::from_str(UNVERSIONED).unwrap();
    json["refine"]
        .as_object_mut()
        .unwrap()
        .remove("pose_lr_jitter");
    assert_eq!(read(json).unwrap().refine.pose_lr_jitter, 5e-3);
}

#[test]
fn a_newer_builds_record_is_refused_naming_its_version() {
    let mut json: Value = serde_json::from_str(UNVERSIONED).unwrap();
    json["version"] = json!(RECIPE_VERSION + 1);
    let err = read(json).unwrap_err();
    assert!(err.contains("`version`") && err.contains("newer"), "{err}");
    let mut json: Value = serde_json::from_str(UNVERSIONED).unwrap();
    json["perceptual"] = json!(7);
    assert!(read(json).unwrap_err().contains("`perceptual`"));
    let mut json: Value = serde_json::from_str(UNVERSIONED).unwrap();
    json.as_object_mut().unwrap().remove("preset");
    assert!(read(json).unwrap_err().contains("preset"));
}

/// A run that never checkpoints on a clock (the benches' runs) records `null`, and reads
/// back as never: its checkpoint can be resumed and stepped on.
#[test]
fn a_period_of_never_round_trips_as_null() {
    let opts = TrainOptions {
        checkpoint_every_s: f64::INFINITY,
        ..TrainOptions::default()
    };
    let json = to_json(&opts).unwrap();
    assert!(json["checkpoint_every_s"].is_null(), "{json}");
    assert_eq!(from_json(json).unwrap().checkpoint_every_s, f64::INFINITY);
    let opts = TrainOptions {
        checkpoint_every_s: 90.0,
        ..TrainOptions::default()
    };
    assert_eq!(
        from_json(to_json(&opts).unwrap())
            .unwrap()
            .checkpoint_every_s,
        90.0
    );
}
