//! Ray-capsule intersection and the BVH against plain references, hard cases included.

mod common;

use common::{marched_interval, random_rays, random_scene, union_of};
use glam::{Vec3, vec3};
use talkin_grids::intersect::{brute_force_hits, ray_capsule};
use talkin_grids::{Capsule, CapsuleBvh, GridError, Part, Ray};

fn capsule(a: Vec3, b: Vec3, radius: f32) -> Capsule {
    Capsule {
        a,
        b,
        radius,
        part: Part::Arms,
        bone: 18,
    }
}

fn ray(o: Vec3, d: Vec3) -> Ray {
    Ray::new(o, d, 0.0, f32::INFINITY).unwrap()
}

#[test]
fn exact_intersection_matches_marching_on_random_scenes() {
    let scene = random_scene(1, 40);
    let rays = random_rays(2, 300, &scene);
    let h = 2e-4;
    let mut checked_hits = 0;
    for r in &rays {
        for c in &scene {
            let exact = ray_capsule(r, c);
            let marched = marched_interval(r, c, h);
            match (exact, marched) {
                (Some((t0, t1)), Some((m0, m1))) => {
                    assert!(t0 <= m0 + 1e-5 && m0 - t0 <= h + 1e-4, "{r:?} {c:?}");
                    assert!(t1 >= m1 - 1e-5 && t1 - m1 <= h + 1e-4, "{r:?} {c:?}");
                    checked_hits += 1;
                }
                (Some((t0, t1)), None) => {
                    assert!(
                        t1 - t0 <= 2.0 * h,
                        "missed by marching: {r:?} {c:?} {t0} {t1}"
                    )
                }
                (None, Some(m)) => panic!("exact missed {m:?}: {r:?} {c:?}"),
                (None, None) => {}
            }
        }
    }
    assert!(
        checked_hits > 200,
        "scene too sparse to test: {checked_hits}"
    );
}

#[test]
fn ray_starting_inside_clamps_to_t_min() {
    let c = capsule(vec3(0.0, 0.0, 0.0), vec3(0.0, 1.0, 0.0), 0.2);
    let r = Ray::new(vec3(0.0, 0.5, 0.0), Vec3::X, 0.0, 10.0).unwrap();
    assert_eq!(ray_capsule(&r, &c), Some((0.0, 0.2)));
    let r = Ray { t_min: 0.05, ..r };
    assert_eq!(ray_capsule(&r, &c), Some((0.05, 0.2)));
    // Range ends inside: t_out clamps to t_max.
    let r = Ray { t_max: 0.1, ..r };
    assert_eq!(ray_capsule(&r, &c), Some((0.05, 0.1)));
    // Range starts past the capsule.
    let r = Ray {
        t_min: 0.3,
        t_max: 1.0,
        ..r
    };
    assert_eq!(ray_capsule(&r, &c), None);
}

#[test]
fn ray_parallel_to_the_axis() {
    let c = capsule(vec3(0.0, 0.0, 0.0), vec3(0.0, 1.0, 0.0), 0.2);
    // Inside the cylinder's footprint: enters the bottom cap, leaves the top cap.
    let (t0, t1) = ray_capsule(&ray(vec3(0.1, -1.0, 0.0), Vec3::Y), &c).unwrap();
    let cap = (0.2f32 * 0.2 - 0.1 * 0.1).sqrt();
    assert!((t0 - (1.0 - cap)).abs() < 1e-6 && (t1 - (2.0 + cap)).abs() < 1e-6);
    // Outside the footprint: miss, even though the axis is straight ahead.
    assert_eq!(ray_capsule(&ray(vec3(0.21, -1.0, 0.0), Vec3::Y), &c), None);
    // Exactly on the surface line, parallel: touches along the whole side.
    let (t0, t1) = ray_capsule(&ray(vec3(0.2, -1.0, 0.0), Vec3::Y), &c).unwrap();
    assert!(
        (t0 - 1.0).abs() < 1e-6 && (t1 - 2.0).abs() < 1e-6,
        "{t0} {t1}"
    );
    // Downwards from inside.
    let (t0, t1) = ray_capsule(&ray(vec3(0.0, 0.5, 0.0), -Vec3::Y), &c).unwrap();
    assert!(t0 == 0.0 && (t1 - 0.7).abs() < 1e-6);
}

