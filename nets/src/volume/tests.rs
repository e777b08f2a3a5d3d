use super::*;
use crate::util::host;

/// Plain per-ray f64 reference: (rgb, opacity, depth, T_end) per ray.
fn reference(sigma: &[f64], rgb: &[f64], s: &OwnedRaySamples) -> Vec<([f64; 3], f64, f64, f64)> {
    let mut out = Vec::new();
    for w in s.offsets.windows(2) {
        let (mut c, mut o, mut d, mut depth) = ([0.0; 3], 0.0, 0.0, 0.0f64);
        for i in w[0]..w[1] {
            let delta = (s.t_end[i] as f64 - s.t_start[i] as f64).max(0.0);
            let tau = (sigma[i].max(0.0) * delta).min(MAX_OPTICAL_DEPTH as f64);
            let weight = (-depth).exp() * (1.0 - (-tau).exp());
            for k in 0..3 {
                c[k] += weight * rgb[i * 3 + k];
            }
            o += weight;
            d += weight * 0.5 * (s.t_start[i] as f64 + s.t_end[i] as f64);
            depth += tau;
        }
        out.push((c, o, d, (-depth).exp()));
    }
    out
}

/// Deterministic pseudo-random numbers in [0, 1).
fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

fn batch(lengths: &[usize], seed: &mut u64) -> (OwnedRaySamples, Vec<f64>, Vec<f64>) {
    let mut s = OwnedRaySamples {
        offsets: vec![0],
        ..Default::default()
    };
    let (mut sigma, mut rgb) = (Vec::new(), Vec::new());
    for &len in lengths {
        let mut t = 1.0f32;
        for _ in 0..len {
            let dt = 0.01 + 0.1 * lcg(seed) as f32;
            s.t_start.push(t);
            s.t_end.push(t + dt);
            t += dt + 0.05 * lcg(seed) as f32;
            sigma.push(8.0 * lcg(seed));
            rgb.extend([lcg(seed), lcg(seed), lcg(seed)]);
        }
        s.offsets.push(s.t_start.len());
    }
    (s, sigma, rgb)
}

fn tensors(sigma: &[f64], rgb: &[f64], device: &Device) -> (Tensor<1>, Tensor<2>) {
    let n = sigma.len();
    (
        floats(sigma.iter().map(|&v| v as f32).collect(), [n], device),
        floats(rgb.iter().map(|&v| v as f32).collect(), [n, 3], device),
    )
}

#[test]
fn matches_per_ray_reference() {
    let device = Device::flex();
    let mut seed = 7;
    // Long and short rays, empty rays at the start, middle and end.
    let (s, sigma, rgb) = batch(&[0, 5, 1, 0, 37, 128, 2, 0], &mut seed);
    let (sig_t, rgb_t) = tensors(&sigma, &rgb, &device);
    let out = render_packed(sig_t, rgb_t.clone(), rgb_t, &s.view()).unwrap();
    let (c, o, d) = (host(&out.rgb), host(&out.opacity), host(&out.depth));
    let seg = host(&out.seg_logits);
    for (k, (rc, ro, rd, _)) in reference(&sigma, &rgb, &s).iter().enumerate() {
        for j in 0..3 {
            assert!((c[k * 3 + j] as f64 - rc[j]).abs() < 1e-5, "ray {k}");
            assert!((seg[k * 3 + j] as f64 - rc[j]).abs() < 1e-5, "ray {k}");
        }
        assert!((o[k] as f64 - ro).abs() < 1e-5, "ray {k}");
        assert!((d[k] as f64 - rd).abs() < 1e-4 * (1.0 + rd), "ray {k}");
    }
    let over = host(&out.rgb_over([1.0, 0.5, 0.0]));
    assert!((over[0] - 1.0).abs() < 1e-6 && (over[1] - 0.5).abs() < 1e-6); // empty ray 0
}

