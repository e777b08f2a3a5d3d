use super::*;

/// Plain f64 reference of the encoding (same vertex indexing).
pub(crate) fn reference(grid: &HashGrid, table: &[f64], p: [f64; 3], id: u32) -> Vec<f64> {
    let f = grid.n_features;
    let mut out = Vec::new();
    for (level, &res) in grid.resolutions.iter().enumerate() {
        let mut c = [0u32; 3];
        let mut t = [0f64; 3];
        for a in 0..3 {
            let q = p[a].clamp(0.0, 1.0) * res as f64;
            let cell = q.floor().clamp(0.0, res as f64 - 1.0);
            c[a] = cell as u32;
            t[a] = q - cell;
        }
        let mut acc = vec![0.0; f];
        for k in 0..8u32 {
            let d = [k & 1, (k >> 1) & 1, k >> 2];
            let mut w = 1.0;
            for a in 0..3 {
                w *= if d[a] == 1 { t[a] } else { 1.0 - t[a] };
            }
            let row = grid.vertex_index(level, [c[0] + d[0], c[1] + d[1], c[2] + d[2]], id);
            for j in 0..f {
                acc[j] += w * table[row * f + j];
            }
        }
        out.extend(acc);
    }
    out
}

fn small_grid(device: &Device) -> HashGrid {
    // Levels 0-1 dense, 2-3 hashed into 512 entries.
    HashGridConfig::new()
        .with_n_levels(4)
        .with_log2_hashmap_size(9)
        .with_base_resolution(3)
        .with_per_level_scale(2.0)
        .with_init_scale(1.0)
        .init(device, &mut WeightRng::seeded(3))
}

#[test]
fn matches_reference_and_levels_hash_when_full() {
    let device = Device::flex();
    let grid = small_grid(&device);
    assert_eq!(
        grid.offsets,
        vec![0, 64, 64 + 343, 64 + 343 + 512, 64 + 343 + 1024]
    );
    let table: Vec<f64> = host(&grid.table.val()).iter().map(|&v| v as f64).collect();
    let pts = [[0.1f32, 0.5, 0.9], [0.77, 0.01, 0.33], [1.0, 0.0, 0.5]];
    let x = floats(pts.iter().flatten().copied().collect(), [3, 3], &device);
    let y = host(&grid.forward(x, 0));
    for (i, p) in pts.iter().enumerate() {
        let r = reference(&grid, &table, p.map(|v| v as f64), 0);
        for (j, v) in r.iter().enumerate() {
            assert!((y[i * 8 + j] as f64 - v).abs() < 1e-5, "{i} {j}");
        }
    }
}

/// Points in and around the unit cube: cell boundaries, the faces, outside (clamped).
fn awkward_points() -> Vec<[f32; 3]> {
    let mut pts = vec![
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [0.5, 0.25, 0.75],
        [-0.2, 0.4, 1.3],
        [1.0, 0.0, 0.999_999],
    ];
    let mut s = 12345u32;
    for _ in 0..200 {
        let mut p = [0f32; 3];
        for v in p.iter_mut() {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            *v = (s >> 8) as f32 / (1u32 << 24) as f32;
        }
        pts.push(p);
    }
    pts
}

