//! The occupancy grid's tests: cells, updates, marks and their errors.

use super::*;
use crate::{Capsule, Part};
use glam::vec3;

fn grid(res: u32) -> OccupancyGrid {
    OccupancyGrid::new(Vec3::splat(-1.0), Vec3::splat(1.0), [res; 3]).unwrap()
}

/// A field: a ball of density 5 around (0.3, 0, 0), a faint haze elsewhere.
fn ball(points: &[Vec3]) -> Vec<f32> {
    points
        .iter()
        .map(|p| {
            if p.distance(vec3(0.3, 0.0, 0.0)) < 0.4 {
                5.0
            } else {
                0.001
            }
        })
        .collect()
}

#[test]
fn cells_and_box_edges() {
    let g = grid(4);
    assert_eq!(g.cell_of(Vec3::splat(-1.0)), Some(0));
    assert_eq!(g.cell_of(Vec3::splat(1.0)), Some(63));
    assert_eq!(g.cell_of(vec3(1.0001, 0.0, 0.0)), None);
    assert_eq!(g.cell_of(vec3(f32::NAN, 0.0, 0.0)), None);
    assert_eq!(
        g.cell_coords(vec3(-0.9, 0.1, 0.6)),
        Some(UVec3::new(0, 2, 3))
    );
    for i in 0..g.num_cells() {
        assert_eq!(g.cell_of(g.cell_point(i, Vec3::splat(0.5))), Some(i));
    }
    assert!(!g.is_occupied(Vec3::ZERO));
    assert!(!g.is_occupied(Vec3::splat(7.0)));
}

#[test]
fn bad_construction_is_an_error() {
    assert!(OccupancyGrid::new(Vec3::ONE, Vec3::ZERO, [4; 3]).is_err());
    assert!(OccupancyGrid::new(Vec3::ZERO, Vec3::splat(f32::NAN), [4; 3]).is_err());
    assert!(OccupancyGrid::new(Vec3::ZERO, Vec3::ONE, [0, 4, 4]).is_err());
}

#[test]
fn warmup_finds_the_ball_and_never_drops_dense_cells() {
    let mut g = grid(32);
    for step in 0..8 {
        let opts = OccUpdateOpts {
            warmup_steps: 2,
            n: 1,
            dilation: step % 2,
            ..Default::default()
        };
        let seen: std::sync::Mutex<Vec<(Vec3, f32)>> = Default::default();
        let report = g
            .update_every_n_steps(
                step,
                |p| {
                    let d = ball(p);
                    let mut seen = seen.lock().unwrap();
                    seen.extend(p.iter().copied().zip(d.iter().copied()));
                    d
                },
                &opts,
            )
            .unwrap()
            .unwrap();
        if step < 2 {
            assert_eq!(report.evaluated, g.num_cells());
        } else {
            assert!(report.evaluated < g.num_cells());
        }
        // The invariant: every evaluated point denser than the threshold is occupied.
        for (p, d) in seen.lock().unwrap().iter() {
            if *d > report.threshold {
                assert!(g.is_occupied(*p), "step {step}: dropped {p} with {d}");
            }
        }
        assert!(g.is_occupied(vec3(0.3, 0.0, 0.0)));
        assert!(!g.is_occupied(vec3(-0.8, -0.8, -0.8)));
    }
    // Dilation grows exactly the undilated result by one cell.
    let undilated = OccUpdateOpts {
        warmup_steps: 0,
        ..Default::default()
    };
    let dilated = OccUpdateOpts {
        dilation: 1,
        ..undilated
    };
    let (mut a, mut b) = (g.clone(), g.clone());
    a.update(100, ball, &undilated).unwrap();
    b.update(100, ball, &dilated).unwrap();
    assert!(b.num_occupied() > a.num_occupied());
    a.dilate(1);
    assert_eq!(a, b);
    g.update(8, ball, &OccUpdateOpts::default()).unwrap();
    let occupied = g.num_occupied() as f32 / g.num_cells() as f32;
    let ball_fraction = 4.0 / 3.0 * std::f32::consts::PI * 0.4f32.powi(3) / 8.0;
    assert!(
        (occupied - ball_fraction).abs() < 0.02,
        "{occupied} vs {ball_fraction}"
    );
}

