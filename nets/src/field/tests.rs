//! The field's tests: shapes, routing, gradients and the fused kernels against the
//! composed reference.

use super::*;
use crate::encoding::{EncodingConfig, HashGridConfig};
use crate::init::WeightRng;
use crate::skinning::SkinningConfig;
use crate::skinning::ladder_prior;
use crate::util::host;
use burn::optim::{AdamConfig, GradientsParams};

/// `rays` rays of `per_ray` samples marching through the box along z.
pub(crate) fn batch(rays: usize, per_ray: usize) -> (Vec<[f32; 3]>, OwnedRaySamples) {
    let mut pts = Vec::new();
    let mut s = OwnedRaySamples {
        offsets: vec![0],
        ..Default::default()
    };
    for r in 0..rays {
        let (x, y) = (
            -0.6 + 1.2 * (r % 7) as f32 / 7.0,
            -1.0 + 1.8 * (r % 11) as f32 / 11.0,
        );
        for k in 0..per_ray {
            let t = 0.4 * k as f32 / per_ray as f32;
            pts.push([x, y, -0.2 + t]);
            s.t_start.push(t);
            s.t_end.push(t + 0.4 / per_ray as f32);
        }
        s.offsets.push(pts.len());
    }
    (pts, s)
}

/// Bone and part masks for `n` samples: each one bone and the spine, and the parts
/// cycling through none, head, hands and all.
fn mixed_masks(n: usize) -> (Vec<u64>, Vec<u8>) {
    let bones = (0..n).map(|i| (1u64 << (i % 22)) | (1 << 15)).collect();
    let parts = (0..n)
        .map(|i| [0, PART_BIT_HEAD, PART_BIT_HANDS, 0xff][i % 4])
        .collect();
    (bones, parts)
}

pub(crate) fn tiny_fast() -> FieldConfig {
    let mut c = FieldConfig::fast(2).with_non_rigid_start_step(Some(10));
    c.encoding = EncodingConfig::HashGrid(
        HashGridConfig::new()
            .with_n_levels(4)
            .with_log2_hashmap_size(12),
    );
    c.skinning = SkinningConfig::new().with_resolution(8);
    c
}

/// Makes F_body output exactly `bias` (zero weights), so routing labels are known.
pub(crate) fn force_body(field: &mut TalkinField, bias: [f32; 9]) {
    let device = field.device();
    let out = &mut field.body.mlp.output;
    let w = out.weight.val().zeros_like();
    out.weight = Param::from_tensor(w);
    out.bias = Some(Param::from_tensor(floats(bias.to_vec(), [9], &device)));
}

/// Makes a radiance net output NaN on every row it sees.
fn poison(net: &mut RadianceNet) {
    let w = net.mlp.output.weight.val().full_like(f32::NAN);
    net.mlp.output.weight = Param::from_tensor(w);
}

/// The isotropic unit map: the box's bounding cube (a centimetre is the same unit
/// length on every axis, the box's points land in [0, 1], centred on the short axes);
/// the per-axis map stretches each axis of the box to [0, 1]; a config written before
/// the choice existed reads as the per-axis map.
#[test]
fn unit_map_is_isotropic_unless_an_old_config_says_otherwise() {
    let device = Device::flex();
    let mut config = tiny_fast()
        .with_aabb_min([-1.0, 0.0, -0.25])
        .with_aabb_max([1.0, 4.0, 0.25]);
    assert_eq!(
        config.unit_map,
        Some(UnitMap::Isotropic),
        "the presets' map"
    );
    let corners = floats(vec![-1.0, 0.0, -0.25, 1.0, 4.0, 0.25], [2, 3], &device);
    let unit = |config: &FieldConfig| {
        let field = config
            .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
            .unwrap();
        host(&field.to_unit(corners.clone()))
    };
    let got = unit(&config);
    let want = [0.25, 0.0, 0.4375, 0.75, 1.0, 0.5625];
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-6, "{got:?}");
    }
    config.unit_map = Some(UnitMap::PerAxis);
    let got = unit(&config);
    for (g, w) in got.iter().zip([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]) {
        assert!((g - w).abs() < 1e-6, "{got:?}");
    }
    let mut json = serde_json::to_value(&config).unwrap();
    json.as_object_mut().unwrap().remove("unit_map");
    let old: FieldConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old.unit_map, None);
    assert_eq!(unit(&old), unit(&config));
}

