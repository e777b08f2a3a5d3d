//! The field, its render and the loss of a step (`LPIPS + 0.2 MSE + 0.05 CE(seg)`, or
//! without patches `MSE + 0.05 CE`), and the loss's gradients: on the CPU from chunks of
//! the batch run as rayon tasks, on a GPU from the whole batch.
//!
//! burn's Flex backend runs many ops on one core, so a step on one graph leaves the other
//! cores idle. The batch's rays are cut into chunks of `CHUNK_RAYS` (256); each chunk runs
//! forward and backward on its own fork of the field (`TalkinField::fork_leaves`: fresh
//! autodiff leaves, the same parameter ids, so the graphs never merge) as a rayon task,
//! whose fused kernels share rayon's threads, and the chunks' gradients are summed in
//! chunk order. Each chunk's loss is weighted by its share of the rays, so the sum is the
//! whole batch's loss and the summed gradient the whole batch's gradient. The cut depends
//! on the batch alone, not on the machine: any number of cores gives the same bits.

use burn::optim::GradientsParams;
use burn::prelude::*;
use talkin_avatar::field_inputs::packed_layout;
use talkin_grids::{PackedSamples, Ray};
use talkin_nets::field::leaves::zero_grads;
use talkin_nets::loss::{PerceptualLoss, PixelInputs, PixelLoss, PixelWeights, pixel_loss};
use talkin_nets::volume::{RenderedRays, distortion, hard_surface};
use talkin_nets::{
    FieldInput, FrameConditions, NetsError, PoseGrads, PoseLeaves, TalkinField, is_cpu,
};

use rayon::prelude::*;
use talkin_nets::kernels::grad_sum::sum_grads;
use talkin_nets::profile;

/// Weight of the segmentation cross-entropy.
pub const SEG_WEIGHT: f32 = 0.05;
/// Weight of the MSE next to the perceptual term (the paper's 0.2).
pub const MSE_WEIGHT: f32 = 0.2;
/// Weight of the frame codes' Gaussian prior (their squared norm): it keeps a code near
/// the others' mean, which is what frames without a code render with.
pub const FRAME_CODE_PRIOR: f32 = 1e-2;

/// One step's batch as the loss sees it.
pub(crate) struct StepBatch<'a> {
    /// The step's whole batch (every peer's rays).
    pub rays: &'a [Ray],
    /// The rays this process computes: all of them alone, a peer's share among peers
    /// (`crate::peers::share_of`). Each ray's loss is weighted by the whole batch's size.
    pub share: std::ops::Range<usize>,
    pub samples: PackedSamples,
    /// `[rays * 3]` in [0, 1].
    pub rgb: &'a [f32],
    pub labels: &'a [i32],
    /// Per ray, the weight of its silhouette term (0 on the mask's cut). `[rays]`
    pub silhouette: &'a [f32],
    /// Row-major 32x32 LPIPS patches at the start of the rays (0 without the term).
    pub patches: usize,
    pub patch_side: usize,
    pub frame: &'a FrameConditions,
    pub step: usize,
    pub background: [f32; 3],
    /// Weight of the opacity-against-mask term (0: off).
    pub mask_weight: f32,
    /// Weight of the distortion term (0: off).
    pub distortion: f32,
    /// Weight of the hard-surface term (0: off).
    pub hard_surface: f32,
    /// Differentiate with respect to the frame's pose too (pose refinement).
    pub pose_grads: bool,
}

/// The summed loss, its MSE part and the gradients of the whole batch (of a half: its
/// `[loss, mse]` still a tensor).
pub(crate) struct StepLoss<V = LossValues> {
    pub values: V,
    pub grads: GradientsParams,
    /// With [`StepBatch::pose_grads`]: the gradients w.r.t. the frame's conditions.
    pub pose: Option<PoseGrads>,
}

/// A step's loss and its MSE part: read on the CPU, where a read is a copy; on a GPU
/// left on the device, so that no step waits for its own work (the trainer reads a few
/// steps' values in one transfer).
pub(crate) enum LossValues {
    Read {
        loss: f32,
        mse: f32,
    },
    /// `[loss, mse]`.
    Queued(Box<Tensor<1>>),
}

