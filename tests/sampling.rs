//! The accelerated sampler on a small synthetic scene: no training pixel's true surface
//! point is lost, and it needs far fewer samples than the dense baseline; the initial
//! grid is carved to the training surfaces when depth is known.

mod common;

use glam::Vec3;
use talkin::avatar::scene::{
    CanonicalGrid, CapsuleShells, DilatedGrids, FrameSampler, FrameScene, canonical_surface_points,
    fit_subject_margins, foreground_rays, shell_capsules,
};
use talkin::benches::sampling::bench_sampling;
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::{
    MarginFitOpts, OccupancyGrid, PackedSamples, Part, Ray, SURFACE_SLACK_M, SamplerKind,
    sample_in_capsules, sample_in_front_of_cores,
};
use talkin::human::body::canonical_params;
use talkin::synth::{CaptureConfig, SynthConfig, generate};

/// The capsule shells the training masks and depth fit for subject 0.
fn first_subject_shells(dataset: &Dataset) -> CapsuleShells {
    fit_subject_margins(dataset, 0, &MarginFitOpts::default())
        .unwrap()
        .shells
}

/// One identity, six 96 px frames, seed 3; `capture` adds the capture-like flaws.
fn small_scene(capture: Option<CaptureConfig>) -> SynthConfig {
    SynthConfig {
        identities: 1,
        frames: 6,
        size: 96,
        seed: 3,
        motion: None,
        capture,
        framing: None,
    }
}

#[test]
fn accelerated_sampling_keeps_every_training_surface_point() {
    let dir = common::temp_dir("sampling_scene");
    generate(&small_scene(None), &dir, &mut |_, _| {}).unwrap();
    let dataset = Dataset::load(&dir).unwrap();
    let report = bench_sampling(&dataset, None, &mut |_, _| {}).unwrap();
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

/// With depth, the body and arm cells of the initial grid are carved to the training
/// surfaces: a subset of the capsule grid, far smaller, still holding every training
/// surface point and every hand capsule (novel finger poses are never carved away).
#[test]
fn the_initial_grid_is_carved_to_the_training_surfaces_when_depth_is_known() {
    let dataset = common::synthetic_scene("carve_scene", 1, 96, 5);
    let train = dataset.split_indices(Split::Train);
    let shells = first_subject_shells(&dataset);
    let points = canonical_surface_points(&dataset, &train, &shells)
        .unwrap()
        .expect("synthetic frames have depth");
    assert!(points.len() > 1000, "{}", points.len());
    let skeleton = &dataset.subjects[0].skeleton;
    let params = || train.iter().map(|&i| &dataset.frames[i].params);
    let full = CanonicalGrid::initial(skeleton, params(), &shells, 64, None).unwrap();
    let carved = CanonicalGrid::initial(skeleton, params(), &shells, 64, Some(&points)).unwrap();
    for i in 0..carved.num_cells() {
        assert!(
            !carved.is_cell_occupied(i) || full.is_cell_occupied(i),
            "cell {i}"
        );
    }
    assert!(
        carved.num_occupied() * 4 < full.num_occupied() * 3,
        "carved {} of {}",
        carved.num_occupied(),
        full.num_occupied()
    );
    for p in &points {
        assert!(!full.is_occupied(*p) || carved.is_occupied(*p), "{p}");
    }
    let canonical = skeleton.pose(&canonical_params());
    for c in shell_capsules(skeleton, &canonical) {
        if c.part == Part::Hands {
            assert!(carved.is_occupied(c.a.lerp(c.b, 0.5)), "{c:?}");
        }
    }
}

/// Without depth there is nothing to carve with: no surface points, and the grid keeps
/// the capsules.
#[test]
fn frames_without_depth_give_no_surface_points() {
    let dataset = common::write_tiny_dataset(&common::temp_dir("carve_no_depth"));
    let train = dataset.split_indices(Split::Train);
    let shells = first_subject_shells(&dataset);
    assert!(
        canonical_surface_points(&dataset, &train, &shells)
            .unwrap()
            .is_none()
    );
}

/// Without depth rays stop at no core (the skinning prior keeps them). The masks cannot
/// see a fit that sits nearer the camera than the person, and a core of such a fit lies
/// in front of the visible surface: the rays would stop there (on ZJU-MoCap 387 an
/// outstretched arm rendered as a black band). A capture-like scene whose fits are 4 cm
/// off, its shells fitted without its depth: every training pixel's true surface point
/// that the grown capsules hold is still sampled once the rays stop at their first core.
#[test]
fn fits_off_toward_the_camera_hide_no_surface_behind_a_core_without_depth() {
    let dir = common::temp_dir("sampling_biased_fits");
    let biased = CaptureConfig {
        smooth_skin_m: 0.0,
        fit_bias_deg: 0.0,
        fit_bias_m: 0.04,
        masks_only: false,
    };
    generate(&small_scene(Some(biased)), &dir, &mut |_, _| {}).unwrap();
    let with_depth = Dataset::load(&dir).unwrap();
    let mut masks_only = with_depth.clone();
    for frame in &mut masks_only.frames {
        frame.depth = None;
    }
    let shells = first_subject_shells(&masks_only);
    assert!(!shells.from_depth);
    let skeleton = &with_depth.subjects[0].skeleton;
    let canonical = skeleton.pose(&canonical_params());
    let bare = shell_capsules(skeleton, &canonical);
    assert!(
        !shells.cores(&bare).is_empty(),
        "the skinning prior keeps its cores"
    );
    let (mut held, mut behind_a_core) = (0usize, 0usize);
    for i in with_depth.split_indices(Split::Train) {
        let frame = &with_depth.frames[i];
        let scene = FrameScene::new(skeleton, &canonical, &frame.params);
        let images = with_depth.images(i).unwrap();
        let depth = with_depth
            .depth(i)
            .unwrap()
            .expect("the scene writes depth");
        let (labelled, pixels) = foreground_rays(&frame.camera, &images).unwrap();
        let rays: Vec<Ray> = labelled.iter().map(|l| l.ray).collect();
        let sampler = FrameSampler::new(scene, &shells, &rays, true).unwrap();
        let opts = sampler.accelerated_opts(Some(i as u64));
        let (capsules, cores) = sampler.bvhs().unwrap();
        let in_capsules = sample_in_capsules(capsules, &rays, &opts).unwrap();
        let in_front =
            sample_in_front_of_cores(capsules, cores, &rays, sampler.step, &opts).unwrap();
        let forward = frame.camera.forward_in_world().as_vec3();
        for (r, ray) in rays.iter().enumerate() {
            let Some(z) = depth[pixels[r] as usize] else {
                continue;
            };
            let t = z / ray.direction.dot(forward);
            if in_capsules.holds(r, t, SURFACE_SLACK_M) {
                held += 1;
                if !in_front.holds(r, t, SURFACE_SLACK_M) {
                    behind_a_core += 1;
                }
            }
        }
    }
    assert!(held > 1000, "{held}");
    assert_eq!(
        behind_a_core, 0,
        "{behind_a_core} of {held} surface points behind a core"
    );
}

/// Grids from elsewhere (a run trained on other data) are refused by name, not used.
#[test]
fn trained_grids_must_match_the_dataset() {
    let dataset = common::synthetic_scene("bench_trained_grids", 1, 64, 2);
    let other = OccupancyGrid::new(Vec3::ZERO, Vec3::ONE, [8, 8, 8]).unwrap();
    let err =
        bench_sampling(&dataset, Some(std::slice::from_ref(&other)), &mut |_, _| {}).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("subjects[0]") && msg.contains("trained on this dataset"),
        "{msg}"
    );
    let err = bench_sampling(&dataset, Some(&[other.clone(), other]), &mut |_, _| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("2 trained grids for 1 subjects"), "{err}");
}

