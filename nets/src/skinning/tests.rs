//! D_r's tests: candidates, the priors, the warp and its gradients.

use super::*;
use crate::util::host;

fn identity_transforms() -> Vec<[f32; 16]> {
    (0..N_SMPLX_JOINTS)
        .map(|b| {
            let s = b as f32 * 0.01;
            [
                1.0,
                0.0,
                0.0,
                s,
                0.0,
                1.0,
                0.0,
                -s,
                0.0,
                0.0,
                1.0,
                0.5 * s,
                0.0,
                0.0,
                0.0,
                1.0,
            ]
        })
        .collect()
}

/// Each joint a rotation about its own axis (up to 0.53 rad) and a translation, except
/// every ninth (0, 9, 18, ...), which keeps points where they are (on a cell's face, say).
#[cfg(feature = "wgpu")]
fn rigid_transforms() -> Vec<[f32; 16]> {
    (0..N_SMPLX_JOINTS)
        .map(|b| {
            let angle = if b % 9 == 0 { 0.0 } else { b as f64 * 0.01 };
            let axis = [1.0, (b % 3) as f64, 2.0 - (b % 5) as f64];
            let len = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
            let [x, y, z] = axis.map(|v| v / len);
            let (sin, cos) = angle.sin_cos();
            let c1 = 1.0 - cos;
            let r = [
                [cos + x * x * c1, x * y * c1 - z * sin, x * z * c1 + y * sin],
                [y * x * c1 + z * sin, cos + y * y * c1, y * z * c1 - x * sin],
                [z * x * c1 - y * sin, z * y * c1 + x * sin, cos + z * z * c1],
            ];
            let t = [0.02 * angle, -0.5 * angle, 0.3 * angle];
            let mut m = [0f32; 16];
            for i in 0..3 {
                for j in 0..3 {
                    m[4 * i + j] = r[i][j] as f32;
                }
                m[4 * i + 3] = t[i] as f32;
            }
            m[15] = 1.0;
            m
        })
        .collect()
}

#[test]
fn ancestors_and_candidates() {
    assert_eq!(body_ancestor(22), HEAD_JOINT);
    assert_eq!(body_ancestor(24), HEAD_JOINT);
    assert_eq!(body_ancestor(25), LEFT_WRIST);
    assert_eq!(body_ancestor(39), LEFT_WRIST);
    assert_eq!(body_ancestor(40), RIGHT_WRIST);
    assert_eq!(body_ancestor(54), RIGHT_WRIST);
    assert_eq!(skinned_candidates(0, false), (1 << 22) - 1);
    assert_eq!(skinned_candidates(0, true), (1 << 22) - 1);
    let mask = (1 << 30) | (1 << 23) | 1;
    assert_eq!(skinned_candidates(mask, false), (1 << 20) | (1 << 15) | 1);
    // With finger bones a finger is its own candidate; the jaw and eyes still follow the
    // head.
    assert_eq!(skinned_candidates(mask, true), (1 << 30) | (1 << 15) | 1);
    // A mask naming every joint (a dense sample) is skinned over the body joints.
    let all = (1u64 << N_SMPLX_JOINTS) - 1;
    assert_eq!(skinned_candidates(all, true), (1 << 22) - 1);
    assert_eq!(skinned_candidates(all, false), (1 << 22) - 1);
    assert_eq!(skinned_joint(54, true), 54);
    assert_eq!(skinned_joint(24, true), HEAD_JOINT);
    assert_eq!(skinned_joint(FIRST_FINGER_JOINT - 1, true), HEAD_JOINT);
    assert_eq!(skinned_joint(N_SMPLX_JOINTS, true), RIGHT_WRIST);
}