#[test]
fn sphere_capsule_and_grazing_rays() {
    let s = capsule(vec3(1.0, 2.0, 3.0), vec3(1.0, 2.0, 3.0), 0.5);
    let (t0, t1) = ray_capsule(&ray(vec3(1.0, 2.0, 0.0), Vec3::Z), &s).unwrap();
    assert!((t0 - 2.5).abs() < 1e-6 && (t1 - 3.5).abs() < 1e-6);
    // Grazing: just inside hits with a short chord, just outside misses.
    let inside = ray(vec3(1.0, 2.4999, 0.0), Vec3::Z);
    let (t0, t1) = ray_capsule(&inside, &s).unwrap();
    let chord = 2.0 * (0.5f32 * 0.5 - 0.4999 * 0.4999).sqrt();
    assert!(((t1 - t0) - chord).abs() < 1e-4, "{} vs {chord}", t1 - t0);
    assert_eq!(ray_capsule(&ray(vec3(1.0, 2.5001, 0.0), Vec3::Z), &s), None);
    // Tangent to the cylinder at a point where the spheres are not involved.
    let c = capsule(vec3(-1.0, 0.0, 0.0), vec3(1.0, 0.0, 0.0), 0.25);
    let tangent = ray(vec3(0.5, -1.0, 0.25), Vec3::Y);
    assert_eq!(ray_capsule(&tangent, &c), Some((1.0, 1.0)));
    let barely = ray(vec3(0.5, -1.0, 0.25 * (1.0 - 1e-6)), Vec3::Y);
    let (t0, t1) = ray_capsule(&barely, &c).expect("a grazing ray inside the radius hits");
    assert!(t0 <= 1.0 && t1 >= 1.0 && t1 - t0 < 1e-3);
    let outside = ray(vec3(0.5, -1.0, 0.25 * (1.0 + 1e-6)), Vec3::Y);
    assert_eq!(ray_capsule(&outside, &c), None);
}

#[test]
fn zero_radius_and_zero_length() {
    let point = capsule(Vec3::ZERO, Vec3::ZERO, 0.0);
    assert_eq!(
        ray_capsule(&ray(vec3(0.0, 0.0, -1.0), Vec3::Z), &point),
        Some((1.0, 1.0))
    );
    assert_eq!(
        ray_capsule(&ray(vec3(0.0, 1e-3, -1.0), Vec3::Z), &point),
        None
    );
}

#[test]
fn scale_invariance_for_huge_and_tiny_scenes() {
    let scene = random_scene(3, 20);
    let rays = random_rays(4, 200, &scene);
    for scale in [1e-6f32, 1e-3, 1e3, 1e6] {
        for r in &rays {
            let rs = Ray {
                origin: r.origin * scale,
                t_min: r.t_min * scale,
                t_max: r.t_max * scale,
                ..*r
            };
            for c in &scene {
                let cs = Capsule {
                    a: c.a * scale,
                    b: c.b * scale,
                    radius: c.radius * scale,
                    ..*c
                };
                let (Some((t0, t1)), Some((s0, s1))) = (ray_capsule(r, c), ray_capsule(&rs, &cs))
                else {
                    continue;
                };
                let tol = 1e-4 * scale;
                assert!(
                    (s0 - t0 * scale).abs() <= tol,
                    "scale {scale}: {s0} vs {t0}"
                );
                assert!(
                    (s1 - t1 * scale).abs() <= tol,
                    "scale {scale}: {s1} vs {t1}"
                );
            }
        }
    }
}

#[test]
fn far_away_origin_keeps_precision() {
    // A camera 10 km away looking at a 5 cm finger: f32 squares of the origin would
    // already lose the finger.
    let c = capsule(vec3(0.0, 0.0, 0.0), vec3(0.05, 0.0, 0.0), 0.01);
    let (t0, t1) = ray_capsule(&ray(vec3(0.02, 0.0, -1.0e4), Vec3::Z), &c).unwrap();
    assert!((t0 - (1.0e4 - 0.01)).abs() < 2e-3 && (t1 - (1.0e4 + 0.01)).abs() < 2e-3);
    assert!(t1 > t0);
}

/// Breaking stops the visit where it is: the hits reported are the plain visit's first
/// ones, in its order, and a visit never broken reports them all.
#[test]
fn a_broken_visit_reports_the_plain_visits_first_hits() {
    use std::ops::ControlFlow;
    let scene = random_scene(7, 60);
    let bvh = CapsuleBvh::build(&scene).unwrap();
    let mut several = 0;
    for r in random_rays(107, 300, &scene) {
        let mut all = Vec::new();
        bvh.for_each_hit(&r, |h| all.push(h.capsule));
        let mut kept = Vec::new();
        let flow = bvh.try_for_each_hit(&r, |h| {
            kept.push(h.capsule);
            if kept.len() == 2 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        });
        assert_eq!(kept, all[..all.len().min(2)]);
        assert_eq!(flow.is_break(), all.len() >= 2);
        several += usize::from(all.len() > 2);
    }
    assert!(several > 10, "{several} rays cross more than two capsules");
}

