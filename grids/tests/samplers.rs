//! Dense and accelerated samplers: packed layout, coverage against plain references,
//! candidates, culling, determinism, bad input.

mod common;

use common::{random_rays, random_scene};
use glam::{Vec3, vec3};
use talkin_grids::intersect::{distance_to_segment, ray_capsule};
use talkin_grids::{
    ALL_BONES, ALL_PARTS, AcceleratedOpts, Capsule, CapsuleBvh, DenseOpts, GridError,
    OccupancyGrid, PackedSamples, Ray, cull_with_grid, sample_dense, sample_in_capsules,
    sample_reference,
};

fn scene() -> (Vec<Capsule>, Vec<Ray>) {
    let scene = random_scene(11, 60);
    let rays = random_rays(12, 400, &scene);
    (scene, rays)
}

/// Rays whose `t_max` is infinite are capped so the posed box test below is meaningful.
const BOX_MIN: Vec3 = Vec3::splat(-1.3);
const BOX_MAX: Vec3 = Vec3::splat(1.3);

#[test]
fn dense_layout_and_box_tiling() {
    let (_, rays) = scene();
    let s = sample_dense(&rays, BOX_MIN, BOX_MAX, &DenseOpts::default()).unwrap();
    s.check_layout().unwrap();
    assert_eq!(s.num_rays(), rays.len());
    let mut rays_in_box = 0;
    for (i, r) in rays.iter().enumerate() {
        let range = s.range(i);
        if range.is_empty() {
            // A miss: no point of the ray range may be in the box (checked coarsely).
            for k in 0..=200 {
                let t = r.t_min + (r.t_max.min(10.0) - r.t_min) * k as f32 / 200.0;
                let p = r.at(t);
                assert!(
                    !(p.cmpgt(BOX_MIN + 1e-3).all() && p.cmplt(BOX_MAX - 1e-3).all()),
                    "ray {i} got no samples but passes through the box at t = {t}"
                );
            }
            continue;
        }
        rays_in_box += 1;
        assert_eq!(range.len(), 128);
        // Contiguous bins, tiling the chord.
        for s0 in range.start..range.end - 1 {
            assert_eq!(s.t_end[s0], s.t_start[s0 + 1]);
        }
        let (t0, t1) = (s.t_start[range.start], s.t_end[range.end - 1]);
        assert!(t0 >= r.t_min && t1 <= r.t_max);
        for p in [r.at(t0), r.at(t1), r.at(0.5 * (t0 + t1))] {
            assert!(
                p.cmpge(BOX_MIN - 1e-4).all() && p.cmple(BOX_MAX + 1e-4).all(),
                "{p}"
            );
        }
        assert!(range.clone().all(|k| s.part_mask[k] == ALL_PARTS));
        assert!(range.clone().all(|k| s.bone_mask[k] == ALL_BONES));
    }
    assert!(rays_in_box > 300, "{rays_in_box}");
}

#[test]
fn dense_jitter_is_stratified_and_deterministic() {
    let r = Ray::new(vec3(0.0, 0.0, -3.0), Vec3::Z, 0.0, f32::INFINITY).unwrap();
    let regular = sample_dense(
        &[r],
        BOX_MIN,
        BOX_MAX,
        &DenseOpts {
            jitter: false,
            ..Default::default()
        },
    )
    .unwrap();
    let width = 2.6 / 128.0;
    for k in 0..128 {
        assert!((regular.t_start[k] - (1.7 + k as f32 * width)).abs() < 1e-5);
    }
    let a = sample_dense(&[r, r], BOX_MIN, BOX_MAX, &DenseOpts::default()).unwrap();
    let b = sample_dense(&[r, r], BOX_MIN, BOX_MAX, &DenseOpts::default()).unwrap();
    assert_eq!(a, b);
    assert_ne!(
        a.t_start[..128],
        a.t_start[128..],
        "rays must get their own jitter"
    );
    for k in 0..128 {
        // Each midpoint stays within its stratum (one bin around its regular place).
        assert!((a.t_mid(k) - regular.t_mid(k)).abs() < width, "{k}");
    }
}