#[test]
fn single_candidate_is_rigid_and_all_bones_is_fallback() {
    let device = Device::flex();
    let vol = SkinningConfig::new()
        .with_resolution(8)
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    let t = identity_transforms();
    let pts = [[0.1f32, 0.2, 0.3], [0.0, 0.0, 0.0]];
    let warp = vol
        .inverse_lbs(&pts, &[1 << 5, 0], &t, &[], &device)
        .unwrap();
    assert_eq!(warp.n_pairs, 1 + 22);
    let x = host(&warp.x_canonical);
    assert!(
        (x[0] - 0.15).abs() < 1e-6 && (x[1] - 0.15).abs() < 1e-6 && (x[2] - 0.325).abs() < 1e-6
    );
}

/// A forearm held against the chest: a sample inside the forearm's core, 2.5 cm from the
/// chest's, goes where the forearm's transform sends it; one inside the chest's core
/// goes with the chest. Both bones are candidates of both samples.
#[test]
fn posed_prior_lets_the_core_holding_a_sample_win() {
    let device = Device::flex();
    let vol = SkinningConfig::new()
        .with_resolution(8)
        .with_posed_tau(Some(0.005))
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    let (chest, forearm) = (9, 18);
    let mut t = identity_transforms();
    // The forearm's transform moves points 0.4 m along x, the chest's not at all.
    t[forearm][3] = 0.4;
    t[chest][3] = 0.0;
    let capsules = [
        BoneCapsule {
            bone: chest,
            a: [0.0, -0.2, 0.0],
            b: [0.0, 0.2, 0.0],
            radius: 0.12,
        },
        BoneCapsule {
            bone: forearm,
            a: [-0.2, 0.0, 0.16],
            b: [0.2, 0.0, 0.16],
            radius: 0.035,
        },
    ];
    let mask = (1u64 << chest) | (1 << forearm);
    // 2.5 cm outside the chest's core and 2 cm inside the forearm's; then the other
    // way round.
    let pts = [[0.0f32, 0.0, 0.145], [0.0, 0.0, 0.10]];
    let warp = vol
        .inverse_lbs(&pts, &[mask, mask], &t, &capsules, &device)
        .unwrap();
    let x = host(&warp.x_canonical);
    let moved =
        |k: usize, b: usize| -> [f32; 3] { std::array::from_fn(|i| pts[k][i] + t[b][4 * i + 3]) };
    for (k, bone) in [(0, forearm), (1, chest)] {
        let want = moved(k, bone);
        for i in 0..3 {
            assert!(
                (x[3 * k + i] - want[i]).abs() < 2e-3,
                "sample {k}: {:?} against {want:?}",
                &x[3 * k..3 * k + 3]
            );
        }
    }
}

#[test]
fn posed_prior_checks_its_input() {
    let device = Device::flex();
    let bad_tau = SkinningConfig::new().with_posed_tau(Some(0.0)).init(
        [-1.0; 3],
        [1.0; 3],
        &ladder_prior(),
        &device,
    );
    assert!(matches!(
        bad_tau,
        Err(NetsError::Config {
            field: "skinning.posed_tau",
            ..
        })
    ));
    let vol = SkinningConfig::new()
        .with_resolution(4)
        .with_posed_tau(Some(0.01))
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    let t = identity_transforms();
    let capsule = |bone: usize, radius: f32| BoneCapsule {
        bone,
        a: [0.0; 3],
        b: [0.1, 0.0, 0.0],
        radius,
    };
    let run = |c: BoneCapsule| vol.inverse_lbs(&[[0.0; 3]], &[1], &t, &[c], &device);
    assert!(matches!(
        run(capsule(55, 0.1)),
        Err(NetsError::Index {
            what: "bone capsule",
            ..
        })
    ));
    assert!(matches!(
        run(capsule(2, f32::NAN)),
        Err(NetsError::NonFinite {
            what: "bone_capsules"
        })
    ));
    assert!(run(capsule(2, 0.1)).is_ok());
}

