use std::sync::Arc;

use glam::{Affine3A, Quat, vec3};

use super::*;
use crate::intersect::signed_distance;
use crate::rng::SplitMix64;
use crate::{CapsuleBvh, DilatedOccupancy, OccupancyGrid, Part, sample_in_front_of_cores};

/// Three limbs of different bones (one a sphere), their cores, and per bone a rigid
/// map.
fn scene() -> (Vec<Capsule>, Vec<Capsule>, Vec<Affine3A>) {
    // (a, b, radius, part, bone); the head is a sphere.
    #[rustfmt::skip]
    let limbs = [
        (vec3(0.0, 0.0, 0.0), vec3(0.0, 0.5, 0.0), 0.15, Part::Body, 3),
        (vec3(0.0, 0.5, 0.0), vec3(0.3, 0.6, 0.0), 0.06, Part::Arms, 16),
        (vec3(0.3, 0.6, 0.0), vec3(0.4, 0.6, 0.02), 0.02, Part::Hands, 20),
        (vec3(0.0, 0.7, 0.0), vec3(0.0, 0.7, 0.0), 0.1, Part::Head, 15),
    ];
    let capsules: Vec<Capsule> = limbs
        .into_iter()
        .map(|(a, b, radius, part, bone)| Capsule {
            a,
            b,
            radius,
            part,
            bone,
        })
        .collect();
    let cores = capsules
        .iter()
        .map(|c| Capsule {
            radius: 0.6 * c.radius,
            ..*c
        })
        .collect();
    let maps = (0..64)
        .map(|b| {
            let angle = 0.1 * b as f32;
            Affine3A::from_rotation_translation(
                Quat::from_axis_angle(vec3(0.3, 1.0, 0.2).normalize(), angle),
                vec3(0.01 * b as f32, -0.02, 0.05),
            )
        })
        .collect();
    (capsules, cores, maps)
}

fn points(n: usize, lo: Vec3, hi: Vec3, seed: u64) -> Vec<Vec3> {
    let mut rng = SplitMix64::for_stream(seed, 0);
    (0..n)
        .map(|_| lo + (hi - lo) * vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()))
        .collect()
}

/// Pixel rays from a camera at `origin` in small square tiles of 128 (8 x 16 rays over
/// 4 x 4 cm at the scene's plane z = 0), a tile every 10 cm over the scene: each tile
/// is one chunk with a narrow, round cone of directions, as a frame's neighbouring
/// foreground rays, so capsules at a cone's edge are the hard case.
fn tiled_rays(origin: Vec3) -> Vec<Ray> {
    let mut rays = Vec::new();
    for ty in 0..12 {
        for tx in 0..9 {
            let corner = vec3(-0.3 + 0.1 * tx as f32, -0.25 + 0.1 * ty as f32, 0.0);
            for y in 0..16 {
                for x in 0..8 {
                    let f = vec3((x as f32 + 0.5) / 8.0, (y as f32 + 0.5) / 16.0, 0.0);
                    let target = corner + 0.04 * f;
                    rays.push(Ray::new(origin, target - origin, 0.0, f32::INFINITY).unwrap());
                }
            }
        }
    }
    assert_eq!(CHUNK, 128, "one tile a chunk");
    rays
}

/// Rays from one camera at `origin` towards random points of the scene, in random
/// order (every chunk's cone spans the scene).
fn camera_rays(origin: Vec3, n: usize, seed: u64) -> Vec<Ray> {
    points(n, vec3(-0.25, -0.2, -0.2), vec3(0.55, 0.85, 0.2), seed)
        .into_iter()
        .map(|p| Ray::new(origin, p - origin, 0.0, f32::INFINITY).unwrap())
        .collect()
}

fn opts(step: f32, seed: u64) -> AcceleratedOpts {
    AcceleratedOpts {
        step,
        jitter: true,
        seed,
    }
}

