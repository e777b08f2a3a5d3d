//! The accelerated sampler on a small synthetic scene: no training pixel's true surface
//! point is lost, and it needs far fewer samples than the dense baseline.

mod common;

use talkin::engine::dataset::Dataset;
use talkin::engine::sampling::bench_sampling;
use talkin::engine::synth::{SynthConfig, generate};

#[test]
fn accelerated_sampling_keeps_every_training_surface_point() {
    let dir = common::temp_dir("sampling_scene");
    let cfg = SynthConfig {
        identities: 1,
        frames: 6,
        size: 96,
        seed: 3,
        motion: None,
    };
    generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    let dataset = Dataset::load(&dir).unwrap();
    let report = bench_sampling(&dataset, &mut |_, _| {}).unwrap();
    assert!(report.foreground_rays > 1000, "{report:?}");
    assert_eq!(report.surface_checked_rays, report.foreground_rays);
    assert_eq!(report.surface_misses_by_split["train"], 0, "{report:?}");
    assert!(
        (report.dense_samples_per_ray - 128.0).abs() < 1e-9,
        "every foreground ray crosses the box"
    );
    assert!(
        report.accelerated_samples_per_ray < 0.5 * report.dense_samples_per_ray,
        "{} vs {}",
        report.accelerated_samples_per_ray,
        report.dense_samples_per_ray
    );
    assert!(report.truncated_samples_per_ray <= report.capsule_samples_per_ray);
    for (part, cover) in &report.coverage_by_part {
        assert!(cover.train_coverage >= 0.9999, "{part}: {cover:?}");
    }
}