/// A config written before the posed prior existed reads as the canonical prior alone,
/// and one written before finger skinning moves the fingers with their wrist.
#[test]
fn configs_without_posed_tau_read_as_off() {
    let old: SkinningConfig =
        serde_json::from_str(r#"{"resolution": 32, "prior_sigma": 0.1}"#).unwrap();
    assert_eq!(old.posed_tau, None);
    assert!(!old.skins_fingers());
    let device = Device::flex();
    let vol = old
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    assert_eq!(vol.logits.dims(), [N_BODY_JOINTS * 32 * 32 * 32]);
}

/// With finger bones a finger sample inside one phalanx's core goes where that
/// phalanx's transform sends it, though its wrist is a candidate too; without, it goes
/// with the wrist. The volume has a channel per SMPL-X joint.
#[test]
fn finger_bones_skin_a_finger_sample_by_its_own_phalanx() {
    let device = Device::flex();
    let config = SkinningConfig::new()
        .with_resolution(8)
        .with_posed_tau(Some(0.005));
    let phalanx = FIRST_FINGER_JOINT + 4; // left middle finger, second joint
    let mut t = identity_transforms();
    t[phalanx][7] = 0.3; // the phalanx's transform moves points 0.3 m along y
    let capsules = [
        BoneCapsule {
            bone: LEFT_WRIST,
            a: [0.0, 0.0, 0.0],
            b: [0.08, 0.0, 0.0],
            radius: 0.015,
        },
        BoneCapsule {
            bone: phalanx,
            a: [0.12, 0.0, 0.0],
            b: [0.15, 0.0, 0.0],
            radius: 0.004,
        },
    ];
    let mask = (1u64 << LEFT_WRIST) | (1 << phalanx);
    let p = [[0.135f32, 0.0, 0.002]];
    for (finger_bones, by) in [(true, phalanx), (false, LEFT_WRIST)] {
        let vol = config
            .clone()
            .with_finger_bones(Some(finger_bones))
            .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
            .unwrap();
        let channels = if finger_bones {
            N_SMPLX_JOINTS
        } else {
            N_BODY_JOINTS
        };
        assert_eq!(vol.logits.dims(), [channels * 8 * 8 * 8]);
        let warp = vol
            .inverse_lbs(&p, &[mask], &t, &capsules, &device)
            .unwrap();
        assert_eq!(warp.n_pairs, if finger_bones { 2 } else { 1 });
        let x = host(&warp.x_canonical);
        let want = p[0][1] + t[by][7];
        assert!((x[1] - want).abs() < 1e-3, "{finger_bones}: {x:?}");
    }
}

/// d(sum x_canonical * c)/d(logits) against central differences of an f64 reference,
/// with the canonical prior and with the posed-space prior (its logits a constant
/// offset per pair).
#[test]
fn gradient_wrt_volume_matches_central_differences() {
    gradient_check(None, &[]);
    let capsules = [
        BoneCapsule {
            bone: 3,
            a: [0.0, -0.4, 0.2],
            b: [0.2, -0.2, 0.2],
            radius: 0.1,
        },
        BoneCapsule {
            bone: 6,
            a: [0.1, -0.3, 0.1],
            b: [0.1, -0.3, 0.1],
            radius: 0.05,
        },
        BoneCapsule {
            bone: 22 - 1,
            a: [0.5, 0.5, 0.0],
            b: [0.8, 0.7, -0.2],
            radius: 0.0,
        },
    ];
    gradient_check(Some(0.05), &capsules);
}

fn gradient_check(posed_tau: Option<f64>, capsules: &[BoneCapsule]) {
    let device = Device::flex().autodiff();
    let mut vol = SkinningConfig::new()
        .with_resolution(6)
        .with_prior_sigma(0.3)
        .with_posed_tau(posed_tau)
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    if posed_tau.is_some() {
        // A non-zero volume, so both terms of the logits are exercised.
        let n = vol.logits.val().dims()[0];
        let v: Vec<f32> = (0..n)
            .map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0)
            .collect();
        vol.logits = Param::from_tensor(floats(v, [n], &device));
    }
    let t = identity_transforms();
    let pts = [[0.13f32, -0.31, 0.22], [-0.4, 0.05, 0.61], [0.7, 0.7, -0.2]];
    let masks = [
        (1 << 3) | (1 << 6) | (1 << 9),
        (1 << 12) | (1 << 22) | (1 << 41),
        1 << 0,
    ];
    let coeff = [0.7f64, -1.1, 0.4, 0.3, 0.9, -0.5, 1.3, 0.2, -0.8];
    let warp = vol
        .inverse_lbs(&pts, &masks, &t, capsules, &device)
        .unwrap();
    let c = floats(coeff.iter().map(|&v| v as f32).collect(), [3, 3], &device);
    let grads = (warp.x_canonical * c).sum().backward();
    let g = host(&vol.logits.grad(&grads).unwrap());
    let logits: Vec<f64> = host(&vol.logits.val()).iter().map(|&v| v as f64).collect();
    let pairs = vol.pairs(&pts, &masks, &t, capsules);
    assert_eq!(
        pairs.posed.iter().any(|&l| l != 0.0),
        posed_tau.is_some(),
        "the posed logits are on exactly when asked for"
    );
    let loss = |logits: &[f64]| -> f64 {
        let mut out = 0.0;
        for s in 0..pts.len() {
            let idx: Vec<usize> = (0..pairs.sample.len())
                .filter(|&i| pairs.sample[i] == s as i32)
                .collect();
            let l: Vec<f64> = idx
                .iter()
                .map(|&i| {
                    (0..8)
                        .map(|k| {
                            pairs.weights[i * 8 + k] as f64 * logits[pairs.rows[i * 8 + k] as usize]
                        })
                        .sum::<f64>()
                        + pairs.posed[i] as f64
                })
                .collect();
            let mx = l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let z: f64 = l.iter().map(|v| (v - mx).exp()).sum();
            for (j, &i) in idx.iter().enumerate() {
                let w = (l[j] - mx).exp() / z;
                for a in 0..3 {
                    out += coeff[s * 3 + a] * w * pairs.x[i * 3 + a] as f64;
                }
            }
        }
        out
    };
    let h = 1e-4;
    let mut nonzero = 0;
    for &row in &pairs.rows {
        let row = row as usize;
        let mut l = logits.clone();
        l[row] += h;
        let up = loss(&l);
        l[row] -= 2.0 * h;
        let fd = (up - loss(&l)) / (2.0 * h);
        assert!(
            (fd - g[row] as f64).abs() < 1e-4 * (1.0 + fd.abs()),
            "row {row}: fd {fd} ad {}",
            g[row]
        );
        nonzero += (fd.abs() > 1e-6) as usize;
    }
    assert!(nonzero > 8);
}