impl LossValues {
    /// `[loss, mse]` of `values` (a `[2]` tensor): read now on the CPU, queued elsewhere.
    fn of(values: Tensor<1>) -> LossValues {
        if is_cpu(&values.device()) {
            let v = values.try_to_vec_as::<f32>().unwrap_or_default();
            let value = |i: usize| v.get(i).copied().unwrap_or(f32::NAN);
            LossValues::Read {
                loss: value(0),
                mse: value(1),
            }
        } else {
            LossValues::Queued(Box::new(values))
        }
    }

    /// The loss and MSE, read back now if they are still on the device.
    #[cfg(test)]
    pub fn read(&self) -> (f32, f32) {
        match self {
            LossValues::Read { loss, mse } => (*loss, *mse),
            LossValues::Queued(t) => {
                let v = t.as_ref().clone().try_to_vec_as::<f32>().unwrap();
                (v[0], v[1])
            }
        }
    }
}

/// Rays a chunk of the batch holds on the CPU (a 512-ray step: two chunks).
pub(crate) const CHUNK_RAYS: usize = 256;

/// Where a batch of `rays` is cut into chunks of about `chunk_rays`: the cuts, from 0 to
/// `rays`, never inside the LPIPS patches (the first `patch_rays`, scored whole by the
/// first chunk).
pub(crate) fn chunk_bounds(rays: usize, patch_rays: usize, chunk_rays: usize) -> Vec<usize> {
    let chunks = (rays / chunk_rays.max(1)).max(1);
    let mut bounds: Vec<usize> = (0..=chunks).map(|i| i * rays / chunks).collect();
    bounds.retain(|&b| b == 0 || b == rays || b >= patch_rays);
    bounds.dedup();
    bounds
}

/// The batch's loss (seg CE + MSE, or with patches LPIPS + 0.2 MSE + seg CE) and its
/// gradients w.r.t. `field`'s parameters, from chunks of [`CHUNK_RAYS`] in parallel.
pub(crate) fn loss_and_grads(
    field: &TalkinField,
    perceptual: Option<&PerceptualLoss>,
    batch: StepBatch,
) -> Result<StepLoss, NetsError> {
    loss_and_grads_in_chunks(field, perceptual, batch, CHUNK_RAYS)
}

/// [`loss_and_grads`] with chunks of `chunk_rays`.
fn loss_and_grads_in_chunks(
    field: &TalkinField,
    perceptual: Option<&PerceptualLoss>,
    batch: StepBatch,
    chunk_rays: usize,
) -> Result<StepLoss, NetsError> {
    let share = batch.share.clone();
    let n = share.len();
    if n == 0 {
        // A peer whose share is empty (more peers than rays beside the patches).
        let device = field.identity.val().device();
        return Ok(StepLoss {
            values: LossValues::of(Tensor::<1>::zeros([2], &device)),
            grads: GradientsParams::new(),
            pose: batch.pose_grads.then(|| zero_grads(field.pose_dim())),
        });
    }
    let samples = if share.len() == batch.rays.len() {
        None
    } else {
        let (_, rest) = batch.samples.split_at_ray(share.start);
        Some(rest.split_at_ray(n).0)
    };
    let samples = samples.as_ref().unwrap_or(&batch.samples);
    // The patches in this share: all of them in peer 0's (or the lone process's).
    let patch_rays = (batch.patches * batch.patch_side * batch.patch_side)
        .saturating_sub(share.start)
        .min(n);
    // A GPU takes the batch whole: its work is queued, not run on this thread.
    let on_cpu = is_cpu(&field.identity.val().device());
    let bounds = chunk_bounds(n, patch_rays, chunk_rays);
    if !on_cpu || bounds.len() <= 2 {
        let whole = chunk_loss(field, false, perceptual, &batch, share, samples)?;
        return Ok(StepLoss {
            values: LossValues::of(whole.values),
            grads: whole.grads,
            pose: whole.pose,
        });
    }
    // Each chunk's samples, cut off the rest in turn.
    let mut chunks = Vec::with_capacity(bounds.len() - 1);
    let mut rest: Option<PackedSamples> = None;
    for w in bounds.windows(2) {
        let (head, tail) = rest.as_ref().unwrap_or(samples).split_at_ray(w[1] - w[0]);
        chunks.push((share.start + w[0]..share.start + w[1], head));
        rest = Some(tail);
    }
    let parts: Vec<Result<StepLoss<Tensor<1>>, NetsError>> = chunks
        .par_iter()
        .map(|(range, samples)| chunk_loss(field, true, perceptual, &batch, range.clone(), samples))
        .collect();
    // Summed in chunk order: the same bits whichever thread ran which chunk.
    let mut parts = parts.into_iter();
    let first = parts.next().expect("at least two chunks")?;
    let (mut values, mut grads, mut pose) = (first.values, first.grads, first.pose);
    for part in parts {
        let part = part?;
        values = values + part.values;
        grads = profile::timed("step: gradient sum", || sum_grads(field, grads, part.grads));
        pose = match (pose, part.pose) {
            (Some(mut a), Some(b)) => {
                a.accumulate(&b);
                Some(a)
            }
            (a, b) => a.or(b),
        };
    }
    Ok(StepLoss {
        values: LossValues::of(values),
        grads,
        pose,
    })
}