/// The `fast` preset's F_face and F_hands tables hold 2^PART_LOG2_ENTRIES rows a level
/// where F_body's hold 2^17; a config written before the choice existed builds them
/// as large as F_body's, so its checkpoints load.
#[test]
fn part_tables_are_smaller_unless_an_old_config_says_otherwise() {
    let device = Device::flex();
    let rows = |e: &Encoding| match e {
        Encoding::HashGrid(g) => g.n_entries(),
        Encoding::Frequency(_) => 0,
    };
    let config = FieldConfig::fast(3);
    let field = config
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let body = rows(&field.body.encoding);
    let face = rows(&field.face.as_ref().unwrap().encoding);
    let hands = rows(&field.hands.as_ref().unwrap().encoding);
    assert_eq!(face, hands);
    assert!(face * 3 < body, "face {face} rows, body {body}");
    let per_level = |config: &FieldConfig, field: &TalkinField| {
        let Some(EncodingConfig::HashGrid(g)) = &config.part_encoding else {
            panic!("the fast preset sets the parts' encoding");
        };
        assert_eq!(g.log2_hashmap_size, super::config::PART_LOG2_ENTRIES);
        rows(&field.face.as_ref().unwrap().encoding)
    };
    assert_eq!(per_level(&config, &field), face);
    let mut json = serde_json::to_value(&config).unwrap();
    json.as_object_mut().unwrap().remove("part_encoding");
    let old: FieldConfig = serde_json::from_value(json).unwrap();
    assert!(old.part_encoding.is_none());
    let old_field = old
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert_eq!(rows(&old_field.face.as_ref().unwrap().encoding), body);
    assert_eq!(rows(&old_field.hands.as_ref().unwrap().encoding), body);
}

#[test]
fn non_candidates_never_reach_face_or_hands() {
    let device = Device::flex();
    let (pts, _) = batch(6, 8);
    let n = pts.len();
    let bones = vec![1u64 << 15; n];
    let frame = FrameConditions::still();
    let mut field = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    poison(field.face.as_mut().unwrap());
    poison(field.hands.as_mut().unwrap());
    // Every sample's body label is head; only every third sample is a head candidate,
    // and every sample is a hand candidate (but no label is hands).
    force_body(&mut field, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
    let parts: Vec<u8> = (0..n)
        .map(|i| PART_BIT_HANDS | if i % 3 == 0 { PART_BIT_HEAD } else { 0 })
        .collect();
    let input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &frame,
        step: 0,
    };
    let out = field.forward(&input).unwrap();
    assert_eq!(out.stats.face_rows, n.div_ceil(3));
    assert_eq!(out.stats.hand_rows, 0);
    let (rgb, sigma) = (host(&out.rgb), host(&out.sigma));
    for i in 0..n {
        if i % 3 == 0 {
            assert!(
                sigma[i].is_nan(),
                "candidate {i} went through the (poisoned) face net"
            );
        } else {
            assert_eq!(sigma[i], std::f32::consts::LN_2, "{i}");
            assert_eq!(rgb[i * 3], 0.5);
        }
    }

    // Now every label is hands; candidates are every other sample.
    force_body(&mut field, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0]);
    let parts: Vec<u8> = (0..n)
        .map(|i| PART_BIT_HEAD | if i % 2 == 0 { PART_BIT_HANDS } else { 0 })
        .collect();
    let input = FieldInput {
        part_masks: &parts,
        ..input
    };
    let out = field.forward(&input).unwrap();
    assert_eq!(out.stats.face_rows, 0);
    assert_eq!(out.stats.hand_rows, n / 2);
    let hands = out.hands.as_ref().expect("two-pass hands");
    assert_eq!(hands.indices, (0..n).step_by(2).collect::<Vec<_>>());
    assert!(
        host(&out.sigma).iter().all(|s| s.is_finite()),
        "pass 1 holds body outputs only"
    );
}