/// The device op (`kernels::cube::skin`) skins and differentiates as the CPU's pairs and
/// scattered blend do, with finger bones, the posed prior and a rotation and translation
/// a joint: one candidate, several, every bone (the body fallback), fingers, logits far
/// apart, points on a cell's face and outside the box; the volume's and the transforms'
/// gradients both.
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn device_op_skins_like_the_cpu() {
    let gpu = crate::device::test_wgpu().autodiff();
    let t = rigid_transforms();
    let capsules = [
        BoneCapsule {
            bone: 9,
            a: [0.0, -0.2, 0.0],
            b: [0.0, 0.2, 0.0],
            radius: 0.12,
        },
        BoneCapsule {
            bone: 27,
            a: [0.3, 0.1, 0.0],
            b: [0.35, 0.1, 0.0],
            radius: 0.01,
        },
        // A sample between two finger bones' capsules is weighed at the fingers'
        // temperature.
        BoneCapsule {
            bone: 28,
            a: [0.3, 0.15, 0.0],
            b: [0.36, 0.15, 0.0],
            radius: 0.01,
        },
    ];
    let pts = [
        [0.13f32, -0.31, 0.22],
        [-0.4, 0.05, 0.61],
        [0.7, 0.7, -0.2],
        [0.32, 0.1, 0.01],
        // On a cell's face (resolution 6 over [-1, 1]: faces every 0.4), and outside.
        [0.2, -0.6, 0.2],
        [1.7, -2.0, 0.0],
        [0.0, 0.0, 0.0],
    ];
    let masks = [
        (1 << 3) | (1 << 6) | (1 << 9),
        (1 << 12) | (1 << 22) | (1 << 41),
        1 << 0,
        (1 << 20) | (1 << 26) | (1 << 27) | (1 << 28),
        (1 << 9) | (1 << 18),
        (1 << 1) | (1 << 2),
        0,
    ];
    let n = pts.len();
    let run = |device: &Device| {
        let mut vol = SkinningConfig::new()
            .with_resolution(6)
            .with_posed_tau(Some(0.05))
            .with_finger_bones(Some(true))
            .init([-1.0; 3], [1.0; 3], &ladder_prior(), device)
            .unwrap();
        let len = vol.logits.val().dims()[0];
        let v: Vec<f32> = (0..len)
            .map(|i| ((i * 37 % 101) as f32 / 25.0) - 2.0 + if i % 97 == 5 { 40.0 } else { 0.0 })
            .collect();
        vol.logits = Param::from_tensor(floats(v, [len], device));
        let rows: Vec<f32> = t.iter().flat_map(|m| m[..12].to_vec()).collect();
        let transforms = floats(rows, [N_SMPLX_JOINTS, 12], device).require_grad();
        let warp = vol
            .inverse_lbs_with(&pts, &masks, &t, &capsules, device, Some(&transforms))
            .unwrap();
        let plain = vol
            .inverse_lbs(&pts, &masks, &t, &capsules, device)
            .unwrap();
        let coeff: Vec<f32> = (0..n * 3)
            .map(|k| ((k * 5 % 7) as f32 - 3.0) / 3.0)
            .collect();
        let coeff = floats(coeff, [n, 3], device);
        let grads = ((warp.x_canonical.clone() + plain.x_canonical.clone()) * coeff)
            .sum()
            .backward();
        [
            host(&warp.x_canonical),
            host(&plain.x_canonical),
            host(&vol.logits.grad(&grads).unwrap()),
            host(&transforms.grad(&grads).unwrap()),
        ]
    };
    let (cpu, dev) = (run(&Device::flex().autodiff()), run(&gpu));
    for (what, a, b) in [
        ("x_canonical (transforms)", &dev[0], &cpu[0]),
        ("x_canonical", &dev[1], &cpu[1]),
        ("volume gradient", &dev[2], &cpu[2]),
        ("transforms gradient", &dev[3], &cpu[3]),
    ] {
        assert!(b.iter().any(|&v| v != 0.0), "{what}: all zero");
        crate::util::assert_close_to(what, a, b, 1e-4);
    }
}

