//! The speed-vs-error benchmark end to end on a tiny scene with budgets of seconds: the
//! report's structure (every file, every key, one value per target, the sweep's pick),
//! not its numbers.

mod common;

use talkin::benches::speed_vs_error::{SpeedVsErrorOptions, speed_vs_error};
use talkin::grids::SamplerKind;

#[test]
fn reports_time_to_each_target_for_both_samplers() {
    let dataset = common::synthetic_scene("speed_vs_error_scene", 1, 32, 2);
    let out = common::temp_dir("speed_vs_error_report");
    let opts = SpeedVsErrorOptions {
        // The first is met by the untrained field (a run still trains to its next mark,
        // so its steps have a cost); the last is out of reach of seconds of training.
        targets_db: vec![0.0, 11.0, 60.0],
        accelerated_s: 2.0,
        dense_s: 1.0,
        eval_frames: 1,
        eval_every_s: Some(1.0),
        dense_lrs: vec![1e-2, 2e-2],
        dense_sweep_s: 0.3,
        train: common::small_train_opts(SamplerKind::Accelerated, 1),
        lpips_dir: None,
    };
    let mut heard = Vec::new();
    let summary =
        speed_vs_error(&dataset, &out, &opts, &mut |m| heard.push(m.to_string())).unwrap();
    assert!(!heard.is_empty());

    for file in [
        "summary.json",
        "report.md",
        "speed_vs_error.csv",
        "speed_vs_error.png",
    ] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
    for run in ["accelerated", "dense"] {
        assert!(
            out.join("runs").join(run).join("checkpoint").is_dir(),
            "{run}"
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let n = opts.targets_db.len();
    assert_eq!(json["targets_db"].as_array().unwrap().len(), n);
    for key in ["speedup_at_target", "is_lower_bound"] {
        assert_eq!(json[key].as_array().unwrap().len(), n, "{key}");
    }
    for key in [
        "highest_common_target_db",
        "speedup_at_highest_common_target",
        "highest_common_is_lower_bound",
    ] {
        assert!(json.get(key).is_some(), "{key}");
    }
    for sampler in ["accelerated", "dense"] {
        for key in ["seconds_to_target", "steps_to_target"] {
            assert_eq!(
                json[sampler][key].as_array().unwrap().len(),
                n,
                "{sampler}.{key}"
            );
        }
        // 60 dB is never reached.
        assert!(json[sampler]["seconds_to_target"][2].is_null(), "{sampler}");
        assert!(json[sampler]["cost"]["median_step_s"].as_f64().unwrap() > 0.0);
        assert_eq!(json[sampler]["seconds_to_target"][0].as_f64(), Some(0.0));
    }
    assert_eq!(
        json["dense"]["cost"]["bones_per_sample"].as_f64(),
        Some(22.0)
    );
    assert!(
        json["accelerated"]["cost"]["bones_per_sample"]
            .as_f64()
            .unwrap()
            < 22.0
    );
    assert_eq!(summary.speedup_at_target[2], None);
    assert!(!summary.is_lower_bound[2]);

    // The sweep: one run per rate, one chosen, and the dense run trains at it.
    assert_eq!(summary.dense_lr_sweep.len(), 2);
    let chosen: Vec<_> = summary.dense_lr_sweep.iter().filter(|r| r.chosen).collect();
    assert_eq!(chosen.len(), 1);
    assert_eq!(summary.dense.lr, chosen[0].lr);
    assert_eq!(summary.accelerated.lr, opts.train.initial_lr());

    // Every evaluation is a CSV row: both runs from their untrained start, one row per
    // sweep run.
    let csv = std::fs::read_to_string(out.join("speed_vs_error.csv")).unwrap();
    let runs: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    assert_eq!(runs.len(), summary.points.len());
    assert_eq!(
        runs.iter().filter(|r| r.starts_with("dense-sweep")).count(),
        2
    );
    for run in ["accelerated", "dense"] {
        let first = summary.points.iter().find(|p| p.run == run).unwrap();
        assert_eq!((first.seconds, first.steps), (0.0, 0), "{run}");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("speed-up") && report.contains("learning-rate sweep"));
}