/// Rays `range` of the batch (sampled as `samples`), in three stages: the field's render
/// of them, their loss (weighted by their share of the rays) and its backward. `fork`:
/// run on a fork of the field (needed when other chunks run at the same time).
fn chunk_loss(
    field: &TalkinField,
    fork: bool,
    perceptual: Option<&PerceptualLoss>,
    batch: &StepBatch,
    range: std::ops::Range<usize>,
    samples: &PackedSamples,
) -> Result<StepLoss<Tensor<1>>, NetsError> {
    let forked;
    let field = if fork {
        forked = field.fork_leaves();
        &forked
    } else {
        field
    };
    let rendered = render_rays(field, batch, range.clone(), samples)?;
    let loss = profile::timed("step: loss", || {
        rays_loss(field, perceptual, batch, range, &rendered)
    });
    Ok(profile::timed("step: backward", || {
        backward(field, batch, loss, rendered.leaves.as_ref())
    }))
}

/// What the field rendered of a range of rays.
struct RaysRender {
    rendered: RenderedRays,
    /// The terms on the body pass's weights, weighted: the distortion (with
    /// `--distortion`) and the hard surface (with `--hard-surface`).
    weight_terms: Vec<Tensor<1>>,
    /// The frame's conditions as autodiff leaves (pose refinement).
    leaves: Option<PoseLeaves>,
}

/// The field's forward on the rays' samples (through pose leaves when the pose is
/// refined) and its volume render.
fn render_rays(
    field: &TalkinField,
    batch: &StepBatch,
    range: std::ops::Range<usize>,
    samples: &PackedSamples,
) -> Result<RaysRender, NetsError> {
    let device = field.identity.val().device();
    let rays = &batch.rays[range];
    let points: Vec<[f32; 3]> = samples
        .midpoints_in_world(rays)
        .into_iter()
        .map(|p| p.to_array())
        .collect();
    let layout = packed_layout(samples);
    let input = FieldInput {
        points: &points,
        bone_masks: &samples.bone_mask,
        part_masks: &samples.part_mask,
        frame: batch.frame,
        step: batch.step,
    };
    let leaves = batch
        .pose_grads
        .then(|| PoseLeaves::new(batch.frame, &device));
    let out = profile::timed("step: field forward", || match &leaves {
        Some(l) => field.forward_with_leaves(&input, l),
        None => field.forward(&input),
    })?;
    let view = layout.view();
    let (rendered, weights) =
        profile::timed("step: volume render", || out.render_with_weights(&view))?;
    let mut weight_terms = Vec::new();
    if batch.distortion > 0.0 {
        weight_terms.push(
            distortion(&weights, &view)?
                .mean()
                .mul_scalar(batch.distortion),
        );
    }
    if batch.hard_surface > 0.0 {
        weight_terms.push(hard_surface(&weights).mul_scalar(batch.hard_surface));
    }
    Ok(RaysRender {
        rendered,
        weight_terms,
        leaves,
    })
}

/// A range of rays' loss, weighted by their share of the batch, and `[loss, mse]`
/// detached for the log.
struct RaysLoss {
    loss: Tensor<1>,
    values: Tensor<1>,
}