/// The corners and rows the composed path computes as int tensor ops equal the host's,
/// on dense and hashed levels, for several identities (points off the cell
/// boundaries, where f32 and f64 could floor differently).
#[test]
fn device_corners_equal_host_corners() {
    let device = Device::flex();
    let grid = HashGridConfig::new()
        .with_n_levels(16)
        .with_log2_hashmap_size(19)
        .with_n_identities(3)
        .init(&device, &mut WeightRng::seeded(3));
    let on_boundary = |p: &[f32; 3]| {
        grid.resolutions.iter().any(|&r| {
            p.iter().any(|&v| {
                let q = v as f64 * r as f64;
                (q - q.round()).abs() < 1e-3
            })
        })
    };
    let pts: Vec<[f32; 3]> = awkward_points()
        .into_iter()
        .map(|p| p.map(|v| v.clamp(0.0, 1.0)))
        .filter(|p| !on_boundary(p))
        .collect();
    assert!(pts.len() > 50, "{} points", pts.len());
    let (n, l) = (pts.len(), grid.resolutions.len());
    let flat: Vec<f32> = pts.iter().flatten().copied().collect();
    let x = floats(flat.clone(), [n, 3], &device);
    let levels = grid.resolutions.iter().zip(&grid.offsets[1..]);
    let hashed = levels
        .zip(&grid.offsets)
        .filter(|((r, end), start)| (*r + 1).pow(3) > *end - *start)
        .count();
    assert!(hashed > 0 && hashed < l, "{hashed} of {l} levels hashed");
    for id in 0..4u32 {
        let (lower, rows) =
            corners_on_device(&x, &grid.resolutions, &grid.offsets, id).expect("fits");
        let (host_lower, host_rows) = grid.corners(&flat, id);
        assert_eq!(
            host(&lower.reshape([n * l, 3])),
            host_lower,
            "identity {id}"
        );
        assert_eq!(
            rows.into_data()
                .convert::<i32>()
                .try_to_vec::<i32>()
                .unwrap(),
            host_rows,
            "identity {id}"
        );
    }
}

/// The fused CPU op and the composed tensor ops (kept for other backends) give the same
/// encoding and the same gradients for the table and the points, for every identity
/// and one past them, with two features a level (the fused op's own path) and three
/// (its general one); and on Flex the fused op is the one `forward` takes.
#[test]
fn fused_op_matches_composed_ops() {
    for features in [2, 3] {
        fused_matches_composed(features);
    }
    // Without autodiff (rendering) the fused op is taken too.
    let plain = Device::flex();
    let grid = HashGridConfig::new()
        .with_n_levels(3)
        .init(&plain, &mut WeightRng::seeded(3));
    let x = floats(vec![0.3, 0.6, 0.9], [1, 3], &plain);
    let (res, off) = (&grid.resolutions, &grid.offsets);
    let fused = hash_fused::encode(&grid.table.val(), &x, |points| {
        let cells = CellRows::new(res, off, 0);
        Corners::new(points, res, off, 2, &|l, c| cells.rows(l, c))
    })
    .expect("Flex tensors take the fused op");
    let composed = grid.forward_composed(grid.table.val(), x, 0);
    for (u, v) in host(&fused).iter().zip(host(&composed).iter()) {
        assert!((u - v).abs() < 1e-6, "{u} {v}");
    }
}

/// The composed encoding in pieces equals it whole (values and both gradients), with
/// a last piece shorter than the rest.
#[test]
fn composed_pieces_match_the_whole() {
    let device = Device::flex().autodiff();
    let grid = HashGridConfig::new()
        .with_n_levels(4)
        .with_log2_hashmap_size(9)
        .init(&device, &mut WeightRng::seeded(3));
    let n = 23;
    let pts: Vec<f32> = (0..n * 3).map(|k| (k as f32 * 0.618).fract()).collect();
    let run = |chunk: usize| {
        let table = grid.table.val().require_grad();
        let x = floats(pts.clone(), [n, 3], &device).require_grad();
        let out = grid.forward_pieces(table.clone(), x.clone(), 1, chunk);
        let weights = floats(
            (0..out.dims()[0] * out.dims()[1])
                .map(|k| (k as f32 * 0.37).sin())
                .collect(),
            out.dims(),
            &device,
        );
        let g = (out.clone() * weights).sum().backward();
        (
            host(&out),
            host(&table.grad(&g).unwrap()),
            host(&x.grad(&g).unwrap()),
        )
    };
    let (whole, pieces) = (run(n), run(5));
    assert_eq!(whole.0, pieces.0);
    for (a, b) in [(&whole.1, &pieces.1), (&whole.2, &pieces.2)] {
        for (u, v) in a.iter().zip(b) {
            assert!((u - v).abs() <= 1e-6 * (1.0 + u.abs()), "{u} {v}");
        }
    }
}