#[test]
fn hard_cases_stay_finite() {
    let device = Device::flex().autodiff();
    // sigma 1e6, zero-length and reversed intervals, an empty ray, and a later ray that
    // must be unaffected by the huge optical depth before it.
    let s = OwnedRaySamples {
        offsets: vec![0, 3, 3, 5, 7],
        t_start: vec![0.0, 0.5, 0.5, 1.0, 1.5, 2.0, 2.1],
        t_end: vec![0.5, 0.5, 1.0, 1.5, 1.4, 2.1, 2.2],
    };
    let sigma_h = [1e6, 1e6, 1e6, 1e6, 3.0, 0.0, 2.0];
    let rgb_h: Vec<f64> = (0..21).map(|i| (i % 5) as f64 / 4.0).collect();
    let (sigma, rgb) = tensors(&sigma_h, &rgb_h, &device);
    let (sigma, rgb) = (sigma.require_grad(), rgb.require_grad());
    let out = render_packed(sigma.clone(), rgb.clone(), rgb.clone(), &s.view()).unwrap();
    let loss = out.rgb.clone().sum() + out.opacity.clone().sum() + out.depth.clone().sum();
    let grads = loss.backward();
    for v in host(&out.rgb)
        .iter()
        .chain(&host(&out.opacity))
        .chain(&host(&out.depth))
    {
        assert!(v.is_finite());
    }
    for v in host(&sigma.grad(&grads).unwrap())
        .iter()
        .chain(&host(&rgb.grad(&grads).unwrap()))
    {
        assert!(v.is_finite());
    }
    let o = host(&out.opacity);
    assert!((o[0] - 1.0).abs() < 1e-6, "opaque ray");
    assert_eq!(o[1], 0.0, "empty ray");
    let reference = reference(&sigma_h, &rgb_h, &s);
    assert!((o[2] as f64 - reference[2].1).abs() < 1e-6);
    assert!(
        (o[3] as f64 - reference[3].1).abs() < 1e-6,
        "later ray unaffected"
    );
}

#[test]
fn all_empty_batch() {
    let device = Device::flex();
    let s = OwnedRaySamples {
        offsets: vec![0, 0, 0],
        ..Default::default()
    };
    let out = render_packed(
        Tensor::zeros([0], &device),
        Tensor::zeros([0, 3], &device),
        Tensor::zeros([0, 5], &device),
        &s.view(),
    )
    .unwrap();
    assert_eq!(out.rgb.dims(), [2, 3]);
    assert_eq!(out.seg_logits.dims(), [2, 5]);
    assert_eq!(host(&out.opacity), vec![0.0, 0.0]);
    let none = OwnedRaySamples {
        offsets: vec![0],
        ..Default::default()
    };
    let out = render_packed(
        Tensor::zeros([0], &device),
        Tensor::zeros([0, 3], &device),
        Tensor::zeros([0, 5], &device),
        &none.view(),
    )
    .unwrap();
    assert_eq!(out.rgb.dims(), [0, 3]);
}

#[test]
fn rejects_malformed_offsets() {
    let s = OwnedRaySamples {
        offsets: vec![0, 2, 1],
        t_start: vec![0.0],
        t_end: vec![1.0],
    };
    assert!(matches!(s.view().validate(), Err(NetsError::Offsets(_))));
}