/// The pixel terms (MSE or 0.2 MSE, seg CE, the silhouette), the weights' terms and the
/// frame code's prior, weighted by the rays' share; the LPIPS patches on the first half.
fn rays_loss(
    field: &TalkinField,
    perceptual: Option<&PerceptualLoss>,
    batch: &StepBatch,
    range: std::ops::Range<usize>,
    render: &RaysRender,
) -> RaysLoss {
    let device = field.identity.val().device();
    let n_rays = range.len();
    let weight = n_rays as f32 / batch.rays.len() as f32;
    let rendered = &render.rendered;
    let target = Tensor::<2>::from_data(
        TensorData::new(
            batch.rgb[3 * range.start..3 * range.end].to_vec(),
            [n_rays, 3],
        ),
        &device,
    );
    let labels = Tensor::<1, Int>::from_data(
        TensorData::new(batch.labels[range.clone()].to_vec(), [n_rays]),
        &device,
    );
    // Patches sit at the start of the first chunk (see `chunk_bounds`); with them, the
    // MSE is the minor term in every chunk.
    let with_patches = perceptual.is_some() && batch.patches > 0;
    let mse_weight = if with_patches { MSE_WEIGHT } else { 1.0 };
    let sure = (batch.mask_weight > 0.0).then(|| {
        Tensor::<1>::from_data(
            TensorData::new(batch.silhouette[range.clone()].to_vec(), [n_rays]),
            &device,
        )
    });
    let weights = PixelWeights {
        mse: mse_weight,
        seg: SEG_WEIGHT,
    };
    // On a GPU the pixel terms are one device op; elsewhere tensor ops, the same terms.
    let PixelLoss {
        loss: pixel,
        mse: l_mse,
        rgb,
    } = pixel_loss(PixelInputs {
        rendered,
        background: batch.background,
        target: &target,
        labels: &labels,
        silhouette: sure.as_ref().map(|sure| (sure, batch.mask_weight)),
        weights,
    });
    let code_prior = field
        .frame_code_norm2(batch.frame)
        .map(|n2| n2.mul_scalar(FRAME_CODE_PRIOR));
    let pixel = render
        .weight_terms
        .iter()
        .cloned()
        .chain(code_prior)
        .fold(pixel, |sum, term| sum + term)
        .mul_scalar(weight);
    let loss = match perceptual {
        Some(p) if with_patches && range.start == 0 => {
            let (k, side) = (batch.patches, batch.patch_side);
            let to_images = |t: Tensor<2>| {
                t.narrow(0, 0, k * side * side)
                    .reshape([k, side, side, 3])
                    .permute([0, 3, 1, 2])
            };
            let rgb = rgb.unwrap_or_else(|| rendered.rgb_over(batch.background));
            pixel + p.forward(to_images(rgb), to_images(target)).mean()
        }
        _ => pixel,
    };
    // The loss and its weighted MSE, together (read by `loss_and_grads` on the CPU once
    // both halves' backwards are recorded; left queued on a GPU).
    let values = Tensor::cat(
        vec![loss.clone().detach(), l_mse.detach().mul_scalar(weight)],
        0,
    );
    RaysLoss { loss, values }
}

