//! Adam in one pass per parameter on the CPU backend.
//!
//! burn's Adam updates a parameter with ~14 whole-tensor ops (moments, square, sqrt,
//! division, ...), most allocating a fresh tensor. For the `fast` preset's three 11 MB hash
//! tables that was ~14% of a training step (perf). This is the same update, in the same
//! f32 operation order, as one parallel pass over the parameter, its gradient and both
//! moments, in place where the buffers are not shared. Its state is burn's `AdamState`, so
//! checkpoints written with either optimizer load in the other. On a CubeCL device (the
//! `wgpu` feature) the same update is one device kernel per parameter
//! (`kernels::cube::adam`); other tensors go through burn's Adam.

use burn::backend::Flex;
use burn::backend::flex::FlexTensor;
use burn::optim::{Adam, AdamConfig, AdamState, AdaptiveMomentumState, LearningRate, Optimizer};
use burn::prelude::*;
use burn::tensor::{DType, TensorData};
use rayon::prelude::*;

use crate::profile::{self, Work};

/// Elements per parallel task.
const CHUNK: usize = 1 << 16;

/// Adam (no weight decay, no AMSGrad) with burn's update rule.
#[derive(Clone)]
pub struct FusedAdam {
    beta_1: f32,
    beta_2: f32,
    epsilon: f32,
    /// The same optimizer from burn, for tensors the fused pass cannot take.
    fallback: Adam,
}

impl FusedAdam {
    pub fn new(beta_1: f32, beta_2: f32, epsilon: f32) -> FusedAdam {
        FusedAdam {
            beta_1,
            beta_2,
            epsilon,
            fallback: AdamConfig::new()
                .with_beta_1(beta_1)
                .with_beta_2(beta_2)
                .with_epsilon(epsilon)
                .build(),
        }
    }

    /// Whether the parameter, its gradient and its state are plain (not autodiff) f32
    /// tensors on `device`, and the state has no AMSGrad maximum: what either kernel takes.
    fn plain_on<const D: usize>(
        device: &Device,
        tensor: &Tensor<D>,
        grad: &Tensor<D>,
        state: Option<&AdamState<D>>,
    ) -> bool {
        let plain =
            |t: &Tensor<D>| t.device() == *device && !t.is_autodiff() && t.dtype() == DType::F32;
        plain(tensor)
            && plain(grad)
            && state.is_none_or(|s| {
                plain(&s.momentum.moment_1)
                    && plain(&s.momentum.moment_2)
                    && s.momentum.max_moment_2.is_none()
            })
    }

    /// Whether the fused CPU pass takes these tensors: plain ones on the Flex backend.
    fn takes<const D: usize>(
        tensor: &Tensor<D>,
        grad: &Tensor<D>,
        state: Option<&AdamState<D>>,
    ) -> bool {
        Self::plain_on(&Device::flex(), tensor, grad, state)
    }

    /// `[beta_1, beta_2, combined, epsilon, lr]` of step `time` (from 1): burn's
    /// bias-corrected factors, in f32 as burn computes them.
    fn factors(&self, lr: LearningRate, time: usize) -> [f32; 5] {
        let bias_2_sqrt = (1.0 - self.beta_2.powi(time as i32)).sqrt();
        let combined = bias_2_sqrt / (1.0 - self.beta_1.powi(time as i32));
        let eps = self.epsilon * bias_2_sqrt;
        [self.beta_1, self.beta_2, combined, eps, lr as f32]
    }

    /// Whether the device kernel (`kernels::cube::adam`) takes these tensors: plain
    /// ones off the CPU.
    #[cfg(feature = "wgpu")]
    fn on_device<const D: usize>(
        tensor: &Tensor<D>,
        grad: &Tensor<D>,
        state: Option<&AdamState<D>>,
    ) -> bool {
        let device = tensor.device();
        !crate::device::is_cpu(&device) && Self::plain_on(&device, tensor, grad, state)
    }