/// Autodiff vs central differences of the f64 reference, w.r.t. sigma and rgb.
#[test]
fn gradients_match_central_differences() {
    let device = Device::flex().autodiff();
    let mut seed = 11;
    let (s, sigma, rgb) = batch(&[4, 0, 9, 1], &mut seed);
    let n = sigma.len();
    let coeff: Vec<f64> = (0..4 * 5)
        .map(|i| ((i * 5 % 7) as f64 - 3.0) / 3.0)
        .collect();
    let loss_ref = |sigma: &[f64], rgb: &[f64]| -> f64 {
        reference(sigma, rgb, &s)
            .iter()
            .enumerate()
            .map(|(k, (c, o, d, _))| {
                let q = &coeff[k * 5..k * 5 + 5];
                q[0] * c[0] + q[1] * c[1] + q[2] * c[2] + q[3] * o + q[4] * d
            })
            .sum()
    };
    let (sig_t, rgb_t) = tensors(&sigma, &rgb, &device);
    let (sig_t, rgb_t) = (sig_t.require_grad(), rgb_t.require_grad());
    let out = render_packed(sig_t.clone(), rgb_t.clone(), rgb_t.clone(), &s.view()).unwrap();
    let q = floats(coeff.iter().map(|&v| v as f32).collect(), [4, 5], &device);
    let stacked = Tensor::cat(
        vec![
            out.rgb,
            out.opacity.unsqueeze_dim(1),
            out.depth.unsqueeze_dim(1),
        ],
        1,
    );
    let grads = (stacked * q).sum().backward();
    let (g_sigma, g_rgb) = (
        host(&sig_t.grad(&grads).unwrap()),
        host(&rgb_t.grad(&grads).unwrap()),
    );
    let h = 1e-6;
    for i in 0..n {
        let (mut p, mut m) = (sigma.clone(), sigma.clone());
        p[i] += h;
        m[i] -= h;
        let fd = (loss_ref(&p, &rgb) - loss_ref(&m, &rgb)) / (2.0 * h);
        assert!(
            (fd - g_sigma[i] as f64).abs() < 2e-4 * (1.0 + fd.abs()),
            "dsigma[{i}] {fd} vs {}",
            g_sigma[i]
        );
    }
    for i in 0..3 * n {
        let (mut p, mut m) = (rgb.clone(), rgb.clone());
        p[i] += h;
        m[i] -= h;
        let fd = (loss_ref(&sigma, &p) - loss_ref(&sigma, &m)) / (2.0 * h);
        assert!(
            (fd - g_rgb[i] as f64).abs() < 2e-4 * (1.0 + fd.abs()),
            "drgb[{i}]"
        );
    }
}

/// A sum of `stacked`'s entries with fixed weights of both signs, for a backward that
/// reaches every entry.
#[cfg(feature = "wgpu")]
fn mixed_sum(stacked: &Tensor<2>) -> Tensor<1> {
    let [r, c] = stacked.dims();
    let q: Vec<f32> = (0..r * c)
        .map(|i| ((i * 5 % 7) as f32 - 3.0) / 3.0)
        .collect();
    (stacked.clone() * floats(q, [r, c], &stacked.device())).sum()
}

/// The device op (`kernels::cube::render`) renders and differentiates a batch as the
/// CPU's scan does: long, short and empty rays, a huge density, zero-length intervals,
/// through a body pass and a hands pass in front of it (the final transmittance).
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn device_op_renders_like_the_cpu() {
    let gpu = crate::device::test_wgpu().autodiff();
    let mut seed = 5;
    let (mut s, mut sigma, rgb) = batch(&[0, 5, 1, 0, 37, 128, 2, 0, 9], &mut seed);
    sigma[3] = 1e6;
    sigma[50] = 1e6;
    s.t_end[7] = s.t_start[7];
    let (front, front_sigma, front_rgb) = batch(&[2, 0, 1, 0, 3, 0, 0, 4, 1], &mut seed);
    let run = |device: &Device| {
        let (sig, col) = tensors(&sigma, &rgb, device);
        let (sig, col) = (sig.require_grad(), col.require_grad());
        let (fs, fc) = tensors(&front_sigma, &front_rgb, device);
        let fs = fs.require_grad();
        let body = render_packed(sig.clone(), col.clone(), col.clone(), &s.view()).unwrap();
        let out = render_in_front(fs.clone(), fc, &front.view(), &body).unwrap();
        let stacked = Tensor::cat(
            vec![
                out.rgb,
                out.seg_logits,
                out.opacity.unsqueeze_dim(1),
                out.depth.unsqueeze_dim(1),
            ],
            1,
        );
        let grads = mixed_sum(&stacked).backward();
        [
            host(&stacked),
            host(&sig.grad(&grads).unwrap()),
            host(&col.grad(&grads).unwrap()),
            host(&fs.grad(&grads).unwrap()),
        ]
    };
    let (cpu, dev) = (run(&Device::flex().autodiff()), run(&gpu));
    for (what, a, b) in [
        ("rendered", &dev[0], &cpu[0]),
        ("sigma gradient", &dev[1], &cpu[1]),
        ("rgb gradient", &dev[2], &cpu[2]),
        ("front sigma gradient", &dev[3], &cpu[3]),
    ] {
        crate::util::assert_close_to(what, a, b, 1e-4);
    }
}

