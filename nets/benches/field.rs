//! Field throughput per preset: forward (inference) and forward + render + backward + Adam
//! (a training step) on a realistic packed batch, samples per second. A plain main.
//!
//! `cargo bench -p talkin-nets --bench field` (env: `RAYS`, default 4096; `SAMPLES`
//! per ray, default 32; `ITERS`, default 3). With `--features wgpu` it also runs on the
//! default wgpu adapter when one exists, and skips it otherwise. Run with
//! `MIMALLOC_PURGE_DELAY=-1` so mimalloc keeps freed pages instead of re-faulting them.

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use talkin_nets::field::{FieldConfig, FieldInput, FrameConditions, PART_BIT_HANDS, PART_BIT_HEAD};
use talkin_nets::init::WeightRng;
use talkin_nets::skinning::ladder_prior;
use talkin_nets::volume::OwnedRaySamples;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

struct Batch {
    points: Vec<[f32; 3]>,
    bones: Vec<u64>,
    parts: Vec<u8>,
    samples: OwnedRaySamples,
}

/// Rays along z through a human-sized box; 2-3 candidate bones per sample, ~15% head and
/// ~15% hand candidates (what the capsule BVH hands over).
fn batch(rays: usize, per_ray: usize) -> Batch {
    let mut b = Batch {
        points: vec![],
        bones: vec![],
        parts: vec![],
        samples: OwnedRaySamples {
            offsets: vec![0],
            ..Default::default()
        },
    };
    let mut seed = 1u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..rays {
        let (x, y) = (-0.8 + 1.6 * rnd(), -1.2 + 2.1 * rnd());
        let mut t = 0.0;
        for _ in 0..per_ray {
            let dt = 0.6 / per_ray as f32;
            b.points.push([x, y, -0.3 + t]);
            b.samples.t_start.push(t);
            b.samples.t_end.push(t + dt);
            t += dt;
            let bone = (rnd() * 22.0) as u64 % 22;
            b.bones.push(
                (1 << bone) | (1 << ((bone + 3) % 22)) | if rnd() < 0.5 { 1 << 9 } else { 0 },
            );
            let u = rnd();
            b.parts.push(if u < 0.15 {
                PART_BIT_HEAD
            } else if u < 0.3 {
                PART_BIT_HANDS
            } else {
                1
            });
        }
        b.samples.offsets.push(b.points.len());
    }
    b
}

fn run(device: &Device, device_name: &str, preset: &str, b: &Batch, iters: usize) {
    let n = b.points.len();
    let cfg = match preset {
        "paper" => FieldConfig::paper(1),
        "fast" => FieldConfig::fast(1),
        other => panic!("PRESETS: unknown preset `{other}` (fast or paper)"),
    };
    // Same initialisation (hence the same routing) in every run.
    let f = FrameConditions::still();
    // Past D_nr's start, so every module runs.
    let input = FieldInput {
        points: &b.points,
        bone_masks: &b.bones,
        part_masks: &b.parts,
        frame: &f,
        step: 1 << 30,
    };

    let field = cfg
        .init(&ladder_prior(), device, &mut WeightRng::seeded(17))
        .expect("field");
    let warm = field.forward(&input).expect("forward");
    let stats = warm.stats;
    let start = Instant::now();
    for _ in 0..iters {
        let out = field.forward(&input).unwrap();
        let _ = out.render(&b.samples.view()).unwrap().rgb.into_data();
    }
    let fwd = start.elapsed().as_secs_f64() / iters as f64;

    let ad = device.clone().autodiff();
    let mut field = cfg
        .init(&ladder_prior(), &ad, &mut WeightRng::seeded(17))
        .expect("field");
    let mut optim = AdamConfig::new().init();
    let r = b.samples.offsets.len() - 1;
    let target = Tensor::<2>::full([r, 3], 0.5, &ad);
    let mut train = 0.0;
    for i in 0..=iters {
        let start = Instant::now();
        let out = field.forward(&input).unwrap();
        let rgb = out.render(&b.samples.view()).unwrap().rgb_over([1.0; 3]);
        let loss = (rgb - target.clone()).square().mean();
        let grads = GradientsParams::from_grads(loss.backward(), &field);
        field = optim.step(5e-4, field, grads);
        let _ = field.identity.val().into_data();
        if i > 0 {
            train += start.elapsed().as_secs_f64(); // the first step is warm-up
        }
    }
    let train = train / iters as f64;
    println!(
        "| {device_name:<6} | {preset:<5} | {n:>7} | {:>5}/{:>5} | {:>10.0} | {:>10.0} | {:>8.3} |",
        stats.face_rows,
        stats.hand_rows,
        n as f64 / fwd,
        n as f64 / train,
        train
    );
}

/// Raw matmul rate of this machine (GFLOP/s), the ceiling for the MLP-bound paper preset.
fn gemm_probe(device: &Device) -> f64 {
    let a = Tensor::<2>::ones([65_536, 256], device);
    let b = Tensor::<2>::ones([256, 256], device);
    let _ = a.clone().matmul(b.clone()).into_data();
    let start = Instant::now();
    for _ in 0..5 {
        let _ = a.clone().matmul(b.clone()).into_data();
    }
    5.0 * 2.0 * 65_536.0 * 256.0 * 256.0 / start.elapsed().as_secs_f64() / 1e9
}

fn main() {
    let rays = env("RAYS", 4096);
    let per_ray = env("SAMPLES", 32);
    let iters = env("ITERS", 3).max(1);
    let b = batch(rays, per_ray);
    println!("field throughput, {rays} rays x {per_ray} samples, mean of {iters} iterations");
    println!(
        "flex matmul [65536,256]x[256,256]: {:.1} GFLOP/s",
        gemm_probe(&Device::flex())
    );
    println!(
        "| device | preset | samples | face/hand rows | fwd samples/s | train samples/s | train s/step |"
    );
    println!(
        "|--------|--------|---------|----------------|---------------|-----------------|--------------|"
    );
    let presets: Vec<String> = std::env::var("PRESETS")
        .map(|p| p.split(',').map(str::to_owned).collect())
        .unwrap_or_else(|_| vec!["fast".into(), "paper".into()]);
    for preset in &presets {
        run(&Device::flex(), "flex", preset, &b, iters);
    }
    #[cfg(feature = "wgpu")]
    {
        let probe = std::panic::catch_unwind(|| {
            let device = Device::wgpu(burn::prelude::DeviceKind::DefaultDevice);
            let _ = Tensor::<1>::zeros([1], &device).into_data();
            device
        });
        match probe {
            Ok(device) => {
                for preset in &presets {
                    run(&device, "wgpu", preset, &b, iters);
                }
            }
            Err(_) => println!("wgpu: no adapter, skipped"),
        }
    }
}