    /// The step on a CubeCL device: one kernel for the parameter and both moments.
    #[cfg(feature = "wgpu")]
    fn device_step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<AdamState<D>>,
    ) -> (Tensor<D>, AdamState<D>) {
        let (time, m, v) = match state {
            Some(s) => (s.momentum.time, s.momentum.moment_1, s.momentum.moment_2),
            None => (0, tensor.zeros_like(), tensor.zeros_like()),
        };
        let time = time + 1;
        let (tensor, m, v) = super::cube::adam::step(tensor, grad, m, v, self.factors(lr, time));
        let state = AdamState::new(AdaptiveMomentumState::new(time, m, v));
        (tensor, state)
    }

    /// The fused step on tensors [`FusedAdam::takes`]. It takes them by value: a buffer
    /// nobody else holds is updated in place, where a shared one would be copied first.
    fn fused<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<AdamState<D>>,
    ) -> (Tensor<D>, AdamState<D>) {
        let shape = tensor.shape();
        let n = shape.num_elements();
        let primitive = |t: Tensor<D>| -> FlexTensor {
            let p = t
                .try_into_primitive::<Flex>()
                .expect("takes() checked: an f32 tensor on Flex");
            if p.layout().contiguous_offsets() == Some((0, n)) {
                p
            } else {
                p.to_contiguous()
            }
        };
        let mut param = primitive(tensor);
        let grad = primitive(grad);
        let zeros = || FlexTensor::from_data(TensorData::new(vec![0f32; n], shape.clone()));
        let (time, mut m, mut v) = match state {
            Some(s) => (
                s.momentum.time,
                primitive(s.momentum.moment_1),
                primitive(s.momentum.moment_2),
            ),
            None => (0, zeros(), zeros()),
        };
        let time = time + 1;
        let [b1, b2, combined, eps, lr] = self.factors(lr, time);
        let (f1, f2) = (1.0 - b1, 1.0 - b2);
        let g = grad.as_slice::<f32>().expect("a contiguous f32 gradient");
        // Copy-on-write: in place unless another tensor shares the buffer.
        let (p_s, m_s, v_s) = (
            param.storage_mut::<f32>(),
            m.storage_mut::<f32>(),
            v.storage_mut::<f32>(),
        );
        // Per element: the parameter, gradient and moments read, three of them written.
        let work = Work {
            flops: 12.0 * n as f64,
            bytes: 28.0 * n as f64,
            gathered: 0.0,
        };
        profile::timed_work("kernel: Adam", work, || {
            p_s[..n]
                .par_chunks_mut(CHUNK)
                .zip(m_s[..n].par_chunks_mut(CHUNK))
                .zip(v_s[..n].par_chunks_mut(CHUNK))
                .zip(g.par_chunks(CHUNK))
                .for_each(|(((p, m), v), g)| {
                    for (((p, m), v), &g) in p.iter_mut().zip(m).zip(v).zip(g) {
                        *m = *m * b1 + g * f1;
                        *v = *v * b2 + g * g * f2;
                        let step = (*m * combined) / (v.sqrt() + eps);
                        *p -= step * lr;
                    }
                })
        });
        let state = AdamState::new(AdaptiveMomentumState::new(
            time,
            Tensor::from_primitive::<Flex>(m),
            Tensor::from_primitive::<Flex>(v),
        ));
        (Tensor::from_primitive::<Flex>(param), state)
    }
}