/// Routing read on the device (every candidate runs the part's net, the label picks)
/// gives the outputs and gradients that routing read on the host gives, with and
/// without the hands' second pass.
#[test]
fn routing_on_the_device_matches_routing_on_the_host() {
    use burn::module::{ModuleVisitor, Param as P};
    struct Grads(Vec<Option<Vec<f32>>>, GradientsParams);
    impl ModuleVisitor for Grads {
        fn visit_float<const D: usize>(&mut self, param: &P<Tensor<D>>) {
            let g = self.1.get::<D>(param.id);
            self.0.push(g.map(|g| g.try_to_vec_as::<f32>().unwrap()));
        }
    }
    let device = Device::flex().autodiff();
    let (pts, samples) = batch(8, 12);
    let n = pts.len();
    let (bones, parts) = mixed_masks(n);
    let f = FrameConditions::still();
    let input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &f,
        step: 0,
    };
    for background in [true, false] {
        let mut field = tiny_fast()
            .with_hand_background(background)
            .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
            .unwrap();
        // Labels that vary from sample to sample (the hash features and the output
        // layer scaled up, its bias zero), so a part's net usually gets candidates
        // routed and turned away.
        if let Encoding::HashGrid(grid) = &mut field.body.encoding {
            grid.table = P::from_tensor((grid.table.val() * 1e4).detach());
        }
        let out = &mut field.body.mlp.output;
        out.weight = P::from_tensor((out.weight.val() * 30.0).detach());
        out.bias = out
            .bias
            .take()
            .map(|b| P::from_tensor(b.val().zeros_like()));
        let run = |routing: Routing| {
            let o = field.forward_routed(&input, routing).unwrap();
            let seg = o.seg_logits.clone();
            let r = o.render(&samples.view()).unwrap();
            let loss = r.rgb.clone().sum() + r.opacity.clone().sum() + seg.sum() * 1e-3;
            let mut g = Grads(
                Vec::new(),
                GradientsParams::from_grads(loss.backward(), &field),
            );
            field.visit(&mut g);
            (host(&r.rgb), host(&r.opacity), o.stats, g.0)
        };
        let (rgb_h, op_h, stats_h, grads_h) = run(Routing::OnHost);
        let (rgb_d, op_d, stats_d, grads_d) = run(Routing::OnDevice);
        // The device runs every candidate (a quarter of the samples each, and a
        // quarter both); the host a subset of them, which depends on the draw of the
        // weights (the CPU's RNG is shared with the tests running beside this one).
        // routing.rs tests partly routed parts with fixed labels.
        let what = format!("background {background}: {stats_h:?} vs {stats_d:?}");
        assert_eq!(
            (stats_d.face_rows, stats_d.hand_rows),
            (n / 2, n / 2),
            "{what}"
        );
        assert!(stats_h.face_rows <= stats_d.face_rows, "{what}");
        assert!(stats_h.hand_rows <= stats_d.hand_rows, "{what}");
        let close = |a: &[f32], b: &[f32], what: &str| {
            assert_eq!(a.len(), b.len(), "{what}");
            for (x, y) in a.iter().zip(b) {
                assert!(
                    (x - y).abs() <= 1e-5 * (1.0 + x.abs()),
                    "{what}: {x} vs {y}"
                );
            }
        };
        close(&rgb_h, &rgb_d, "rgb");
        close(&op_h, &op_d, "opacity");
        assert_eq!(grads_h.len(), grads_d.len());
        for (k, (a, b)) in grads_h.iter().zip(&grads_d).enumerate() {
            let what = format!("gradient {k} (background {background})");
            match (a, b) {
                (Some(a), Some(b)) => close(a, b, &what),
                // A net no row was routed to: no gradient on the host, zeros on the
                // device (it ran on the candidates and every one was turned away).
                (None, Some(g)) | (Some(g), None) => {
                    assert!(g.iter().all(|&v| v == 0.0), "{what}")
                }
                (None, None) => {}
            }
        }
    }
}