/// Samples `rays` with an unculled sampler and with the exact BVH pipeline, asserts
/// they agree sample for sample (t within 1e-5, same parts and bones), and returns
/// the sampler's.
fn assert_matches_exact(rays: &[Ray], step: f32, seed: u64) -> PackedSamples {
    let (capsules, cores, _) = scene();
    assert_matches_exact_with(&capsules, &cores, rays, step, seed)
}

fn assert_matches_exact_with(
    capsules: &[Capsule],
    cores: &[Capsule],
    rays: &[Ray],
    step: f32,
    seed: u64,
) -> PackedSamples {
    let sampler = AcceleratedSampler::new(capsules, cores, None, step).unwrap();
    let bvh = CapsuleBvh::build(capsules).unwrap();
    let core_bvh = CapsuleBvh::build(cores).unwrap();
    let got = sampler.sample(rays, &opts(step, seed)).unwrap();
    let want = sample_in_front_of_cores(&bvh, &core_bvh, rays, step, &opts(step, seed)).unwrap();
    got.check_layout().unwrap();
    assert_eq!(got.num_rays(), want.num_rays());
    for i in 0..rays.len() {
        let (g, w) = (got.range(i), want.range(i));
        assert_eq!(g.len(), w.len(), "ray {i}: {:?}", rays[i]);
        for (s, t) in g.zip(w) {
            assert!((got.t_start[s] - want.t_start[t]).abs() < 1e-5, "ray {i}");
            assert!((got.t_end[s] - want.t_end[t]).abs() < 1e-5, "ray {i}");
            assert_eq!(got.part_mask[s], want.part_mask[t], "ray {i}");
            assert_eq!(got.bone_mask[s], want.bone_mask[t], "ray {i}");
        }
    }
    got
}