#[test]
fn updates_are_deterministic_and_skip_off_steps() {
    let opts = OccUpdateOpts {
        warmup_steps: 0,
        seed: 9,
        ..Default::default()
    };
    let (mut a, mut b) = (grid(16), grid(16));
    a.update(32, ball, &opts).unwrap();
    b.update(32, ball, &opts).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.update_every_n_steps(3, ball, &opts).unwrap(), None);
    let mut c = grid(16);
    c.update(48, ball, &opts).unwrap();
    assert_ne!(
        a.occupancy(),
        c.occupancy(),
        "another step draws other cells"
    );
}

#[test]
fn ema_forgets_density_that_moved_away() {
    let mut g = grid(8);
    let opts = OccUpdateOpts {
        warmup_steps: u32::MAX,
        ema_decay: 0.5,
        occ_thre: 0.01,
        ..Default::default()
    };
    g.update(0, ball, &opts).unwrap();
    assert!(g.is_occupied(vec3(0.5, 0.0, 0.0)));
    let moved = |p: &[Vec3]| ball(&p.iter().map(|p| -*p).collect::<Vec<_>>());
    for step in 1..20 {
        g.update(step, moved, &opts).unwrap();
    }
    assert!(!g.is_occupied(vec3(0.5, 0.0, 0.0)));
    assert!(g.is_occupied(vec3(-0.5, 0.0, 0.0)));
}

#[test]
fn bad_density_callbacks_are_errors() {
    let mut g = grid(4);
    let opts = OccUpdateOpts::default();
    assert!(matches!(
        g.update(0, |p| vec![0.0; p.len() - 1], &opts),
        Err(GridError::LengthMismatch { .. })
    ));
    assert!(matches!(
        g.update(0, |p| vec![f32::NAN; p.len()], &opts),
        Err(GridError::NonFiniteValue { .. })
    ));
    // A bad chunk after good ones: the grid is left exactly as it was.
    let small_chunks = OccUpdateOpts { chunk: 8, ..opts };
    let before = (g.occupancy().to_vec(), g.bitfield().to_vec());
    let last_bad = |p: &[Vec3]| {
        p.iter()
            .map(|q| if q.x > 0.4 { f32::NAN } else { 100.0 })
            .collect()
    };
    assert!(g.update(0, last_bad, &small_chunks).is_err());
    assert_eq!((g.occupancy().to_vec(), g.bitfield().to_vec()), before);
}

#[test]
fn capsules_marks_union_and_dilation() {
    let mut g = grid(20);
    let arm = Capsule {
        a: vec3(-0.5, 0.0, 0.0),
        b: vec3(0.5, 0.0, 0.0),
        radius: 0.1,
        part: Part::Arms,
        bone: 16,
    };
    g.mark_capsules(&[arm], 0.05).unwrap();
    // Every point of the inflated capsule lies in a marked cell, far points do not.
    for k in 0..=100 {
        let t = k as f32 / 100.0;
        for dir in [Vec3::Y, Vec3::Z, -Vec3::Y, vec3(0.0, 0.7, 0.7)] {
            let p = arm.a.lerp(arm.b, t) + dir * 0.149;
            assert!(g.is_occupied(p), "{p}");
        }
    }
    assert!(!g.is_occupied(vec3(0.0, 0.5, 0.0)));
    // Union keeps both sets.
    let mut other = grid(20);
    other.mark(&[vec3(0.0, 0.5, 0.0), vec3(9.0, 9.0, 9.0)]);
    let marked = g.num_occupied();
    g.union(&other).unwrap();
    assert_eq!(g.num_occupied(), marked + 1);
    assert!(g.is_occupied(vec3(0.0, 0.5, 0.0)));
    assert!(g.union(&grid(10)).is_err());
    // Intersection keeps what both hold: of the arm, only the marked point's cell.
    let mut both = g.clone();
    let mut point = grid(20);
    point.mark(&[arm.a, vec3(0.0, 0.5, 0.0) + Vec3::X]);
    both.intersect(&point).unwrap();
    assert_eq!(both.num_occupied(), 1);
    assert!(both.is_occupied(arm.a));
    assert!(both.intersect(&grid(10)).is_err());
    // Restricted, the cleared cells leave the support.
    both.restrict_to_marked();
    assert_eq!(both.num_supported(), 1);
    // Dilation by one cell grows a single cell into a 3x3x3 block.
    let mut single = grid(20);
    single.mark(&[Vec3::splat(0.01)]);
    single.dilate(1);
    assert_eq!(single.num_occupied(), 27);
    assert!(single.is_occupied(Vec3::splat(0.01) + 0.1));
    assert!(!single.is_occupied(Vec3::splat(0.01) + 0.2));
}