/// The pairs are laid out by tasks of samples on rayon's threads: any number of threads
/// gives the same pairs, bit for bit, and each sample's pairs follow the last sample's.
#[test]
fn pairs_are_the_same_on_any_number_of_threads() {
    let device = Device::flex();
    let vol = SkinningConfig::new()
        .with_resolution(8)
        .with_posed_tau(Some(0.02))
        .with_finger_bones(Some(true))
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    let t = identity_transforms();
    // Several tasks' worth of samples (2048 a task) and a ragged last one.
    let n = 3 * 2048 + 17;
    let mut seed = 7u64;
    let mut next = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        seed >> 11
    };
    let all = (1u64 << N_SMPLX_JOINTS) - 1;
    let pts: Vec<[f32; 3]> = (0..n)
        .map(|_| std::array::from_fn(|_| (next() % 2000) as f32 / 1000.0 - 1.0))
        .collect();
    // Empty masks (the body fallback), every joint (a dense sample), fingers and a few
    // body joints.
    let masks: Vec<u64> = (0..n)
        .map(|i| match i % 7 {
            0 => 0,
            1 => all,
            _ => (next() & next() & next()) & all,
        })
        .collect();
    let capsules: Vec<BoneCapsule> = (0..N_SMPLX_JOINTS)
        .flat_map(|bone| {
            let o = bone as f32 / N_SMPLX_JOINTS as f32 - 0.5;
            [
                BoneCapsule {
                    bone,
                    a: [o, -0.3, 0.1],
                    b: [o + 0.1, 0.4, -0.1],
                    radius: 0.04,
                },
                BoneCapsule {
                    bone,
                    a: [-o, 0.2, o],
                    b: [-o, 0.2, o],
                    radius: 0.0,
                },
            ]
        })
        .collect();
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| vol.pairs(&pts, &masks, &t, &capsules))
    };
    let (one, three) = (on(1), on(3));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(one.sample, three.sample);
    assert_eq!(one.bone, three.bone);
    assert_eq!(bits(&one.x), bits(&three.x));
    assert_eq!(bits(&one.posed), bits(&three.posed));
    assert_eq!(one.rows, three.rows);
    assert_eq!(bits(&one.weights), bits(&three.weights));
    assert_eq!(one.rows.len(), 8 * one.sample.len());
    assert!(one.posed.iter().any(|&l| l != 0.0));
    // Each sample's candidates, in bone order, right after the last sample's.
    let mut next = 0;
    for (s, &mask) in masks.iter().enumerate() {
        let mut want = vec![];
        let mut bones = vol.candidates(mask);
        while bones != 0 {
            want.push(bones.trailing_zeros() as usize);
            bones &= bones - 1;
        }
        let range = next..next + want.len();
        assert!(one.sample[range.clone()].iter().all(|&k| k == s as i32));
        assert_eq!(one.bone[range.clone()], want[..], "sample {s}");
        next = range.end;
    }
    assert_eq!(next, one.sample.len());
}