/// Every `t` inside any capsule (by point-to-segment distance) lies in some accelerated
/// sample of the ray, and every sample midpoint lies inside a capsule.
#[test]
fn accelerated_covers_exactly_the_capsules() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let opts = AcceleratedOpts {
        step: 0.02,
        jitter: true,
        seed: 5,
    };
    let s = sample_in_capsules(&bvh, &rays, &opts).unwrap();
    s.check_layout().unwrap();
    let inside = |p: Vec3, slack: f32| {
        scene
            .iter()
            .any(|c| distance_to_segment(p, c.a, c.b) <= c.radius + slack)
    };
    let regular = sample_in_capsules(
        &bvh,
        &rays,
        &AcceleratedOpts {
            jitter: false,
            ..opts
        },
    )
    .unwrap();
    assert!(regular.deltas().iter().all(|&d| d <= opts.step * 1.0001));
    for (i, r) in rays.iter().enumerate() {
        let range = s.range(i);
        for k in range.clone() {
            assert!(s.t_end[k] - s.t_start[k] <= opts.step * 1.9);
            assert!(s.t_start[k] >= r.t_min && s.t_end[k] <= r.t_max);
            assert!(
                inside(r.at(s.t_mid(k)), 1e-5),
                "ray {i} sample {k} in empty space"
            );
        }
        let t_far = r.t_max.min(8.0);
        for k in 0..4000 {
            let t = r.t_min + (t_far - r.t_min) * (k as f32 + 0.5) / 4000.0;
            if inside(r.at(t), -1e-4) {
                assert!(
                    range.clone().any(|j| s.t_start[j] <= t && t <= s.t_end[j]),
                    "ray {i}: t = {t} is inside a capsule but not sampled"
                );
            }
        }
    }
}

#[test]
fn accelerated_candidates_are_the_capsules_containing_the_sample() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let s = sample_in_capsules(
        &bvh,
        &rays,
        &AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128),
    )
    .unwrap();
    let mut compared = 0;
    for (i, r) in rays.iter().enumerate() {
        for k in s.range(i) {
            let p = r.at(s.t_mid(k));
            let near_boundary = scene
                .iter()
                .any(|c| (distance_to_segment(p, c.a, c.b) - c.radius).abs() < 1e-4);
            if near_boundary {
                continue;
            }
            let (mut parts, mut bones) = (0u8, 0u64);
            for c in scene
                .iter()
                .filter(|c| distance_to_segment(p, c.a, c.b) <= c.radius)
            {
                parts |= c.part.bit();
                bones |= 1 << c.bone;
            }
            assert_eq!(
                (s.part_mask[k], s.bone_mask[k]),
                (parts, bones),
                "ray {i} sample {k}"
            );
            compared += 1;
        }
    }
    assert!(compared > 1000, "{compared}");
}

#[test]
fn accelerated_needs_fewer_samples_than_dense_at_the_same_resolution() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let opts = AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128);
    let acc = sample_in_capsules(&bvh, &rays, &opts).unwrap();
    let dense = sample_dense(&rays, BOX_MIN, BOX_MAX, &DenseOpts::default()).unwrap();
    assert!(
        acc.num_samples() * 2 < dense.num_samples(),
        "{} vs {}",
        acc.num_samples(),
        dense.num_samples()
    );
    // And no tangent-only (zero-length) interval produced a sample.
    assert!(acc.deltas().iter().all(|&d| d > 0.0));
}

#[test]
fn samplers_do_not_depend_on_thread_count() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let opts = AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            (
                sample_in_capsules(&bvh, &rays, &opts).unwrap(),
                sample_dense(&rays, BOX_MIN, BOX_MAX, &DenseOpts::default()).unwrap(),
            )
        })
    };
    assert_eq!(run(1), run(3));
    let other_seed = sample_in_capsules(&bvh, &rays, &AcceleratedOpts { seed: 1, ..opts }).unwrap();
    assert_ne!(run(1).0.t_start, other_seed.t_start);
}