/// The loss's gradients w.r.t. the field's parameters and, through `leaves`, the frame's
/// pose.
fn backward(
    field: &TalkinField,
    batch: &StepBatch,
    loss: RaysLoss,
    leaves: Option<&PoseLeaves>,
) -> StepLoss<Tensor<1>> {
    // A half whose rays all missed every capsule (e.g. an LPIPS patch beside the person)
    // has no samples: its loss is a constant, with no gradient to take.
    let (grads, pose) = if loss.loss.is_tracked() {
        let g = loss.loss.backward();
        let pose = leaves.map(|l| l.grads(&g));
        (GradientsParams::from_grads(g, field), pose)
    } else {
        let pose = batch.pose_grads.then(|| zero_grads(field.pose_dim()));
        (GradientsParams::new(), pose)
    };
    StepLoss {
        values: loss.values,
        grads,
        pose,
    }
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, ModuleVisitor, Param};
    use glam::Vec3;
    use talkin_grids::{DenseOpts, sample_dense};
    use talkin_nets::FieldConfig;
    use talkin_nets::encoding::{EncodingConfig, HashGridConfig};
    use talkin_nets::init::WeightRng;
    use talkin_nets::skinning::SkinningConfig;

    use super::*;
    use talkin_avatar::field_inputs::frame_conditions;
    use talkin_avatar::scene::{CapsuleShells, FrameScene, capsule_bounds};
    use talkin_avatar::subject::bone_prior;
    use talkin_human::body::canonical_params;
    use talkin_synth::body::default_rest_joints;

    /// Compares every parameter's gradient in two gradient sets.
    struct SameGrads<'a> {
        a: &'a GradientsParams,
        b: &'a GradientsParams,
        compared: usize,
    }

    impl ModuleVisitor for SameGrads<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let (Some(a), Some(b)) = (self.a.get::<D>(param.id), self.b.get::<D>(param.id)) else {
                assert!(
                    self.a.get::<D>(param.id).is_none() && self.b.get::<D>(param.id).is_none(),
                    "a gradient exists in only one set"
                );
                return;
            };
            let (a, b) = (
                a.try_to_vec_as::<f32>().unwrap(),
                b.try_to_vec_as::<f32>().unwrap(),
            );
            let scale = a.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-4 * scale, "{x} vs {y} (scale {scale})");
            }
            self.compared += 1;
        }
    }

    /// The summed chunks' loss and gradients are the whole batch's.
    #[test]
    fn the_chunks_give_the_whole_batch_gradient() {
        let device = Device::flex().autodiff();
        let mut config = FieldConfig::fast(1);
        config.encoding = EncodingConfig::HashGrid(
            HashGridConfig::new()
                .with_n_levels(4)
                .with_log2_hashmap_size(12),
        );
        config.skinning = SkinningConfig::new()
            .with_resolution(8)
            .with_posed_tau(Some(0.005))
            .with_finger_bones(Some(true));
        // A synthetic subject in its canonical pose, as training builds it.
        let skeleton = default_rest_joints(0);
        let prior = bone_prior([&skeleton]);
        let params = canonical_params();
        let canonical = skeleton.pose(&params);
        let scene = FrameScene::new(&skeleton, &canonical, &params);
        // Cores at half the bare radius, so the posed prior has geometry to read.
        let n = scene.capsules.len();
        let shells = CapsuleShells {
            margin: vec![0.0; n],
            core: scene.capsules.iter().map(|c| 0.5 * c.radius).collect(),
            core_shrink: vec![0.0; n],
            from_depth: true,
        };
        let frame = frame_conditions(0, &params, &scene, &shells, true);
        let (lo, hi) = capsule_bounds(&scene.capsules, 0.02);
        let field = config
            .init(&prior, &device, &mut WeightRng::seeded(5))
            .unwrap();
        // Rays across the body's box, along -z; rays 0-3 miss the box (no samples) with
        // `first_half_empty`, so the first half has no gradient: its loss is a constant.
        let make_rays = |first_half_empty: bool| -> Vec<Ray> {
            (0..9)
                .map(|i| {
                    let u = (i as f32 + 0.5) / 9.0;
                    let x = if first_half_empty && i < 4 {
                        hi.x + 3.0
                    } else {
                        lo.x + u * (hi.x - lo.x)
                    };
                    let origin = Vec3::new(x, lo.y + u * (hi.y - lo.y), hi.z + 2.0);
                    Ray::new(origin, Vec3::NEG_Z, 0.0, f32::INFINITY).unwrap()
                })
                .collect()
        };
        for first_half_empty in [false, true] {
            let rays = make_rays(first_half_empty);
            let dense = DenseOpts {
                samples_per_ray: 12,
                jitter: false,
                seed: 0,
            };
            let samples = sample_dense(&rays, lo, hi, &dense).unwrap();
            assert_eq!(chunk_bounds(9, 0, 4), vec![0, 4, 9]);
            assert_eq!(samples.ray_offsets[4] == 0, first_half_empty);
            let rgb: Vec<f32> = (0..27).map(|i| (i * 7 % 10) as f32 / 10.0).collect();
            let labels: Vec<i32> = (0..9).map(|i| i % 5).collect();
            // One ray on the mask's cut: its silhouette term is left out.
            let silhouette: Vec<f32> = (0..9).map(|i| if i == 6 { 0.0 } else { 1.0 }).collect();
            let batch = || StepBatch {
                rays: &rays,
                share: 0..9,
                samples: samples.clone(),
                rgb: &rgb,
                labels: &labels,
                silhouette: &silhouette,
                patches: 0,
                patch_side: 32,
                frame: &frame,
                step: 0,
                background: [1.0; 3],
                mask_weight: 0.1,
                distortion: 0.0,
                hard_surface: 0.0,
                pose_grads: false,
            };
            let whole_batch = batch();
            let whole = chunk_loss(&field, false, None, &whole_batch, 0..9, &samples).unwrap();
            // On the mask's cut the silhouette term has no target: a batch all on it
            // scores as without the term, and off it the term counts.
            let cut = vec![0.0f32; 9];
            let loss_with = |silhouette: &[f32], mask_weight: f32| {
                let b = StepBatch {
                    silhouette,
                    mask_weight,
                    ..batch()
                };
                LossValues::of(
                    chunk_loss(&field, false, None, &b, 0..9, &samples)
                        .unwrap()
                        .values,
                )
                .read()
                .0
            };
            assert_eq!(loss_with(&cut, 1.0), loss_with(&cut, 0.0));
            assert!(loss_with(&silhouette, 1.0) > loss_with(&silhouette, 0.0));
            // In two chunks (the first with no samples) and in three.
            for chunk_rays in [4, 3] {
                let split = loss_and_grads_in_chunks(&field, None, batch(), chunk_rays).unwrap();
                let ((whole_loss, whole_mse), (split_loss, split_mse)) = (
                    LossValues::of(whole.values.clone()).read(),
                    split.values.read(),
                );
                assert!(
                    (whole_loss - split_loss).abs() <= 1e-5 * whole_loss.abs(),
                    "{whole_loss} vs {split_loss}"
                );
                assert!((whole_mse - split_mse).abs() <= 1e-5 * whole_mse.abs());
                let mut same = SameGrads {
                    a: &whole.grads,
                    b: &split.grads,
                    compared: 0,
                };
                field.visit(&mut same);
                assert!(
                    same.compared >= 5,
                    "only {} parameters had gradients",
                    same.compared
                );
            }
            let whole_loss = LossValues::of(whole.values.clone()).read().0;
            // Peers: each share's loss and gradients, summed, are the whole batch's
            // (three peers of nine rays: shares of three, each cut again in chunks).
            for size in [2, 3] {
                let mut loss = 0.0;
                let mut grads = GradientsParams::new();
                for rank in 0..size {
                    let part = loss_and_grads_in_chunks(
                        &field,
                        None,
                        StepBatch {
                            share: crate::peers::share_of(rank, size, 9, 0),
                            ..batch()
                        },
                        2,
                    )
                    .unwrap();
                    loss += part.values.read().0;
                    grads = sum_grads(&field, grads, part.grads);
                }
                assert!(
                    (whole_loss - loss).abs() <= 1e-5 * whole_loss.abs(),
                    "{size} peers: {whole_loss} vs {loss}"
                );
                let mut same = SameGrads {
                    a: &whole.grads,
                    b: &grads,
                    compared: 0,
                };
                field.visit(&mut same);
                assert!(same.compared >= 5, "{size} peers");
            }
        }
    }

    #[test]
    fn the_chunks_keep_patches_in_the_first() {
        assert_eq!(chunk_bounds(512, 0, 256), vec![0, 256, 512]);
        assert_eq!(chunk_bounds(513, 0, 256), vec![0, 256, 513]);
        assert_eq!(chunk_bounds(1024, 0, 256), vec![0, 256, 512, 768, 1024]);
        assert_eq!(
            chunk_bounds(1024 + 512, 1024, 256),
            vec![0, 1024, 1280, 1536]
        );
        assert_eq!(chunk_bounds(1024, 1024, 256), vec![0, 1024]);
        assert_eq!(chunk_bounds(100, 0, 256), vec![0, 100]);
        assert_eq!(chunk_bounds(1, 0, 256), vec![0, 1]);
        assert_eq!(chunk_bounds(0, 0, 256), vec![0]);
    }
}
