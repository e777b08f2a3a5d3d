//! Margin fitting on a stick figure whose "clothes" stick out by known amounts.

use glam::{Vec2, Vec3, vec2, vec3};
use talkin_grids::intersect::ray_capsule;
use talkin_grids::{
    Capsule, GridError, LabelledRay, MarginFitOpts, Part, Ray, count_covered, fit_part_margins,
};

fn figure() -> Vec<Capsule> {
    let c = |a: Vec3, b: Vec3, radius, part, bone| Capsule {
        a,
        b,
        radius,
        part,
        bone,
    };
    vec![
        c(
            vec3(0.0, 0.9, 0.0),
            vec3(0.0, 1.4, 0.0),
            0.15,
            Part::Body,
            3,
        ),
        c(
            vec3(0.2, 1.35, 0.0),
            vec3(0.5, 1.35, 0.0),
            0.05,
            Part::Arms,
            17,
        ),
        c(
            vec3(-0.2, 1.35, 0.0),
            vec3(-0.5, 1.35, 0.0),
            0.05,
            Part::Arms,
            16,
        ),
        c(
            vec3(0.55, 1.35, 0.0),
            vec3(0.55, 1.35, 0.0),
            0.04,
            Part::Hands,
            21,
        ),
        c(
            vec3(-0.55, 1.35, 0.0),
            vec3(-0.55, 1.35, 0.0),
            0.04,
            Part::Hands,
            20,
        ),
        c(
            vec3(0.0, 1.65, 0.0),
            vec3(0.0, 1.65, 0.0),
            0.1,
            Part::Head,
            15,
        ),
    ]
}

/// How far each part's "clothes" stick out of its capsules.
const GAPS: [f32; 4] = [0.06, 0.02, 0.005, 0.04];

/// A ray along +z through image point `xy`.
fn camera_ray(xy: Vec2, label: u8) -> LabelledRay {
    LabelledRay {
        ray: Ray::new(xy.extend(-3.0), Vec3::Z, 0.0, f32::INFINITY).unwrap(),
        label,
    }
}

/// Rays that pass outside each capsule's silhouette by gaps 0..=GAPS[part], evenly.
fn grazing_rays() -> Vec<LabelledRay> {
    let mut rays = Vec::new();
    let n = 50;
    for c in figure() {
        let gap_max = GAPS[c.part as usize - 1];
        for i in 0..n {
            let gap = gap_max * i as f32 / (n - 1) as f32;
            let s = (i as f32 * 0.37).fract();
            let side = if i % 2 == 0 { 1.0 } else { -1.0 };
            let reach = c.radius + gap;
            let xy = if c.a == c.b {
                let angle = s * std::f32::consts::TAU;
                c.a.truncate() + reach * vec2(angle.cos(), angle.sin())
            } else {
                let along = c.a.lerp(c.b, 0.1 + 0.8 * s).truncate();
                let normal = (c.b - c.a).truncate().perp().normalize_or_zero();
                along + side * reach * normal
            };
            rays.push(camera_ray(xy, c.part.label()));
        }
    }
    rays
}

/// Plain reference: the smallest margin (bisection to 1e-6) at which a given fraction of
/// the part's rays hits one of its inflated capsules, by brute-force intersection.
fn bisect_margin(capsules: &[Capsule], rays: &[LabelledRay], part: Part, target: f32) -> f32 {
    let own: Vec<&LabelledRay> = rays.iter().filter(|r| r.label == part.label()).collect();
    let covered = |m: f32| {
        own.iter()
            .filter(|r| {
                capsules.iter().filter(|c| c.part == part).any(|c| {
                    let grown = Capsule {
                        radius: c.radius + m,
                        ..*c
                    };
                    ray_capsule(&r.ray, &grown).is_some()
                })
            })
            .count()
    };
    let needed = (target * own.len() as f32).ceil() as usize;
    if covered(0.0) >= needed {
        return 0.0;
    }
    let mut hi = 0.001f32;
    while covered(hi) < needed {
        hi *= 2.0;
    }
    let mut lo = 0.0f32;
    while hi - lo > 1e-6 {
        let mid = 0.5 * (lo + hi);
        if covered(mid) >= needed {
            hi = mid
        } else {
            lo = mid
        }
    }
    hi
}

#[test]
fn margins_grow_per_part_until_every_grazing_ray_hits() {
    let capsules = figure();
    let rays = grazing_rays();
    let report = fit_part_margins(&capsules, &rays, &MarginFitOpts::default()).unwrap();
    println!("{report}");
    for (k, fit) in report.parts.iter().enumerate() {
        let n_capsules = capsules.iter().filter(|c| c.part == fit.part).count();
        assert_eq!(fit.rays, 50 * n_capsules);
        assert!(
            fit.margin >= GAPS[k] && fit.margin <= GAPS[k] + 1e-4,
            "{:?}: margin {} for gap {}",
            fit.part,
            fit.margin,
            GAPS[k]
        );
        let reference = bisect_margin(&capsules, &rays, fit.part, 1.0);
        assert!(
            (fit.margin - reference).abs() < 2e-5,
            "{} vs {reference}",
            fit.margin
        );
        assert!(
            fit.coverage_before() < 0.1,
            "{:?} {}",
            fit.part,
            fit.coverage_before()
        );
        assert_eq!(fit.covered_after, fit.rays);
        assert!(!fit.capped);
    }
    assert!(report.uncovered.is_empty() && report.uncovered_any.is_empty());
    assert_eq!(report.any_part_after, rays.len());
    assert!(report.any_part_before < rays.len());
    // The margins hand straight to the BVH: inflated capsules really cover every ray.
    let inflated = report.margins.inflate(&capsules);
    for r in &rays {
        assert!(
            inflated
                .iter()
                .any(|c| c.part.label() == r.label && ray_capsule(&r.ray, c).is_some())
        );
    }
}

