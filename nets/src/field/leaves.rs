//! A frame's conditions as differentiable leaves: what pose refinement learns through.
//!
//! [`crate::TalkinField::forward_with_leaves`] reads the frame's skinning transforms
//! (`canonical_from_posed`, `[55, 12]`: the top three rows of each 4x4), D_nr's body pose,
//! the face's expression and jaw and D_hands' hand pose from these tensors instead of the
//! host copies in [`FrameConditions`], so that one backward gives the loss's gradient
//! with respect to each of them. Where the pose goes from there (forward kinematics) is
//! the caller's business: this crate knows no skeleton.

use burn::prelude::*;
use burn::tensor::Gradients;

use super::{EXPRESSION_DIM, FrameConditions, HAND_POSE_DIM, JAW_DIM};
use crate::skinning::N_SMPLX_JOINTS;
use crate::util::{floats, host};

/// Rows of a skinning transform that carry numbers (the bottom row is `0 0 0 1`).
pub const TRANSFORM_ROWS: usize = 12;

/// One frame's conditions as leaves that require gradients.
#[derive(Clone, Debug)]
pub struct PoseLeaves {
    /// `[55, 12]` row-major top three rows of each `canonical_from_posed`.
    pub canonical_from_posed: Tensor<2>,
    /// `[1, pose_dim]` D_nr's body pose.
    pub body_pose: Tensor<2>,
    /// `[1, 10]`
    pub expression: Tensor<2>,
    /// `[1, 3]`
    pub jaw: Tensor<2>,
    /// `[1, 90]`
    pub hand_pose: Tensor<2>,
}

/// The loss's gradient with respect to each leaf (zeros where the forward did not use
/// one: a field without D_nr gives no body-pose gradient).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseGrads {
    /// `[55]` gradients of the top three rows of each `canonical_from_posed`.
    pub canonical_from_posed: Vec<[f32; TRANSFORM_ROWS]>,
    pub body_pose: Vec<f32>,
    pub expression: Vec<f32>,
    pub jaw: Vec<f32>,
    pub hand_pose: Vec<f32>,
}

impl PoseGrads {
    /// Adds `other` in place (two chunks of a batch).
    pub fn accumulate(&mut self, other: &PoseGrads) {
        fn add(a: &mut Vec<f32>, b: &[f32]) {
            if a.is_empty() {
                a.extend_from_slice(b);
            } else {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
            }
        }
        if self.canonical_from_posed.is_empty() {
            self.canonical_from_posed = other.canonical_from_posed.clone();
        } else {
            for (a, b) in self
                .canonical_from_posed
                .iter_mut()
                .zip(&other.canonical_from_posed)
            {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
            }
        }
        add(&mut self.body_pose, &other.body_pose);
        add(&mut self.expression, &other.expression);
        add(&mut self.jaw, &other.jaw);
        add(&mut self.hand_pose, &other.hand_pose);
    }

    /// True if every gradient is finite.
    pub fn is_finite(&self) -> bool {
        self.canonical_from_posed
            .iter()
            .flatten()
            .chain(&self.body_pose)
            .chain(&self.expression)
            .chain(&self.jaw)
            .chain(&self.hand_pose)
            .all(|v| v.is_finite())
    }
}

impl PoseLeaves {
    /// `frame`'s conditions as fresh leaves on `device` (an autodiff device).
    pub fn new(frame: &FrameConditions, device: &Device) -> PoseLeaves {
        let rows: Vec<f32> = frame
            .canonical_from_posed
            .iter()
            .flat_map(|m| m[..TRANSFORM_ROWS].iter().copied())
            .collect();
        let n = frame.canonical_from_posed.len();
        let leaf = |v: Vec<f32>, shape: [usize; 2]| floats(v, shape, device).require_grad();
        PoseLeaves {
            canonical_from_posed: leaf(rows, [n, TRANSFORM_ROWS]),
            body_pose: leaf(frame.body_pose.clone(), [1, frame.body_pose.len()]),
            expression: leaf(frame.expression.to_vec(), [1, EXPRESSION_DIM]),
            jaw: leaf(frame.jaw.to_vec(), [1, JAW_DIM]),
            hand_pose: leaf(frame.hand_pose.clone(), [1, frame.hand_pose.len()]),
        }
    }

    /// The leaves' gradients in `grads` (read back to the host).
    pub fn grads(&self, grads: &Gradients) -> PoseGrads {
        let read = |t: &Tensor<2>| {
            let [_, c] = t.dims();
            let n = t.dims()[0] * c;
            t.grad(grads)
                .map(|g| host(&g))
                .unwrap_or_else(|| vec![0.0; n])
        };
        let rows = read(&self.canonical_from_posed);
        PoseGrads {
            canonical_from_posed: rows
                .chunks_exact(TRANSFORM_ROWS)
                .map(|c| c.try_into().expect("chunks of 12"))
                .collect(),
            body_pose: read(&self.body_pose),
            expression: read(&self.expression),
            jaw: read(&self.jaw),
            hand_pose: read(&self.hand_pose),
        }
    }
}