/// Chunks are evaluated on several threads: the result must not depend on how the
/// cells are split.
#[test]
fn updates_do_not_depend_on_the_chunking() {
    let wavy = |p: &[Vec3]| -> Vec<f32> {
        p.iter()
            .map(|p| (7.0 * p.x).sin() * (5.0 * p.y).cos() + p.z)
            .collect()
    };
    let (mut a, mut b) = (grid(24), grid(24));
    for step in [0, 40, 80] {
        let small = OccUpdateOpts {
            chunk: 37,
            warmup_steps: 10,
            ..Default::default()
        };
        let whole = OccUpdateOpts {
            chunk: 1 << 20,
            ..small
        };
        let ra = a.update(step, wavy, &small).unwrap();
        let rb = b.update(step, wavy, &whole).unwrap();
        assert_eq!(ra, rb, "step {step}");
    }
    assert_eq!(a.occupancy, b.occupancy);
    assert_eq!(a.bitfield, b.bitfield);
}

#[test]
fn cells_outside_the_support_are_never_evaluated_nor_occupied() {
    let mut grid = OccupancyGrid::new(Vec3::ZERO, Vec3::ONE, [4, 4, 4]).unwrap();
    grid.mark(&[Vec3::splat(0.1), Vec3::splat(0.9)]);
    grid.restrict_to_marked();
    assert_eq!(grid.num_supported(), 2);
    let opts = OccUpdateOpts {
        warmup_steps: 10,
        ema_decay: 0.0,
        ..OccUpdateOpts::default()
    };
    // The field says everything is dense: only the support may turn on.
    let asked = std::sync::atomic::AtomicUsize::new(0);
    let report = grid
        .update(
            0,
            |p| {
                asked.fetch_add(p.len(), std::sync::atomic::Ordering::Relaxed);
                vec![5.0; p.len()]
            },
            &opts,
        )
        .unwrap();
    assert_eq!(
        (asked.into_inner(), report.evaluated, report.occupied),
        (2, 2, 2)
    );
    // After warm-up too (occupied cells plus a random quarter of all cells).
    let report = grid.update(20, |p| vec![5.0; p.len()], &opts).unwrap();
    assert_eq!((report.evaluated, report.occupied), (2, 2));
    // An empty field culls the support; it can come back.
    let report = grid.update(20, |p| vec![0.0; p.len()], &opts).unwrap();
    assert_eq!(report.occupied, 0);
    let report = grid.update(20, |p| vec![5.0; p.len()], &opts).unwrap();
    assert!(report.occupied <= 2);
    assert_eq!(grid.num_supported(), 2);
    // Marking brings a cell into the support.
    grid.mark(&[Vec3::new(0.1, 0.9, 0.1)]);
    assert_eq!(grid.num_supported(), 3);
}