#[test]
fn coverage_target_tolerates_outliers_and_the_cap_reports_them() {
    let capsules = figure();
    let mut rays = grazing_rays();
    // Five noisy "body" pixels (of 55) half a metre from the body.
    let outliers: Vec<u32> = (0..5).map(|i| (rays.len() + i) as u32).collect();
    for i in 0..5 {
        rays.push(camera_ray(
            vec2(0.65 + 0.01 * i as f32, 0.5),
            Part::Body.label(),
        ));
    }
    let tolerant = MarginFitOpts {
        coverage_target: 0.9,
        ..Default::default()
    };
    let report = fit_part_margins(&capsules, &rays, &tolerant).unwrap();
    let body = report.parts[0];
    assert_eq!(body.rays, 55);
    assert!(
        body.margin <= GAPS[0] + 1e-4 && body.margin >= 0.95 * GAPS[0],
        "{}",
        body.margin
    );
    let reference = bisect_margin(&capsules, &rays, Part::Body, 0.9);
    assert!((body.margin - reference).abs() < 2e-5);
    // The target applies to every part: each drops at most its 10% farthest rays.
    let body_uncovered: Vec<u32> = report
        .uncovered
        .iter()
        .copied()
        .filter(|&i| rays[i as usize].label == Part::Body.label())
        .collect();
    assert_eq!(body_uncovered, outliers);
    for fit in &report.parts {
        assert!(
            fit.coverage_after() >= 0.9 && fit.coverage_after() < 1.0,
            "{fit:?}"
        );
    }
    assert!(!body.capped);

    let strict = MarginFitOpts {
        coverage_target: 1.0,
        max_margin: 0.2,
    };
    let report = fit_part_margins(&capsules, &rays, &strict).unwrap();
    let body = report.parts[0];
    assert!(body.capped);
    assert_eq!(body.margin, 0.2);
    assert!(body.largest_need > 0.45);
    assert_eq!(report.uncovered, outliers);
    assert_eq!(body.covered_after, 50);
    // The other parts are not dragged along by the body's outliers.
    assert!(report.parts[2].margin <= GAPS[2] + 1e-4);
}

#[test]
fn any_part_coverage_counts_a_pixel_seen_through_another_part() {
    let capsules = figure();
    // Labelled arm, but the ray goes through the torso only.
    let rays = vec![camera_ray(vec2(0.0, 1.0), Part::Arms.label())];
    let opts = MarginFitOpts {
        max_margin: 0.05,
        ..Default::default()
    };
    let report = fit_part_margins(&capsules, &rays, &opts).unwrap();
    assert_eq!(report.any_part_before, 1);
    assert_eq!(report.parts[1].covered_after, 0);
    assert_eq!(report.uncovered, vec![0]);
    assert!(report.uncovered_any.is_empty());
    // Parts without rays keep a zero margin.
    assert_eq!(report.parts[3].margin, 0.0);
    assert_eq!(report.parts[3].coverage_after(), 1.0);
}

/// The check alone counts what the fit's report counts, before and after the margins.
#[test]
fn count_covered_agrees_with_the_fits_report() {
    let capsules = figure();
    let rays = grazing_rays();
    let report = fit_part_margins(&capsules, &rays, &MarginFitOpts::default()).unwrap();
    let before = count_covered(&capsules, &rays).unwrap();
    let after = count_covered(&report.margins.inflate(&capsules), &rays).unwrap();
    assert_eq!(before.rays, rays.len());
    assert_eq!(before.own_part, report.parts.map(|p| p.covered_before));
    assert_eq!(after.own_part, report.parts.map(|p| p.covered_after));
    assert_eq!(before.any_part, report.any_part_before);
    assert_eq!(after.any_part, report.any_part_after);
    assert!(before.own_part.iter().sum::<usize>() < after.own_part.iter().sum::<usize>());
    for label in [0, 5] {
        assert_eq!(
            count_covered(&capsules, &[camera_ray(Vec2::ZERO, label)]),
            Err(GridError::BadLabel { index: 0, label })
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    let capsules = figure();
    let opts = MarginFitOpts::default();
    for label in [0, 5] {
        assert_eq!(
            fit_part_margins(&capsules, &[camera_ray(Vec2::ZERO, label)], &opts),
            Err(GridError::BadLabel { index: 0, label })
        );
    }
    let mut nan = camera_ray(Vec2::ZERO, 1);
    nan.ray.origin.x = f32::NAN;
    assert!(fit_part_margins(&capsules, &[nan], &opts).is_err());
    let mut bad = capsules.clone();
    bad[2].radius = f32::INFINITY;
    assert!(fit_part_margins(&bad, &[camera_ray(Vec2::ZERO, 1)], &opts).is_err());
    let zero_target = MarginFitOpts {
        coverage_target: 0.0,
        ..opts
    };
    assert!(fit_part_margins(&capsules, &[], &zero_target).is_err());
}