/// Zero gradients of a frame's leaves (a chunk of a batch with no samples).
pub fn zero_grads(pose_dim: usize) -> PoseGrads {
    PoseGrads {
        canonical_from_posed: vec![[0.0; TRANSFORM_ROWS]; N_SMPLX_JOINTS],
        body_pose: vec![0.0; pose_dim],
        expression: vec![0.0; EXPRESSION_DIM],
        jaw: vec![0.0; JAW_DIM],
        hand_pose: vec![0.0; HAND_POSE_DIM],
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{batch, force_body, tiny_fast};
    use super::*;
    use crate::FieldInput;
    use crate::field::FrameConditions;
    use crate::field::{PART_BIT_HANDS, PART_BIT_HEAD};
    use crate::init::WeightRng;
    use crate::skinning::ladder_prior;

    /// Through the leaves the field gives the host path's outputs, and the skinning
    /// transforms' gradient is the chain rule's: with one candidate bone the warp is rigid,
    /// `x_c = R x + t`, so `d sum(x_c) / d t = n` per axis and `d / d R[i][k] = sum x_k`.
    #[test]
    fn leaves_give_the_host_outputs_and_the_rigid_warps_gradient() {
        let device = Device::flex().autodiff();
        let (pts, _) = batch(5, 6);
        let n = pts.len();
        let bones = vec![1u64 << 15; n];
        let parts: Vec<u8> = vec![PART_BIT_HEAD | PART_BIT_HANDS; n];
        let mut frame = FrameConditions::still();
        // A turned and shifted head transform.
        frame.canonical_from_posed[15] = [
            0.8, -0.6, 0.0, 0.1, //
            0.6, 0.8, 0.0, -0.2, //
            0.0, 0.0, 1.0, 0.05, //
            0.0, 0.0, 0.0, 1.0,
        ];
        let mut field = tiny_fast()
            .init(&ladder_prior(), &device, &mut WeightRng::seeded(5))
            .unwrap();
        // Every sample is labelled head: the face net sees them all.
        force_body(&mut field, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
        let input = FieldInput {
            points: &pts,
            bone_masks: &bones,
            part_masks: &parts,
            frame: &frame,
            step: 100,
        };
        let host_out = field.forward(&input).unwrap();
        let leaves = PoseLeaves::new(&frame, &device);
        let out = field.forward_with_leaves(&input, &leaves).unwrap();
        for (a, b) in [
            (host(&host_out.rgb), host(&out.rgb)),
            (host(&host_out.sigma), host(&out.sigma)),
        ] {
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-5 * (1.0 + x.abs()), "{x} vs {y}");
            }
        }

        // The rigid warp's gradient.
        let warp = field
            .skinning
            .inverse_lbs_with(
                &pts,
                &bones,
                &frame.canonical_from_posed,
                &[],
                &device,
                Some(&leaves.canonical_from_posed),
            )
            .unwrap();
        let g = leaves.grads(&warp.x_canonical.sum().backward());
        let sums: [f32; 3] = std::array::from_fn(|k| pts.iter().map(|p| p[k]).sum());
        for i in 0..3 {
            let row = &g.canonical_from_posed[15][4 * i..4 * i + 4];
            for k in 0..3 {
                assert!((row[k] - sums[k]).abs() < 1e-3, "{row:?} vs {sums:?}");
            }
            assert!((row[3] - n as f32).abs() < 1e-3, "{row:?}");
        }
        for b in (0..N_SMPLX_JOINTS).filter(|&b| b != 15) {
            assert!(g.canonical_from_posed[b].iter().all(|&v| v == 0.0));
        }

        // The whole forward: D_nr (started at step 100) and the face net put gradient on
        // the body pose, the expression and the jaw; D_hands sees no sample (no label is
        // hands), so the hand pose gets none.
        let out = field.forward_with_leaves(&input, &leaves).unwrap();
        let g = leaves.grads(&(out.rgb.sum() + out.sigma.sum()).backward());
        assert!(g.is_finite());
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!(norm(&g.body_pose) > 0.0);
        assert!(norm(&g.expression) > 0.0);
        assert!(norm(&g.jaw) > 0.0);
        assert_eq!(norm(&g.hand_pose), 0.0);
        assert!(norm(&g.canonical_from_posed[15]) > 0.0);
    }

    #[test]
    fn grads_add_up() {
        let mut a = zero_grads(63);
        let mut b = zero_grads(63);
        b.jaw[1] = 2.0;
        b.canonical_from_posed[3][7] = -1.0;
        a.accumulate(&b);
        a.accumulate(&b);
        assert_eq!(a.jaw, vec![0.0, 4.0, 0.0]);
        assert_eq!(a.canonical_from_posed[3][7], -2.0);
        let mut empty = PoseGrads::default();
        empty.accumulate(&b);
        assert_eq!(empty, b);
    }
}