fn fused_matches_composed(features: usize) {
    let device = Device::flex().autodiff();
    op_matches_composed(&device, features, &|grid, x, id| {
        let (res, off, f) = (&grid.resolutions, &grid.offsets, grid.n_features);
        hash_fused::encode(&grid.table.val(), &x, |points| {
            let cells = CellRows::new(res, off, id as u32);
            Corners::new(points, res, off, f, &|l, c| cells.rows(l, c))
        })
        .expect("Flex autodiff tensors take the fused op")
    });
}

/// An encoding op (`op(grid, clamped points, identity)`) against the composed ops on
/// `device` (with autodiff): the encoding and the table's and points' gradients, on dense
/// and hashed levels, for every identity of a 2-identity grid and one past them (it wraps
/// onto the others' dense blocks), points on and outside the cube's faces.
fn op_matches_composed(
    device: &Device,
    features: usize,
    op: &dyn Fn(&HashGrid, Tensor<2>, usize) -> Tensor<2>,
) {
    let grid = HashGridConfig::new()
        .with_n_levels(5)
        .with_n_features_per_level(features)
        .with_log2_hashmap_size(10)
        .with_base_resolution(3)
        .with_per_level_scale(1.7)
        .with_init_scale(1.0)
        .with_n_identities(2)
        .init(device, &mut WeightRng::seeded(3));
    let pts = awkward_points();
    let n = pts.len();
    let out_dim = grid.output_dim();
    let coeff: Vec<f32> = (0..n * out_dim)
        .map(|i| ((i * 7 % 13) as f32 - 6.0) / 6.0)
        .collect();
    let c = floats(coeff, [n, out_dim], device);
    for id in [0, 1, 3] {
        let run = |under_test: bool| {
            let x = floats(pts.iter().flatten().copied().collect(), [n, 3], device).require_grad();
            let clamped = x.clone().clamp(0.0, 1.0);
            let out = if under_test {
                op(&grid, clamped, id)
            } else {
                grid.forward_composed(grid.table.val(), clamped, id)
            };
            let grads = (out.clone() * c.clone()).sum().backward();
            (
                host(&out),
                host(&grid.table.grad(&grads).expect("table grad")),
                host(&x.grad(&grads).expect("point grad")),
            )
        };
        let (tested, composed) = (run(true), run(false));
        for (what, a, b) in [
            ("encoding", &tested.0, &composed.0),
            ("table gradient", &tested.1, &composed.1),
            ("point gradient", &tested.2, &composed.2),
        ] {
            let what = format!("{features} features, identity {id}, {what}");
            crate::util::assert_close_to(&what, a, b, 1e-4);
        }
        // Clamped coordinates carry no point gradient.
        assert_eq!(tested.2[3 * 3], 0.0);
        assert_eq!(tested.2[3 * 3 + 2], 0.0);
    }
}

/// The device op (`kernels::cube`) against the composed ops on a wgpu adapter, as the
/// fused CPU op is above, through `forward` (which takes it there).
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn device_op_matches_composed_ops() {
    let device = crate::device::test_wgpu().autodiff();
    for features in [2, 3] {
        op_matches_composed(&device, features, &|grid, x, id| {
            // Else `forward` would take the composed ops and compare them with themselves.
            assert!(
                grid.device_levels(id as u32).is_some(),
                "the grid fits the device op"
            );
            grid.forward(x, id)
        });
    }
}