#[test]
fn hands_without_background_replace_body_outputs() {
    let device = Device::flex();
    let (pts, samples) = batch(4, 6);
    let n = pts.len();
    let (bones, frame) = (vec![0u64; n], FrameConditions::still());
    let mut field = tiny_fast()
        .with_hand_background(false)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    force_body(&mut field, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0]);
    let parts: Vec<u8> = (0..n)
        .map(|i| if i < 5 { PART_BIT_HANDS } else { 0 })
        .collect();
    let input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &frame,
        step: 0,
    };
    let out = field.forward(&input).unwrap();
    assert!(out.hands.is_none());
    assert_eq!(out.stats.hand_rows, 5);
    let sigma = host(&out.sigma);
    assert!(sigma[..5].iter().all(|&s| s != std::f32::consts::LN_2));
    assert!(sigma[5..].iter().all(|&s| s == std::f32::consts::LN_2));
    assert_eq!(out.render(&samples.view()).unwrap().rgb.dims(), [4, 3]);
}

#[test]
fn absent_modules_are_not_built_or_run() {
    let device = Device::flex();
    let full = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let cfg = tiny_fast()
        .with_has_face(false)
        .with_has_hands(false)
        .with_non_rigid_start_step(None);
    let mut bare = cfg
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert!(
        bare.face.is_none()
            && bare.hands.is_none()
            && bare.hand_deform.is_none()
            && bare.non_rigid.is_none()
    );
    assert!(bare.num_params() < full.num_params());
    let no_dh = tiny_fast()
        .with_use_d_hands(false)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert!(no_dh.hand_deform.is_none() && no_dh.hands.is_some());
    let jawless = tiny_fast()
        .with_face_uses_jaw(false)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert!(jawless.num_params() < full.num_params());
    let blind = tiny_fast()
        .with_face_uses_jaw(false)
        .with_face_uses_expression(false);
    assert_eq!(blind.expression_dim(), 0);
    let blind = blind
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert!(blind.face.is_some() && blind.num_params() < jawless.num_params());

    force_body(&mut bare, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
    let (pts, _) = batch(2, 4);
    let n = pts.len();
    let (bones, parts, frame) = (vec![0u64; n], vec![0xffu8; n], FrameConditions::still());
    let input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &frame,
        step: 1 << 30,
    };
    let stats = bare.forward(&input).unwrap().stats;
    assert_eq!(
        stats,
        RoutingStats {
            samples: n,
            skinning_pairs: n * 22,
            ..Default::default()
        }
    );
}

#[test]
fn empty_batch_renders_empty_rays() {
    let device = Device::flex().autodiff();
    let field = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let frame = FrameConditions::still();
    let input = FieldInput {
        points: &[],
        bone_masks: &[],
        part_masks: &[],
        frame: &frame,
        step: 50,
    };
    let out = field.forward(&input).unwrap();
    let rays = OwnedRaySamples {
        offsets: vec![0, 0, 0],
        ..Default::default()
    };
    let rendered = out.render(&rays.view()).unwrap();
    assert_eq!(
        host(&rendered.rgb_over([0.2, 0.4, 0.6])),
        vec![0.2, 0.4, 0.6, 0.2, 0.4, 0.6]
    );
}