/// The host weights blend each candidate's canonical point into the warp's own output,
/// sum to one and name only the sample's candidates (prior, posed prior and a learned
/// change in the volume all in play).
#[test]
fn blend_weights_reproduce_the_warp() {
    let device = Device::flex();
    let mut vol = SkinningConfig::new()
        .with_resolution(8)
        .with_posed_tau(Some(0.05))
        .init([-1.0; 3], [1.0; 3], &ladder_prior(), &device)
        .unwrap();
    let n = vol.logits.val().dims()[0];
    let learned: Vec<f32> = (0..n).map(|i| ((i * 37) % 11) as f32 * 0.3 - 1.5).collect();
    vol.logits = burn::module::Param::from_tensor(crate::util::floats(learned, [n], &device));
    let t = identity_transforms();
    let capsules = [
        BoneCapsule {
            bone: 3,
            a: [0.0, -0.2, 0.0],
            b: [0.0, 0.2, 0.0],
            radius: 0.1,
        },
        BoneCapsule {
            bone: 9,
            a: [0.1, 0.2, 0.0],
            b: [0.1, 0.25, 0.0],
            radius: 0.25,
        },
    ];
    let pts = [[0.1f32, 0.2, 0.3], [-0.4, 0.05, 0.0], [0.0, 0.0, 0.0]];
    let masks = [(1u64 << 3) | (1 << 9) | (1 << 16), 1 << 5, 0];
    let warp = host(
        &vol.inverse_lbs(&pts, &masks, &t, &capsules, &device)
            .unwrap()
            .x_canonical,
    );
    let weights = vol.blend_weights(&pts, &masks, &t, &capsules).unwrap();
    for (s, w) in weights.iter().enumerate() {
        let total: f32 = w.iter().map(|p| p.1).sum();
        assert!((total - 1.0).abs() < 1e-5, "sample {s}: {total}");
        let want = vol.candidates(masks[s]);
        assert_eq!(w.iter().fold(0u64, |m, p| m | 1 << p.0), want);
        for i in 0..3 {
            let blended: f32 = w
                .iter()
                .map(|&(b, wb)| wb * (pts[s][i] + t[b][4 * i + 3]))
                .sum();
            assert!(
                (blended - warp[3 * s + i]).abs() < 1e-5,
                "sample {s} axis {i}"
            );
        }
    }
    // A sample with several candidates gets more than one non-zero weight.
    assert!(weights[0].iter().filter(|p| p.1 > 1e-3).count() > 1);
}