/// Each identity has its own dense block on coarse levels and its own hash on fine
/// ones: the same point reads different table rows for different subjects.
#[test]
fn identities_read_their_own_features() {
    let device = Device::flex();
    let grid = HashGridConfig::new()
        .with_n_levels(4)
        .with_log2_hashmap_size(9)
        .with_base_resolution(3)
        .with_per_level_scale(2.0)
        .with_init_scale(1.0)
        .with_n_identities(2)
        .init(&device, &mut WeightRng::seeded(3));
    // Level 0: two dense blocks of 4^3; level 1 (7^3 * 2 > 512) hashed.
    assert_eq!(grid.offsets[1], 128);
    assert_eq!(
        grid.vertex_index(0, [1, 2, 3], 1),
        grid.vertex_index(0, [1, 2, 3], 0) + 64
    );
    let table: Vec<f64> = host(&grid.table.val()).iter().map(|&v| v as f64).collect();
    let p = [0.3f32, 0.6, 0.2];
    let x = floats(p.to_vec(), [1, 3], &device);
    for id in 0..2u32 {
        let y = host(&grid.forward(x.clone(), id as usize));
        let r = reference(&grid, &table, p.map(|v| v as f64), id);
        for (j, v) in r.iter().enumerate() {
            assert!((y[j] as f64 - v).abs() < 1e-5, "{id} {j}");
        }
    }
    let (a, b) = (host(&grid.forward(x.clone(), 0)), host(&grid.forward(x, 1)));
    assert!(a.iter().zip(&b).all(|(u, v)| u != v), "{a:?} {b:?}");
}

/// Autodiff gradients w.r.t. the table and the points against central differences of
/// the f64 reference. Loss = sum(out * coeff).
#[test]
fn gradients_match_central_differences() {
    let device = Device::flex().autodiff();
    let grid = small_grid(&device);
    let table: Vec<f64> = host(&grid.table.val()).iter().map(|&v| v as f64).collect();
    // Points away from every level's cell boundaries (res 3, 6, 12, 24).
    let pts: [[f64; 3]; 2] = [[0.105, 0.52, 0.93], [0.771, 0.0623, 0.354]];
    let out_dim = grid.output_dim();
    let coeff: Vec<f64> = (0..2 * out_dim)
        .map(|i| ((i * 7 % 11) as f64 - 5.0) / 5.0)
        .collect();
    let x = floats(
        pts.iter().flatten().map(|&v| v as f32).collect(),
        [2, 3],
        &device,
    )
    .require_grad();
    let out = grid.forward(x.clone(), 0);
    let c = floats(
        coeff.iter().map(|&v| v as f32).collect(),
        [2, out_dim],
        &device,
    );
    let grads = (out * c).sum().backward();
    let g_table = host(&grid.table.grad(&grads).expect("table grad"));
    let g_x = host(&x.grad(&grads).expect("point grad"));

    let loss = |table: &[f64], pts: &[[f64; 3]; 2]| -> f64 {
        let mut s = 0.0;
        for (i, p) in pts.iter().enumerate() {
            for (j, v) in reference(&grid, table, *p, 0).iter().enumerate() {
                s += v * coeff[i * out_dim + j];
            }
        }
        s
    };
    let h = 1e-5;
    for (i, p) in pts.iter().enumerate() {
        for a in 0..3 {
            let (mut plus, mut minus) = (pts, pts);
            plus[i][a] = p[a] + h;
            minus[i][a] = p[a] - h;
            let fd = (loss(&table, &plus) - loss(&table, &minus)) / (2.0 * h);
            let ad = g_x[i * 3 + a] as f64;
            assert!(
                (fd - ad).abs() < 1e-3 * (1.0 + fd.abs()),
                "dx[{i}][{a}] fd {fd} ad {ad}"
            );
        }
    }
    let mut checked = 0;
    for row in 0..table.len() {
        let mut t = table.clone();
        t[row] += h;
        let up = loss(&t, &pts);
        t[row] -= 2.0 * h;
        let fd = (up - loss(&t, &pts)) / (2.0 * h);
        let ad = g_table[row] as f64;
        assert!(
            (fd - ad).abs() < 1e-4 * (1.0 + fd.abs()),
            "dtable[{row}] fd {fd} ad {ad}"
        );
        checked += (fd != 0.0) as usize;
    }
    assert!(checked > 16, "only {checked} table entries touched");
}