#[test]
fn non_rigid_switches_on_at_its_step() {
    let device = Device::flex();
    let field = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let (pts, _) = batch(2, 4);
    let n = pts.len();
    let (bones, parts, frame) = (vec![1u64 << 3; n], vec![0u8; n], FrameConditions::still());
    let mut input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &frame,
        step: 9,
    };
    assert_eq!(field.forward(&input).unwrap().stats.non_rigid_rows, 0);
    input.step = 10;
    assert_eq!(field.forward(&input).unwrap().stats.non_rigid_rows, n);
}

/// A frame with a code reads its own row, F_body and (with `frame_code_deform`) D_nr
/// see it, a frame without one reads the codes' mean, a code past the last is refused,
/// and the codes draw nothing from the RNG (the identity codes, drawn first, are a seed's).
#[test]
fn frame_codes_are_read_per_frame_and_their_mean_elsewhere() {
    let device = Device::flex();
    let config = |count: usize, deform: bool| FieldConfig {
        frame_codes: Some(FrameCodes {
            count,
            dim: 4,
            deform,
        }),
        ..tiny_fast()
    };
    let without = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let mut field = config(3, true)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    assert_eq!(field.n_frame_codes(), 3);
    assert_eq!(without.n_frame_codes(), 0);
    assert_eq!(
        host(&field.identity.val()),
        host(&without.identity.val()),
        "the codes draw nothing"
    );
    let codes = floats(
        vec![1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.5, 0.0, 0.0, 0.0, -0.5, 0.0],
        [3, 4],
        &device,
    );
    field.frame_codes = Some(Param::from_tensor(codes));
    let (pts, _) = batch(3, 4);
    let n = pts.len();
    let (bones, parts) = (vec![1u64 << 3; n], vec![0u8; n]);
    let render = |field: &TalkinField, code: Option<usize>| {
        let frame = FrameConditions {
            frame_code: code,
            ..FrameConditions::still()
        };
        let input = FieldInput {
            points: &pts,
            bone_masks: &bones,
            part_masks: &parts,
            frame: &frame,
            step: 100,
        };
        field
            .forward(&input)
            .map(|o| (host(&o.rgb), host(&o.x_canonical)))
    };
    let (rgb0, x0) = render(&field, Some(0)).unwrap();
    let (rgb1, x1) = render(&field, Some(1)).unwrap();
    assert_ne!(rgb0, rgb1, "F_body reads the code");
    assert_ne!(x0, x1, "D_nr reads the code");
    // A frame without a code renders as a field whose only code is the mean.
    let mean = host(&field.frame_codes.as_ref().unwrap().val().mean_dim(0));
    let mut single = field.clone();
    single.frame_codes = Some(Param::from_tensor(floats(mean, [1, 4], &device)));
    assert_eq!(
        render(&field, None).unwrap(),
        render(&single, Some(0)).unwrap()
    );
    assert!(matches!(
        render(&field, Some(3)),
        Err(NetsError::Index {
            what: "frame code",
            ..
        })
    ));
    // Without the deformation code, D_nr does not read it.
    let body_only = config(3, false)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let body_only = body_only.reset_frame_codes(2);
    assert_eq!(body_only.n_frame_codes(), 2);
    let mut body_only = body_only;
    body_only.frame_codes = field.frame_codes.clone();
    assert_eq!(
        render(&body_only, Some(0)).unwrap().1,
        render(&body_only, Some(1)).unwrap().1
    );
    assert_ne!(
        render(&body_only, Some(0)).unwrap().0,
        render(&body_only, Some(1)).unwrap().0
    );
    // Its prior term: the squared norm of the frame's own row, none for a mean frame.
    let norm2 = |code| {
        field
            .frame_code_norm2(&FrameConditions {
                frame_code: code,
                ..FrameConditions::still()
            })
            .map(|t| host(&t))
    };
    assert_eq!(norm2(Some(0)), Some(vec![1.0]));
    assert_eq!(norm2(None), None);
}