#[test]
fn bvh_intervals_equal_brute_force_on_random_scenes() {
    for seed in 0..6u64 {
        let scene = random_scene(seed, 30 + 15 * seed as usize);
        let rays = random_rays(seed + 100, 500, &scene);
        let bvh = CapsuleBvh::build(&scene).unwrap();
        let intervals = bvh.intervals(&rays).unwrap();
        assert_eq!(intervals.num_rays(), rays.len());
        let mut hits = Vec::new();
        let mut bvh_hits = Vec::new();
        for (i, r) in rays.iter().enumerate() {
            hits.clear();
            brute_force_hits(&scene, r, &mut hits);
            // Same set of capsules.
            bvh.hits(r, &mut bvh_hits).unwrap();
            let mut a: Vec<u32> = hits.iter().map(|h| h.capsule).collect();
            let mut b: Vec<u32> = bvh_hits.iter().map(|h| h.capsule).collect();
            a.sort();
            b.sort();
            assert_eq!(a, b, "seed {seed} ray {i}");
            // Same merged intervals, sorted and disjoint.
            let reference = union_of(hits.iter().map(|h| (h.t_in, h.t_out)).collect());
            let got: Vec<(f32, f32)> = intervals
                .of_ray(i)
                .iter()
                .map(|v| (v.t_in, v.t_out))
                .collect();
            assert_eq!(got, reference, "seed {seed} ray {i}");
            for w in intervals.of_ray(i).windows(2) {
                assert!(w[0].t_out < w[1].t_in, "not disjoint: {w:?}");
            }
            for v in intervals.of_ray(i) {
                assert!(r.t_min <= v.t_in && v.t_in <= v.t_out && v.t_out <= r.t_max);
                // Masks: exactly the parts/bones of the brute-force capsules inside it.
                let (mut parts, mut bones) = (0u8, 0u64);
                for h in hits
                    .iter()
                    .filter(|h| h.t_in >= v.t_in && h.t_out <= v.t_out)
                {
                    parts |= scene[h.capsule as usize].part.bit();
                    bones |= 1 << scene[h.capsule as usize].bone;
                }
                assert_eq!((v.part_mask, v.bone_mask), (parts, bones));
            }
        }
    }
}

#[test]
fn bvh_finds_capsules_along_axis_aligned_rays_grazing_box_faces() {
    // Axis-aligned rays have infinite 1/d on two axes; the slab test must treat those
    // exactly, also with the origin just inside the capsule's x range.
    let c = capsule(vec3(0.0, 0.0, 30.0), vec3(0.0, 0.0, 30.0), 0.1);
    let bvh = CapsuleBvh::build(&[c, capsule(Vec3::ONE, Vec3::ONE, 0.1)]).unwrap();
    let r = ray(vec3(0.0999999, 0.0, 0.0), Vec3::Z);
    assert_eq!(bvh.intervals(&[r]).unwrap().of_ray(0).len(), 1);
}

#[test]
fn non_finite_input_is_an_error_not_a_panic() {
    let good = capsule(Vec3::ZERO, Vec3::X, 0.1);
    let nan_capsules = [
        Capsule {
            a: vec3(f32::NAN, 0.0, 0.0),
            ..good
        },
        Capsule {
            b: vec3(0.0, f32::INFINITY, 0.0),
            ..good
        },
        Capsule {
            radius: f32::NAN,
            ..good
        },
        Capsule {
            radius: -0.1,
            ..good
        },
        Capsule { bone: 64, ..good },
    ];
    for bad in nan_capsules {
        assert!(CapsuleBvh::build(&[good, bad]).is_err(), "{bad:?}");
    }
    assert!(Ray::new(vec3(f32::NAN, 0.0, 0.0), Vec3::Z, 0.0, 1.0).is_err());
    assert!(Ray::new(Vec3::ZERO, vec3(0.0, f32::INFINITY, 0.0), 0.0, 1.0).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::ZERO, 0.0, 1.0).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::Z, f32::NAN, 1.0).is_err());
    assert!(Ray::new(Vec3::ZERO, Vec3::Z, 2.0, 1.0).is_err());
    let bvh = CapsuleBvh::build(&[good]).unwrap();
    let mut rays = vec![ray(Vec3::ZERO, Vec3::Z); 3];
    rays[2].origin.y = f32::NAN;
    assert_eq!(
        bvh.intervals(&rays),
        Err(GridError::NonFiniteRay {
            index: 2,
            field: "origin"
        })
    );
    rays[2] = Ray {
        direction: vec3(0.0, 0.0, 2.0),
        ..rays[0]
    };
    assert!(matches!(
        bvh.intervals(&rays),
        Err(GridError::DirectionNotUnit { index: 2, .. })
    ));
}