/// The per-ray sums' device op (`kernels::cube::ray_sums`) against the CPU's scatter:
/// a value per sample, one row shared by every sample (whose gradient sums all of them),
/// and the opacity, with empty rays at both ends and in the middle, a ray of 300 samples
/// and a density of 1e6; values and the densities', values' and shared row's gradients.
#[cfg(feature = "wgpu")]
#[test]
#[ignore = "needs a Vulkan adapter (lavapipe will do): \
            cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
fn device_op_ray_sums_match_the_cpu() {
    let gpu = crate::device::test_wgpu().autodiff();
    let mut seed = 11;
    let (s, mut sigma, rgb) = batch(&[0, 4, 1, 0, 300, 7, 0], &mut seed);
    sigma[2] = 1e6;
    let n = sigma.len();
    let run = |device: &Device| {
        let (sig, col) = tensors(&sigma, &rgb, device);
        let (sig, col) = (sig.require_grad(), col.require_grad());
        let shared = floats(vec![0.25, -1.5], [1, 2], device).require_grad();
        let weights = RenderWeights::new(sig.clone(), &s.view()).unwrap();
        let stacked = Tensor::cat(
            vec![
                weights.integrate(col.clone()),
                weights.integrate(shared.clone()),
                weights.opacity().unsqueeze_dim(1),
            ],
            1,
        );
        let grads = mixed_sum(&stacked).backward();
        [
            host(&stacked),
            host(&sig.grad(&grads).unwrap()),
            host(&col.grad(&grads).unwrap()),
            host(&shared.grad(&grads).unwrap()),
        ]
    };
    let (cpu, dev) = (run(&Device::flex().autodiff()), run(&gpu));
    assert_eq!(dev[2].len(), n * 3);
    for (what, a, b) in [
        ("sums", &dev[0], &cpu[0]),
        ("sigma gradient", &dev[1], &cpu[1]),
        ("values gradient", &dev[2], &cpu[2]),
        ("shared row gradient", &dev[3], &cpu[3]),
    ] {
        crate::util::assert_close_to(what, a, b, 1e-4);
    }
}

#[test]
fn hands_in_front_of_body_background() {
    let device = Device::flex();
    let mut seed = 3;
    let (s, sigma, rgb) = batch(&[6, 0, 4], &mut seed);
    let (sig_t, rgb_t) = tensors(&sigma, &rgb, &device);
    let body = render_packed(sig_t, rgb_t.clone(), rgb_t, &s.view()).unwrap();
    let subset = [1usize, 4, 7];
    let front = OwnedRaySamples::subset(&s.view(), &subset);
    assert_eq!(front.offsets, vec![0, 2, 2, 3]);
    let hs: Vec<f64> = vec![5.0, 1.0, 20.0];
    let hc: Vec<f64> = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let (hs_t, hc_t) = tensors(&hs, &hc, &device);
    let out = render_in_front(hs_t, hc_t, &front.view(), &body).unwrap();
    let front_ref = reference(&hs, &hc, &front);
    let body_ref = reference(&sigma, &rgb, &s);
    let c = host(&out.rgb);
    for k in 0..3 {
        let t_end = front_ref[k].3;
        for j in 0..3 {
            let want = front_ref[k].0[j] + t_end * body_ref[k].0[j];
            assert!((c[k * 3 + j] as f64 - want).abs() < 1e-5);
        }
    }
}