impl Optimizer for FusedAdam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        #[cfg(feature = "wgpu")]
        if Self::on_device(&tensor, &grad, state.as_ref()) {
            let (tensor, state) = self.device_step(lr, tensor, grad, state);
            return (tensor, Some(state));
        }
        if Self::takes(&tensor, &grad, state.as_ref()) {
            let (tensor, state) = self.fused(lr, tensor, grad, state);
            (tensor, Some(state))
        } else {
            self.fallback.step(lr, tensor, grad, state)
        }
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        <Adam as Optimizer>::to_device(state, device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
        t.clone().try_to_vec_as::<f32>().unwrap()
    }

    /// Five steps of `FusedAdam` and of burn's Adam from one start on `device`, with
    /// gradients of every scale (zeros, tiny, huge), each step taking the path `takes`
    /// names; the parameter and both moments agree to `tolerance` relative.
    fn against_burns_adam(
        device: &Device,
        n: usize,
        takes: fn(&Tensor<2>, &Tensor<2>, Option<&AdamState<2>>) -> bool,
        tolerance: f32,
    ) {
        let values = |seed: u32, scale: f32| -> Vec<f32> {
            (0..n as u32)
                .map(|i| {
                    let h = (i.wrapping_mul(2_654_435_761) ^ seed.wrapping_mul(97)) >> 8;
                    let u = h as f32 / (1u32 << 24) as f32 - 0.5;
                    match i % 5 {
                        0 => 0.0,
                        1 => u * 1e-12,
                        2 => u * 1e6,
                        _ => u * scale,
                    }
                })
                .collect()
        };
        let tensor = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [n, 1]), device);
        let fused = FusedAdam::new(0.9, 0.99, 1e-15);
        let burn = fused.fallback.clone();
        let (mut p_fused, mut p_burn) = (tensor(values(0, 1.0)), tensor(values(0, 1.0)));
        let (mut s_fused, mut s_burn) = (None, None);
        for step in 0..5u32 {
            let g = tensor(values(step + 1, 0.1));
            let lr = 1e-2 * 0.9f64.powi(step as i32);
            assert!(takes(&p_fused, &g, s_fused.as_ref()));
            (p_fused, s_fused) = fused.step(lr, p_fused, g.clone(), s_fused);
            (p_burn, s_burn) = burn.step(lr, p_burn, g, s_burn);
        }
        let (sf, sb) = (s_fused.unwrap().momentum, s_burn.unwrap().momentum);
        assert_eq!(sf.time, sb.time);
        for (what, a, b) in [
            ("parameter", host(&p_fused), host(&p_burn)),
            ("moment 1", host(&sf.moment_1), host(&sb.moment_1)),
            ("moment 2", host(&sf.moment_2), host(&sb.moment_2)),
        ] {
            for (i, (x, y)) in a.iter().zip(&b).enumerate() {
                assert!(
                    x == y || (x - y).abs() <= tolerance * y.abs(),
                    "{what}[{i}]: fused {x}, burn {y}"
                );
            }
        }
    }

    /// On the CPU the fused pass gives burn's Adam bit for bit or within an ulp.
    #[test]
    fn matches_burns_adam() {
        against_burns_adam(
            &Device::flex(),
            3 * CHUNK + 17,
            FusedAdam::takes,
            2.0 * f32::EPSILON,
        );
    }

    /// With nobody else holding them, the parameter and both moments are updated in
    /// their own buffers: no copy of a whole table per step.
    #[test]
    fn updates_unshared_buffers_in_place() {
        let device = Device::flex();
        let address = |t: Tensor<1>| -> (Tensor<1>, usize) {
            let p = t.try_into_primitive::<Flex>().unwrap();
            let at = p.as_slice::<f32>().unwrap().as_ptr() as usize;
            (Tensor::from_primitive::<Flex>(p), at)
        };
        let tensor =
            |v: f32| Tensor::<1>::from_data(TensorData::new(vec![v; 1000], [1000]), &device);
        let fused = FusedAdam::new(0.9, 0.99, 1e-8);
        let (p, _) = fused.step(1e-2, tensor(1.0), tensor(0.5), None);
        let state = None::<AdamState<1>>;
        let (p, state) = fused.step(1e-2, p, tensor(0.5), state);
        let state = state.unwrap();
        let (p, p_at) = address(p);
        let (m, m_at) = address(state.momentum.moment_1);
        let (v, v_at) = address(state.momentum.moment_2);
        let state = AdamState::new(AdaptiveMomentumState::new(state.momentum.time, m, v));
        let (p, state) = fused.step(1e-2, p, tensor(0.5), Some(state));
        let state = state.unwrap();
        assert_eq!(address(p).1, p_at, "parameter copied");
        assert_eq!(
            address(state.momentum.moment_1).1,
            m_at,
            "first moment copied"
        );
        assert_eq!(
            address(state.momentum.moment_2).1,
            v_at,
            "second moment copied"
        );
    }

    /// A tensor the fused pass cannot take (here: one on the autodiff device) goes through
    /// burn's Adam.
    #[test]
    fn other_tensors_fall_back() {
        let device = Device::flex().autodiff();
        let p = Tensor::<1>::from_data(TensorData::new(vec![1.0f32, 2.0], [2]), &device);
        let g = Tensor::<1>::from_data(TensorData::new(vec![0.5f32, -0.5], [2]), &device);
        let fused = FusedAdam::new(0.9, 0.99, 1e-8);
        assert!(!FusedAdam::takes(&p, &g, None));
        let (p, state) = fused.step(1e-2, p, g, None);
        assert!(state.is_some());
        let v = host(&p);
        assert!(
            (v[0] - 0.99).abs() < 1e-6 && (v[1] - 2.01).abs() < 1e-6,
            "{v:?}"
        );
    }

    /// The device kernel (`kernels::cube::adam`) against burn's Adam on the same wgpu
    /// device.
    #[cfg(feature = "wgpu")]
    #[test]
    #[ignore = "needs a Vulkan adapter (lavapipe will do): \
                cargo test --release --features wgpu -p talkin-nets -p talkin --lib --test device -- --ignored"]
    fn device_op_adam_matches_burns() {
        against_burns_adam(
            &crate::device::test_wgpu(),
            1000,
            FusedAdam::on_device,
            1e-6,
        );
    }
}