/// Renders sample at the bins' regular places (`jitter: None`): adjacent bins of a ray
/// are equally wide, for both samplers; training's seeded jitter moves their shared
/// boundaries, and the same seed gives the same samples.
#[test]
fn unjittered_samples_sit_at_regular_bins() {
    let dataset = common::synthetic_scene("unjittered_scene", 1, 64, 4);
    let train = dataset.split_indices(Split::Train);
    let shells = first_subject_shells(&dataset);
    let skeleton = &dataset.subjects[0].skeleton;
    let params = train.iter().map(|&i| &dataset.frames[i].params);
    let grid = CanonicalGrid::initial(skeleton, params, &shells, 64, None).unwrap();
    let i = train[0];
    let frame = &dataset.frames[i];
    let canonical = skeleton.pose(&canonical_params());
    let scene = FrameScene::new(skeleton, &canonical, &frame.params);
    let (labelled, _) = foreground_rays(&frame.camera, &dataset.images(i).unwrap()).unwrap();
    let rays: Vec<_> = labelled.iter().map(|l| l.ray).collect();
    let sampler = FrameSampler::new(scene, &shells, &rays, true).unwrap();
    let dilated = DilatedGrids::default();
    // The largest width difference between adjacent bins of a ray, relative to the step.
    let spread = |s: &PackedSamples| {
        let mut worst = 0.0f32;
        for r in 0..s.num_rays() {
            let range = s.range(r);
            for k in range.start..range.end.saturating_sub(1) {
                if s.t_end[k] == s.t_start[k + 1] {
                    let (w0, w1) = (s.t_end[k] - s.t_start[k], s.t_end[k + 1] - s.t_start[k + 1]);
                    worst = worst.max((w0 - w1).abs());
                }
            }
        }
        worst / sampler.step
    };
    for kind in [SamplerKind::Accelerated, SamplerKind::Dense] {
        let regular = sampler.sample(kind, &rays, &grid, &dilated, None).unwrap();
        let jittered = sampler
            .sample(kind, &rays, &grid, &dilated, Some(7))
            .unwrap();
        assert!(regular.num_samples() > 1000, "{kind:?}");
        assert!(spread(&regular) < 1e-3, "{kind:?}: {}", spread(&regular));
        assert!(spread(&jittered) > 0.3, "{kind:?}: {}", spread(&jittered));
        let again = sampler
            .sample(kind, &rays, &grid, &dilated, Some(7))
            .unwrap();
        assert_eq!(again.t_start, jittered.t_start, "{kind:?}");
    }
}