#[test]
fn rejects_bad_conditions() {
    let device = Device::flex();
    let field = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let (pts, _) = batch(1, 2);
    let mut f = FrameConditions::still();
    f.identity = 2;
    let input = FieldInput {
        points: &pts,
        bone_masks: &[0, 0],
        part_masks: &[0, 0],
        frame: &f,
        step: 0,
    };
    assert!(matches!(
        field.forward(&input),
        Err(NetsError::Index {
            what: "identity",
            ..
        })
    ));
    let f = FrameConditions {
        body_pose: vec![0.0; 3],
        ..FrameConditions::still()
    };
    let input = FieldInput { frame: &f, ..input };
    assert!(matches!(
        field.forward(&input),
        Err(NetsError::Length {
            what: "body_pose",
            ..
        })
    ));
}

#[test]
fn config_round_trips_through_json() {
    let dir = std::env::temp_dir().join(format!("talkin-nets-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for cfg in [
        FieldConfig::paper(3),
        FieldConfig::fast(1).with_hand_background(false),
    ] {
        let path = dir.join("field.json");
        cfg.save(&path).unwrap();
        let back = FieldConfig::load(&path).unwrap();
        assert_eq!(format!("{back:?}"), format!("{cfg:?}"));
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// One training step: forward, two-pass render, MSE, backward, Adam. Returns the loss.
fn train_step(
    field: TalkinField,
    optim: &mut burn::optim::ModuleOptimizer,
    pts: &[[f32; 3]],
    samples: &OwnedRaySamples,
    target: &Tensor<2>,
    step: usize,
) -> (TalkinField, f32) {
    let n = pts.len();
    let (bones, parts) = mixed_masks(n);
    let f = FrameConditions::still();
    let input = FieldInput {
        points: pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &f,
        step,
    };
    let out = field.forward(&input).unwrap();
    let rendered = out.render(&samples.view()).unwrap();
    let loss = (rendered.rgb_over([1.0, 1.0, 1.0]) - target.clone())
        .square()
        .mean();
    let value = host(&loss)[0];
    let grads = GradientsParams::from_grads(loss.backward(), &field);
    (optim.step(1e-2, field, grads), value)
}

#[test]
fn both_presets_train_and_the_fast_one_fits() {
    let device = Device::flex().autodiff();
    let (pts, samples) = batch(24, 8);
    let r = samples.offsets.len() - 1;
    let target: Vec<f32> = (0..r * 3)
        .map(|i| 0.2 + 0.6 * ((i * 7 % 5) as f32 / 4.0))
        .collect();
    let target = floats(target, [r, 3], &device);

    let mut paper = FieldConfig::paper(1);
    paper.skinning = SkinningConfig::new().with_resolution(8);
    let mut optim = AdamConfig::new().init();
    let field = paper
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let (field, first) = train_step(field, &mut optim, &pts, &samples, &target, 200_000);
    let (_, second) = train_step(field, &mut optim, &pts, &samples, &target, 200_000);
    assert!(first.is_finite() && second.is_finite());

    let mut optim = AdamConfig::new().init();
    let mut field = tiny_fast()
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    let mut losses = Vec::new();
    for step in 0..25 {
        let (f, loss) = train_step(field, &mut optim, &pts, &samples, &target, step);
        field = f;
        losses.push(loss);
    }
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(losses[24] < 0.5 * losses[0], "{losses:?}");
}

/// Every float parameter of `field`, in the order the field lists them.
fn parameters(field: &TalkinField) -> Vec<Vec<f32>> {
    use burn::module::{ModuleVisitor, Param as P};
    struct Values(Vec<Vec<f32>>);
    impl ModuleVisitor for Values {
        fn visit_float<const D: usize>(&mut self, param: &P<Tensor<D>>) {
            self.0.push(host(&param.val()));
        }
    }
    let mut values = Values(Vec::new());
    field.visit(&mut values);
    values.0
}

/// A seed gives one field, even while other fields are built on other threads: the
/// weights come from the caller's generator, not from one the threads share.
#[test]
fn a_seed_gives_one_field_while_others_are_built_beside_it() {
    fn build(seed: u64) -> Vec<Vec<f32>> {
        let field = tiny_fast()
            .init(
                &ladder_prior(),
                &Device::flex(),
                &mut WeightRng::seeded(seed),
            )
            .unwrap();
        parameters(&field)
    }
    let alone = build(5);
    let threads: Vec<_> = (0..4u64)
        .map(|i| std::thread::spawn(move || build(if i % 2 == 0 { 5 } else { 6 + i })))
        .collect();
    for (i, thread) in threads.into_iter().enumerate() {
        let built = thread.join().unwrap();
        if i % 2 == 0 {
            assert!(built == alone, "thread {i}: seed 5 gave another field");
        } else {
            assert!(
                built != alone,
                "thread {i}: another seed gave seed 5's field"
            );
        }
    }
}

/// The heads' device op (`kernels::cube::heads`) against the composed cut and
/// activations on the device: density, colour and labels of a `[n, 9]` output with
/// entries of 0, +-1e-3, +-5, +-40 and +-100 (softplus linear and flat, the sigmoid
/// saturated), values and the output's gradient.
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn device_op_heads_match_the_composed_ops() {
    let gpu = crate::device::test_wgpu().autodiff();
    let n = 40;
    let levels = [
        0.0, 1e-3, -1e-3, 5.0, -5.0, 40.0, -40.0, 100.0, -100.0, 0.7, -2.3,
    ];
    let values: Vec<f32> = (0..n * 9)
        .map(|i| levels[(i * 7 + i / 9) % levels.len()])
        .collect();
    let run = |device_op: bool| {
        let raw = floats(values.clone(), [n, 9], &gpu).require_grad();
        let (sigma, rgb) = if device_op {
            activate(&raw, Density::Softplus)
        } else {
            activate_composed(&raw, Density::Softplus)
        };
        let seg = if device_op {
            seg_logits_of(raw.clone())
        } else {
            raw.clone().narrow(1, 4, N_SEG_CLASSES)
        };
        let stacked = Tensor::cat(vec![sigma.unsqueeze_dim(1), rgb, seg], 1);
        let q: Vec<f32> = (0..n * 9)
            .map(|i| ((i * 5 % 7) as f32 - 3.0) / 3.0)
            .collect();
        let grads = (stacked.clone() * floats(q, [n, 9], &gpu)).sum().backward();
        [host(&stacked), host(&raw.grad(&grads).unwrap())]
    };
    let (dev, composed) = (run(true), run(false));
    crate::util::assert_close_to("heads", &dev[0], &composed[0], 1e-6);
    crate::util::assert_close_to("output gradient", &dev[1], &composed[1], 1e-6);
}

/// F_face that reads neither the expression nor the jaw (a capture whose face never
/// moves) takes the identity alone and renders its routed rows.
#[test]
fn a_face_without_expression_inputs_renders_its_rows() {
    let device = Device::flex();
    let (pts, _) = batch(2, 6);
    let n = pts.len();
    let bones = vec![1u64 << 15; n];
    let frame = FrameConditions::still();
    let mut field = tiny_fast()
        .with_face_uses_jaw(false)
        .with_face_uses_expression(false)
        .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
        .unwrap();
    force_body(&mut field, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
    let parts = vec![PART_BIT_HEAD; n];
    let input = FieldInput {
        points: &pts,
        bone_masks: &bones,
        part_masks: &parts,
        frame: &frame,
        step: 0,
    };
    let out = field.forward(&input).unwrap();
    assert_eq!(out.stats.face_rows, n);
    assert!(host(&out.sigma).iter().all(|s| s.is_finite()));
    assert!(host(&out.rgb).iter().all(|c| c.is_finite()));
}