/// Without a cull it is the exact BVH pipeline, sample for sample: shared-origin
/// chunks (prepared capsules, cone culling: narrow cones of pixel tiles and wide ones
/// of random rays) and mixed-origin chunks alike.
#[test]
fn matches_the_exact_pipeline() {
    let mut rays = tiled_rays(vec3(0.1, 0.4, -2.5));
    rays.extend(camera_rays(vec3(0.1, 0.4, -2.5), 700, 1));
    // A camera inside the scene's box looking every way (cones wider than 90
    // degrees), one inside the body capsule, and a chunk of mixed origins.
    let mut rng = SplitMix64::for_stream(2, 0);
    for origin in [vec3(0.1, 0.3, 0.3), vec3(0.05, 0.2, 0.0)] {
        for _ in 0..256 {
            let d = vec3(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            rays.push(Ray::new(origin, d, 0.0, f32::INFINITY).unwrap());
        }
    }
    for (k, r) in camera_rays(vec3(-1.0, 0.5, -2.0), 300, 3)
        .into_iter()
        .enumerate()
    {
        rays.push(Ray {
            origin: r.origin + 0.01 * (k % 3) as f32 * Vec3::X,
            ..r
        });
    }
    let got = assert_matches_exact(&rays, 0.006, 4);
    assert!(got.num_samples() > 5_000, "{}", got.num_samples());
}

/// The cull keeps every bin holding a point that lies in a grown capsule, in front
/// of the first core entry, and that some bone of a capsule holding it maps into an
/// occupied canonical cell (the exact map's candidates); and it does cull.
#[test]
fn cull_never_drops_a_point_the_exact_map_keeps() {
    let (capsules, cores, maps) = scene();
    let mut canonical =
        OccupancyGrid::new(vec3(-0.6, -0.4, -0.6), vec3(0.8, 1.0, 0.6), [100; 3]).unwrap();
    canonical.mark(&points(
        20_000,
        vec3(-0.6, -0.4, -0.6),
        vec3(0.8, 1.0, 0.6),
        5,
    ));
    let step = 0.006;
    let cull = CanonicalCull {
        grid: Arc::new(
            DilatedOccupancy::new(&canonical, AcceleratedSampler::cull_reach(step)).unwrap(),
        ),
        canonical_from_posed: maps.clone(),
        stop_where_spent: true,
    };
    let sampler = AcceleratedSampler::new(&capsules, &cores, Some(cull), step).unwrap();
    let unculled = AcceleratedSampler::new(&capsules, &cores, None, step).unwrap();
    let rays = camera_rays(vec3(0.1, 0.4, -2.5), 2000, 6);
    let samples = sampler.sample(&rays, &opts(step, 7)).unwrap();
    let all = unculled.sample(&rays, &opts(step, 7)).unwrap();
    assert!(samples.num_samples() < all.num_samples() * 9 / 10);
    assert!(samples.num_samples() > all.num_samples() / 10);
    let mut checked = 0;
    for (i, ray) in rays.iter().enumerate() {
        let t_core = cores
            .iter()
            .filter_map(|c| ray_capsule(ray, c))
            .map(|(t, _)| t)
            .fold(f32::INFINITY, f32::min);
        for k in 0..3000 {
            let t = 1.5 + k as f32 / 3000.0 * 2.0;
            let p = ray.at(t);
            let kept = t < t_core
                && capsules.iter().any(|c| {
                    signed_distance(p, c) < -1e-5
                        && canonical.is_occupied(maps[c.bone as usize].transform_point3(p))
                });
            if kept {
                checked += 1;
                assert!(
                    samples
                        .range(i)
                        .any(|s| samples.t_start[s] <= t && t <= samples.t_end[s]),
                    "ray {i}: t {t} is kept by the exact map but in no sample"
                );
            }
        }
    }
    assert!(checked > 1_000, "{checked}");
}

/// Cores no capsule holds (one sticking out of its limb, one where no limb is) are
/// tested on their own, and a core inside a big capsule and a small one rides on the
/// small one: still the exact pipeline, sample for sample.
#[test]
fn loose_and_shared_cores_match_the_exact_pipeline() {
    let (capsules, mut cores, _) = scene();
    // The arm's core grows past its shell; a core floats in front of the body.
    cores[1].radius = 1.5 * capsules[1].radius;
    cores.push(Capsule {
        a: vec3(0.0, 0.25, -0.4),
        b: vec3(0.05, 0.3, -0.4),
        radius: 0.03,
        ..cores[0]
    });
    // A small capsule inside the body shell holding the body's core as well.
    let mut capsules = capsules;
    capsules.push(Capsule {
        radius: 0.13,
        ..capsules[0]
    });
    let nesting = CoreNesting::new(&capsules, &cores);
    assert_eq!(nesting.loose(), &[1, 4]);
    let mut rays = tiled_rays(vec3(0.1, 0.4, -2.5));
    rays.extend(camera_rays(vec3(0.1, 0.4, -2.5), 700, 8));
    let got = assert_matches_exact_with(&capsules, &cores, &rays, 0.006, 9);
    assert!(got.num_samples() > 5_000, "{}", got.num_samples());
}

/// Hard rays: parallel to a limb's axis, grazing a capsule, starting inside a
/// capsule or a core, starting behind the camera (`t_min < 0`), and directions a
/// little off unit length (within the rays' tolerance).
#[test]
fn hard_rays_match_the_exact_pipeline() {
    let ray = |o: Vec3, d: Vec3, t_min: f32| Ray::new(o, d, t_min, f32::INFINITY).unwrap();
    let mut rays = vec![
        // Along the body's axis, from below, through both caps.
        ray(vec3(0.0, -1.0, 0.0), Vec3::Y, 0.0),
        // Along it, 0.149 off the axis (inside the 0.15 radius, outside the core).
        ray(vec3(0.149, -1.0, 0.0), Vec3::Y, 0.0),
        // Tangent to the head sphere, and a hair inside it.
        ray(vec3(0.1, 0.7, -2.0), Vec3::Z, 0.0),
        ray(vec3(0.0999, 0.7, -2.0), Vec3::Z, 0.0),
        // From inside the body shell and inside its core.
        ray(vec3(0.12, 0.25, 0.0), vec3(0.3, 0.2, 1.0), 0.0),
        ray(vec3(0.0, 0.25, 0.0), vec3(0.3, 0.2, 1.0), 0.0),
        // Starting 2 m behind the origin: the scene lies partly behind it.
        ray(vec3(0.0, 0.3, 0.5), -Vec3::Z, -2.0),
    ];
    let mut off_unit = ray(vec3(0.0, 0.3, -2.0), vec3(0.05, 0.1, 1.0), 0.0);
    off_unit.direction *= 1.0008;
    rays.push(off_unit);
    let got = assert_matches_exact(&rays, 0.005, 1);
    assert!(got.range(0).len() > 10 && got.range(6).len() > 10);
}

#[test]
fn bad_input_is_an_error() {
    let (capsules, cores, maps) = scene();
    let sampler = AcceleratedSampler::new(&capsules, &cores, None, 0.005).unwrap();
    let good = camera_rays(vec3(0.0, 0.4, -2.0), 3, 1);
    let nan = Ray {
        origin: Vec3::NAN,
        ..good[0]
    };
    assert!(sampler.sample(&[good[0], nan], &opts(0.005, 0)).is_err());
    assert!(sampler.sample(&good, &opts(0.01, 0)).is_err());
    assert!(sampler.sample(&good, &opts(f32::NAN, 0)).is_err());
    assert!(AcceleratedSampler::new(&capsules, &cores, None, 0.0).is_err());
    let bad = Capsule {
        radius: f32::NAN,
        ..capsules[0]
    };
    assert!(AcceleratedSampler::new(&[bad], &cores, None, 0.005).is_err());
    // A cull that does not dilate far enough for the step.
    let grid = OccupancyGrid::new(vec3(-1.0, -1.0, -1.0), vec3(1.0, 1.0, 1.0), [8; 3]).unwrap();
    let cull = || CanonicalCull {
        grid: Arc::new(DilatedOccupancy::new(&grid, 0.0).unwrap()),
        canonical_from_posed: maps.clone(),
        stop_where_spent: true,
    };
    assert!(AcceleratedSampler::new(&capsules, &cores, Some(cull()), 0.005).is_err());
    // Empty input is fine.
    let empty = sampler.sample(&[], &opts(0.005, 0)).unwrap();
    assert_eq!(empty.num_rays(), 0);
}

/// A torso of bone 3 whose canonical field is a solid slab behind `z = 0` (identity map),
/// and rays along +z through it: the grid, once updated with the slab's density, stops
/// each ray within the cull's reach of where its light is spent, never before the
/// surface; a grid of marks alone, a cull asked not to stop, or a second bone that maps
/// the same bins to empty space stops nothing.
#[test]
fn rays_stop_where_the_grids_density_spends_them() {
    let torso = Capsule {
        a: vec3(0.0, -0.2, 0.0),
        b: vec3(0.0, 0.2, 0.0),
        radius: 0.15,
        part: Part::Body,
        bone: 3,
    };
    let step = 0.005;
    let mut maps = vec![Affine3A::IDENTITY; 64];
    // Bone 4 maps everything 2 m away, outside the grid.
    maps[4] = Affine3A::from_translation(vec3(0.0, 0.0, 2.0));
    let mut grid = OccupancyGrid::new(Vec3::splat(-0.5), Vec3::splat(0.5), [64; 3]).unwrap();
    let cull = |grid: &OccupancyGrid, maps: &[Affine3A]| CanonicalCull {
        grid: Arc::new(DilatedOccupancy::new(grid, AcceleratedSampler::cull_reach(step)).unwrap()),
        canonical_from_posed: maps.to_vec(),
        stop_where_spent: true,
    };
    let rays: Vec<Ray> = (0..40)
        .map(|k| {
            let x = -0.12 + 0.006 * k as f32;
            Ray::new(vec3(x, 0.05, -2.0), Vec3::Z, 0.0, f32::INFINITY).unwrap()
        })
        .collect();
    let last_z = |samples: &PackedSamples, i: usize| {
        let r = samples.range(i);
        let last = r.end - 1;
        rays[i].origin.z + samples.t_start[last]
    };
    let holds_surface = |samples: &PackedSamples, i: usize| {
        let t = -rays[i].origin.z;
        samples
            .range(i)
            .any(|s| samples.t_start[s] <= t && t <= samples.t_end[s])
    };

    // Marks only: a prior, not a density. Every ray runs to the torso's far side.
    grid.mark_capsules(&[torso], 0.02).unwrap();
    let sampler = AcceleratedSampler::new(&[torso], &[], Some(cull(&grid, &maps)), step).unwrap();
    let marked = sampler.sample(&rays, &opts(step, 7)).unwrap();
    for i in 0..rays.len() {
        assert!(last_z(&marked, i) > 0.05, "ray {i}: {}", last_z(&marked, i));
    }

    // The field's slab: optical depth 100 a cell behind z = 0, none in front.
    let slab = |points: &[Vec3]| {
        points
            .iter()
            .map(|p| if p.z >= 0.0 { 100.0 } else { 0.0 })
            .collect::<Vec<f32>>()
    };
    grid.update(0, slab, &crate::OccUpdateOpts::default())
        .unwrap();
    let dilated = cull(&grid, &maps);
    let reach = dilated.grid.reach();
    let sampler = AcceleratedSampler::new(&[torso], &[], Some(dilated), step).unwrap();
    for seed in 0..4 {
        let stopped = sampler.sample(&rays, &opts(step, seed)).unwrap();
        for i in 0..rays.len() {
            assert!(holds_surface(&stopped, i), "ray {i} misses the surface");
            // Spent once the dense bins (from the surface on: its cell is the first
            // dense one) hold the spent depth at the cap's density, the last of them at
            // most 1.9 steps long; then the reach.
            let cell = 1.0 / 64.0;
            let density = 255.0 / crate::occupancy::DEPTH_CODES_PER_UNIT / cell;
            let spent = SPENT_OPTICAL_DEPTH / density + 1.9 * step;
            let z = last_z(&stopped, i);
            assert!(z <= spent + reach + 1e-4, "ray {i}: last sample at z = {z}");
        }
        // Each ray's far side, at least 9 cm past the surface, is gone but for the
        // spent depth and the reach (about 3.4 cm): at least ten steps a ray.
        assert!(
            stopped.num_samples() + 10 * rays.len() < marked.num_samples(),
            "{} of {}",
            stopped.num_samples(),
            marked.num_samples()
        );
    }

    // Asked not to stop, the same grid only culls.
    let culling = CanonicalCull {
        stop_where_spent: false,
        ..cull(&grid, &maps)
    };
    let sampler = AcceleratedSampler::new(&[torso], &[], Some(culling), step).unwrap();
    let unstopped = sampler.sample(&rays, &opts(step, 7)).unwrap();
    for i in 0..rays.len() {
        assert!(
            last_z(&unstopped, i) > 0.05,
            "ray {i}: {}",
            last_z(&unstopped, i)
        );
    }

    // Two bones hold every bin and bone 4 finds no density: nothing is spent.
    let both = [torso, Capsule { bone: 4, ..torso }];
    let sampler = AcceleratedSampler::new(&both, &[], Some(cull(&grid, &maps)), step).unwrap();
    let unsure = sampler.sample(&rays, &opts(step, 7)).unwrap();
    for i in 0..rays.len() {
        assert!(last_z(&unsure, i) > 0.05, "ray {i}: {}", last_z(&unsure, i));
    }
}