#[test]
fn culling_keeps_exactly_the_samples_in_occupied_cells() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let opts = AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128);
    let all = sample_in_capsules(&bvh, &rays, &opts).unwrap();
    // Canonical = posed shifted by +1 in x; the grid holds only canonical x < 1.
    let mut grid = OccupancyGrid::new(Vec3::splat(-2.0), Vec3::splat(2.0), [40; 3]).unwrap();
    let occupied: Vec<Vec3> = (0..40 * 40 * 40)
        .map(|i| grid.cell_point(i, Vec3::splat(0.5)))
        .filter(|p| p.x < 1.0)
        .collect();
    grid.mark(&occupied);
    let calls = std::cell::Cell::new(0);
    let to_canonical = |p: &[Vec3], bones: &[u64]| {
        calls.set(calls.get() + 1);
        assert_eq!(p.len(), bones.len());
        assert!(bones.iter().all(|&b| b != 0));
        p.iter().map(|p| *p + Vec3::X).collect::<Vec<_>>()
    };
    let kept = sample_reference(&bvh, &rays, &grid, to_canonical, &opts).unwrap();
    assert_eq!(calls.get(), 1, "one batch per call");
    kept.check_layout().unwrap();
    let expect_kept = |s: &PackedSamples, i: usize, k: usize| rays[i].at(s.t_mid(k)).x + 1.0 < 1.0;
    let mut n = 0;
    for i in 0..rays.len() {
        n += all.range(i).filter(|&k| expect_kept(&all, i, k)).count();
        assert!(kept.range(i).all(|k| expect_kept(&kept, i, k)));
    }
    assert_eq!(kept.num_samples(), n);
    assert!(n > 0 && n < all.num_samples());
    // A callback returning the wrong count is an error.
    let short = |p: &[Vec3], _: &[u64]| p[1..].to_vec();
    assert!(matches!(
        cull_with_grid(all.clone(), &rays, &grid, short),
        Err(GridError::LengthMismatch { .. })
    ));
}

#[test]
fn tangent_and_inside_rays_in_the_samplers() {
    let c = Capsule {
        a: vec3(-0.5, 0.0, 0.0),
        b: vec3(0.5, 0.0, 0.0),
        radius: 0.25,
        part: talkin_grids::Part::Body,
        bone: 3,
    };
    let bvh = CapsuleBvh::build(&[c]).unwrap();
    let tangent = Ray::new(vec3(0.0, -1.0, 0.25), Vec3::Y, 0.0, 5.0).unwrap();
    let inside = Ray::new(vec3(0.0, 0.0, 0.0), Vec3::Y, 0.1, 5.0).unwrap();
    assert!(ray_capsule(&tangent, &c).is_some());
    let s = sample_in_capsules(
        &bvh,
        &[tangent, inside],
        &AcceleratedOpts {
            step: 0.01,
            jitter: false,
            seed: 0,
        },
    )
    .unwrap();
    assert!(
        s.range(0).is_empty(),
        "a tangent touch has no length to sample"
    );
    let r = s.range(1);
    assert_eq!(r.len(), 15);
    assert_eq!(s.t_start[r.start], 0.1);
    assert!((s.t_end[r.end - 1] - 0.25).abs() < 1e-6);
    assert!(r.clone().all(|k| s.bone_mask[k] == 1 << 3));
}

#[test]
fn bad_input_is_an_error() {
    let (scene, mut rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let opts = AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128);
    assert!(sample_dense(&rays, BOX_MAX, BOX_MIN, &DenseOpts::default()).is_err());
    assert!(sample_in_capsules(&bvh, &rays, &AcceleratedOpts { step: 0.0, ..opts }).is_err());
    rays[7].direction.x = f32::NAN;
    assert!(matches!(
        sample_dense(&rays, BOX_MIN, BOX_MAX, &DenseOpts::default()),
        Err(GridError::NonFiniteRay { index: 7, .. })
    ));
    assert!(matches!(
        sample_in_capsules(&bvh, &rays, &opts),
        Err(GridError::NonFiniteRay { index: 7, .. })
    ));
}

#[test]
fn packed_helpers() {
    let (scene, rays) = scene();
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let s = sample_in_capsules(
        &bvh,
        &rays,
        &AcceleratedOpts::matching_dense(BOX_MIN, BOX_MAX, 128),
    )
    .unwrap();
    let idx = s.ray_indices();
    let mids = s.midpoints_in_world(&rays);
    assert_eq!(idx.len(), s.num_samples());
    for k in 0..s.num_samples() {
        let i = idx[k] as usize;
        assert!(s.range(i).contains(&k));
        assert_eq!(mids[k], rays[i].at(s.t_mid(k)));
    }
    // A broken layout is reported.
    let mut broken = s.clone();
    broken.t_end.pop();
    assert!(broken.check_layout().is_err());
    let mut broken = s.clone();
    let k = broken.range(idx[0] as usize).start;
    broken.t_start[k] = broken.t_end[k] + 1.0;
    assert!(broken.check_layout().is_err());
}
