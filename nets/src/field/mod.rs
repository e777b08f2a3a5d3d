//! The TalkinNeRF field: D_r (inverse LBS) + D_nr, F_body with segmentation, and hard
//! routing of head samples to F_face and hand samples to D_hands + F_hands.
//!
//! Activations: `rgb = sigmoid`, `sigma = softplus` (the overflow-free form
//! `max(x,0) + ln(1+exp(-|x|))`: smooth, never negative, linear for large inputs, with a
//! gradient that never vanishes the way a ReLU's does on an all-negative init).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use burn::tensor::activation::sigmoid;

use crate::encoding::{Encoding, FrequencyEncoding};
use crate::error::{NetsError, check_len};
use crate::mlp::Mlp;
use crate::render::{OwnedRaySamples, RaySamples, RenderedRays, render_in_front, render_packed};
use crate::skinning::{BlendWeightVolume, BoneCapsule, N_BODY_JOINTS, RigidWarp};
use crate::util::{floats, ints, softplus};

mod config;
mod fork;
pub mod leaves;
mod routing;

pub use config::{FieldConfig, PART_LOG2_ENTRIES, POSED_TAU_M, UnitMap};
pub use leaves::{PoseGrads, PoseLeaves};
use routing::Router;
pub use routing::Routing;

/// Segmentation classes of the body net (DensePose-derived labels of the paper).
pub const N_SEG_CLASSES: usize = 5;
/// Label: background.
pub const SEG_BACKGROUND: usize = 0;
/// Label: rest of the body.
pub const SEG_BODY: usize = 1;
/// Label: arms.
pub const SEG_ARMS: usize = 2;
/// Label: hands.
pub const SEG_HANDS: usize = 3;
/// Label: head.
pub const SEG_HEAD: usize = 4;
/// Candidate-part bit of hands in a sample's part mask (`grids::Part::Hands.bit()`).
pub const PART_BIT_HANDS: u8 = 1 << 2;
/// Candidate-part bit of the head (`grids::Part::Head.bit()`).
pub const PART_BIT_HEAD: u8 = 1 << 3;
/// Expression coefficients psi.
pub const EXPRESSION_DIM: usize = 10;
/// Jaw axis-angle.
pub const JAW_DIM: usize = 3;
/// Both hands' 15 joints x 3.
pub const HAND_POSE_DIM: usize = 90;

/// Encoding + MLP predicting raw `[sigma, rgb (3), extra...]`.
#[derive(Module, Debug)]
pub struct RadianceNet {
    pub(crate) encoding: Encoding,
    pub(crate) mlp: Mlp,
}

impl RadianceNet {
    /// Points of identity `identity` (all of one subject), conditioned on `condition`,
    /// one row shared by every point (the frame's codes; see [`Mlp::forward_with_row`]).
    ///
    /// # Shapes
    /// - `unit_points`: `[n, 3]`, `condition`: `[1, d_c]`; output `[n, d_out]`
    pub fn forward(
        &self,
        unit_points: Tensor<2>,
        identity: usize,
        condition: Tensor<2>,
        step: usize,
    ) -> Tensor<2> {
        let enc = self.encoding.forward(unit_points, identity, step);
        self.mlp.forward_with_row(enc, Some(condition))
    }
}

/// Windowed PE + MLP predicting an offset (metres).
#[derive(Module, Debug)]
pub struct DeformNet {
    pub(crate) encoding: FrequencyEncoding,
    pub(crate) mlp: Mlp,
}

impl DeformNet {
    /// # Shapes
    /// - `unit_points`: `[n, 3]`, `condition`: `[1, d]` (shared by every point); output
    ///   `[n, 3]`
    pub fn forward(&self, unit_points: Tensor<2>, condition: Tensor<2>, step: usize) -> Tensor<2> {
        let enc = self
            .encoding
            .forward(unit_points.mul_scalar(2.0).sub_scalar(1.0), step);
        self.mlp.forward_with_row(enc, Some(condition))
    }
}

#[derive(Clone, Debug)]
struct FieldSettings {
    aabb_min: [f32; 3],
    aabb_max: [f32; 3],
    non_rigid_start_step: Option<usize>,
    hand_background: bool,
    face_uses_jaw: bool,
    unit_map: UnitMap,
    pose_dim: usize,
    n_identities: usize,
}

impl FieldSettings {
    /// The unit cube's corner (metres) and per-axis scale: `unit = (x - min) * inv`.
    fn unit_map(&self) -> ([f32; 3], [f32; 3]) {
        let (lo, hi) = (self.aabb_min, self.aabb_max);
        let extent: [f32; 3] = std::array::from_fn(|a| hi[a] - lo[a]);
        if self.unit_map == UnitMap::PerAxis {
            return (lo, extent.map(|e| 1.0 / e));
        }
        let side = extent.into_iter().fold(0.0f32, f32::max);
        let min = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]) - 0.5 * side);
        (min, [1.0 / side; 3])
    }
}

/// Per-frame conditions (one frame per forward call).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameConditions {
    /// Subject index (< `n_identities`).
    pub identity: usize,
    /// `[22]` row-major 4x4 `canonical_from_posed` per body bone (see [`crate::skinning`]).
    pub canonical_from_posed: Vec<[f32; 16]>,
    /// `[pose_dim]` body pose for D_nr (21 x 3 axis-angle).
    pub body_pose: Vec<f32>,
    /// psi.
    pub expression: [f32; EXPRESSION_DIM],
    /// Jaw axis-angle.
    pub jaw: [f32; JAW_DIM],
    /// `[90]` both hands' poses.
    pub hand_pose: Vec<f32>,
    /// The posed solid cores of the body bones, for the skinning's posed-space prior
    /// (see [`crate::skinning`]); unused without it.
    pub bone_capsules: Vec<BoneCapsule>,
}

/// One packed batch of samples of one frame.
#[derive(Clone, Copy, Debug)]
pub struct FieldInput<'a> {
    /// `[n]` observation-space sample positions.
    pub points: &'a [[f32; 3]],
    /// `[n]` candidate SMPL-X joints (bit j = joint j < 55), from the capsule BVH.
    pub bone_masks: &'a [u64],
    /// `[n]` candidate parts ([`PART_BIT_HEAD`], [`PART_BIT_HANDS`], ...).
    pub part_masks: &'a [u8],
    /// The frame's conditions.
    pub frame: &'a FrameConditions,
    /// Training step (D_nr switch, Hann windows); use a large value at inference.
    pub step: usize,
}

/// Hand-routed samples kept apart for the second compositing pass.
#[derive(Clone, Debug)]
pub struct HandSamples {
    /// Ascending sample indices into the batch. `[h]`
    pub indices: Vec<usize>,
    /// `[h, 3]`
    pub rgb: Tensor<2>,
    /// `[h]`
    pub sigma: Tensor<1>,
}

/// Rows evaluated by each net in one forward: what routing saved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RoutingStats {
    /// Samples in the batch (= rows through F_body).
    pub samples: usize,
    /// (sample, bone) pairs evaluated by inverse LBS.
    pub skinning_pairs: usize,
    /// Rows through D_nr (0 before its start step).
    pub non_rigid_rows: usize,
    /// Rows through F_face.
    pub face_rows: usize,
    /// Rows through F_hands (and D_hands when used).
    pub hand_rows: usize,
}

/// Per-sample outputs of [`TalkinField::forward`].
#[derive(Clone, Debug)]
pub struct FieldOutput {
    /// Body colour, face-replaced where routed (and hand-replaced without the two-pass
    /// background). `[n, 3]`
    pub rgb: Tensor<2>,
    /// Density, same replacement rules. `[n]`
    pub sigma: Tensor<1>,
    /// F_body's segmentation logits. `[n, 5]`
    pub seg_logits: Tensor<2>,
    /// Canonical positions after D_r and D_nr. `[n, 3]`
    pub x_canonical: Tensor<2>,
    /// Hand samples for the second pass (`hand_background` and at least one routed).
    pub hands: Option<HandSamples>,
    /// Rows per net.
    pub stats: RoutingStats,
}

impl FieldOutput {
    /// Volume-renders the batch: pass 1 composites every sample's body/face output;
    /// with hand samples, pass 2 composites them in ray order in front of pass 1's colour.
    pub fn render(&self, samples: &RaySamples) -> Result<RenderedRays, NetsError> {
        let body = render_packed(
            self.sigma.clone(),
            self.rgb.clone(),
            self.seg_logits.clone(),
            samples,
        )?;
        match &self.hands {
            None => Ok(body),
            Some(h) => {
                let front = OwnedRaySamples::subset(samples, &h.indices);
                render_in_front(h.sigma.clone(), h.rgb.clone(), &front.view(), &body)
            }
        }
    }
}

/// The whole TalkinNeRF field.
#[derive(Module, Debug)]
pub struct TalkinField {
    /// Identity codes. `[n_identities, identity_dim]`
    pub identity: Param<Tensor<2>>,
    /// D_r's weight volume.
    pub skinning: BlendWeightVolume,
    /// D_nr (absent when the config never starts it).
    pub non_rigid: Option<DeformNet>,
    /// F_body.
    pub body: RadianceNet,
    /// F_face.
    pub face: Option<RadianceNet>,
    /// D_hands.
    pub hand_deform: Option<DeformNet>,
    /// F_hands.
    pub hands: Option<RadianceNet>,
    #[module(skip)]
    settings: FieldSettings,
}

/// Splits raw `[sigma, rgb]` into activated `(sigma [n], rgb [n, 3])`.
fn activate(raw: &Tensor<2>) -> (Tensor<1>, Tensor<2>) {
    let sigma = softplus(raw.clone().narrow(1, 0, 1)).squeeze_dim::<1>(1);
    let rgb = sigmoid(raw.clone().narrow(1, 1, 3));
    (sigma, rgb)
}

/// `base` with rows `idx` replaced by `values` (unique indices; gradients exact).
fn replace_rows<const D: usize>(base: Tensor<D>, idx: &[usize], values: Tensor<D>) -> Tensor<D> {
    let device = base.device();
    let n = base.dims()[0];
    let mut keep = vec![1.0f32; n];
    for &i in idx {
        keep[i] = 0.0;
    }
    let mut keep_shape = [1usize; D];
    keep_shape[0] = n;
    let keep = floats(keep, keep_shape, &device);
    let idx = ints(idx.iter().map(|&i| i as i32).collect(), &device);
    let scattered = Tensor::<D>::zeros(base.shape(), &device).select_assign(
        0,
        idx,
        values,
        IndexingUpdateOp::Add,
    );
    base * keep + scattered
}

impl TalkinField {
    fn device(&self) -> Device {
        self.identity.val().device()
    }

    /// Maps canonical metres to the nets' unit cube: the canonical box's bounding cube
    /// (same centre, its longest side), or for [`UnitMap::PerAxis`] the box itself
    /// stretched per axis. `[n, 3]`
    pub fn to_unit(&self, x: Tensor<2>) -> Tensor<2> {
        let device = x.device();
        let (min, inv) = self.settings.unit_map();
        (x - floats(min.to_vec(), [1, 3], &device)) * floats(inv.to_vec(), [1, 3], &device)
    }

    /// Identity codes this field holds.
    pub fn n_identities(&self) -> usize {
        self.settings.n_identities
    }

    /// Appends a new identity code (for adapting to a novel subject), initialised to the
    /// mean of the existing codes; returns the field and the new code's index.
    pub fn add_identity(mut self) -> (TalkinField, usize) {
        let codes = self.identity.val();
        let mean = codes.clone().mean_dim(0); // [1, d]
        let grown = Tensor::cat(vec![codes, mean], 0).detach();
        self.identity = Param::from_tensor(grown);
        let index = self.settings.n_identities;
        self.settings.n_identities += 1;
        (self, index)
    }

    /// D_r alone (e.g. for the engine's occupancy test before the full forward).
    pub fn rigid_warp(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        frame: &FrameConditions,
    ) -> Result<RigidWarp, NetsError> {
        self.skinning.inverse_lbs(
            points,
            bone_masks,
            &frame.canonical_from_posed,
            &frame.bone_capsules,
            &self.device(),
        )
    }

    /// The field's pose dimension (D_nr's body-pose condition).
    pub fn pose_dim(&self) -> usize {
        self.settings.pose_dim
    }

    fn check(&self, input: &FieldInput) -> Result<(), NetsError> {
        let n = input.points.len();
        check_len("bone_masks", input.bone_masks.len(), n)?;
        check_len("part_masks", input.part_masks.len(), n)?;
        let f = input.frame;
        check_len(
            "canonical_from_posed",
            f.canonical_from_posed.len(),
            N_BODY_JOINTS,
        )?;
        check_len("body_pose", f.body_pose.len(), self.settings.pose_dim)?;
        check_len("hand_pose", f.hand_pose.len(), HAND_POSE_DIM)?;
        if f.identity >= self.settings.n_identities {
            return Err(NetsError::Index {
                what: "identity",
                index: f.identity,
                limit: self.settings.n_identities,
            });
        }
        if input.points.iter().flatten().any(|v| !v.is_finite()) {
            return Err(NetsError::NonFinite { what: "points" });
        }
        Ok(())
    }

    /// Evaluates the field on a packed batch of one frame.
    ///
    /// # Shapes
    /// `n = input.points.len()`; outputs as documented on [`FieldOutput`].
    pub fn forward(&self, input: &FieldInput) -> Result<FieldOutput, NetsError> {
        self.forward_routed(input, Routing::for_device(&self.device()))
    }

    /// [`TalkinField::forward`] with the routing labels read where `routing` says (the
    /// two give the same outputs and gradients; tests compare them on one device).
    pub fn forward_routed(
        &self,
        input: &FieldInput,
        routing: Routing,
    ) -> Result<FieldOutput, NetsError> {
        self.forward_inner(input, routing, None)
    }

    /// [`TalkinField::forward`] reading the frame's skinning transforms, body pose,
    /// expression, jaw and hand pose from `leaves` (see [`leaves`]): the backward then
    /// gives their gradients, for pose refinement. `input.frame` still supplies the
    /// identity and the posed-space prior's capsules, and must hold the same values.
    pub fn forward_with_leaves(
        &self,
        input: &FieldInput,
        leaves: &PoseLeaves,
    ) -> Result<FieldOutput, NetsError> {
        self.forward_inner(input, Routing::for_device(&self.device()), Some(leaves))
    }

    fn forward_inner(
        &self,
        input: &FieldInput,
        routing: Routing,
        leaves: Option<&PoseLeaves>,
    ) -> Result<FieldOutput, NetsError> {
        self.check(input)?;
        let device = self.device();
        let n = input.points.len();
        let step = input.step;
        let frame = input.frame;
        let mut stats = RoutingStats {
            samples: n,
            ..Default::default()
        };

        let warp = self.skinning.inverse_lbs_with(
            input.points,
            input.bone_masks,
            &frame.canonical_from_posed,
            &frame.bone_capsules,
            &device,
            leaves.map(|l| &l.canonical_from_posed),
        )?;
        stats.skinning_pairs = warp.n_pairs;
        if n == 0 {
            return Ok(FieldOutput {
                rgb: Tensor::zeros([0, 3], &device),
                sigma: Tensor::zeros([0], &device),
                seg_logits: Tensor::zeros([0, N_SEG_CLASSES], &device),
                x_canonical: warp.x_canonical,
                hands: None,
                stats,
            });
        }
        let mut x = warp.x_canonical; // [n, 3]
        let started = self
            .settings
            .non_rigid_start_step
            .is_some_and(|s| step >= s);
        if let (Some(nr), true) = (&self.non_rigid, started) {
            let pose = match leaves {
                Some(l) => l.body_pose.clone(),
                None => floats(
                    frame.body_pose.clone(),
                    [1, self.settings.pose_dim],
                    &device,
                ),
            };
            x = x.clone() + nr.forward(self.to_unit(x), pose, step); // [n, 3]
            stats.non_rigid_rows = n;
        }
        let identity = self
            .identity
            .val()
            .select(0, ints(vec![frame.identity as i32], &device)); // [1, id]
        let raw = self.body.forward(
            self.to_unit(x.clone()),
            frame.identity,
            identity.clone(),
            step,
        ); // [n, 9]
        let (mut sigma, mut rgb) = activate(&raw);
        let seg_logits = raw.narrow(1, 4, N_SEG_CLASSES); // [n, 5]

        // Hard routing: candidates (BVH) whose body label is the part.
        let route = Router::new(input.part_masks, &seg_logits, routing);
        if let Some(face) = &self.face {
            let head = route.rows(PART_BIT_HEAD, SEG_HEAD);
            if !head.rows.is_empty() {
                let h = head.rows.len();
                let xh = x.clone().select(0, head.indices(&device)); // [h, 3]
                let e = match leaves {
                    Some(l) if self.settings.face_uses_jaw => {
                        Tensor::cat(vec![l.expression.clone(), l.jaw.clone()], 1)
                    }
                    Some(l) => l.expression.clone(),
                    None => {
                        let mut e = frame.expression.to_vec();
                        if self.settings.face_uses_jaw {
                            e.extend(frame.jaw);
                        }
                        let d_e = e.len();
                        floats(e, [1, d_e], &device)
                    }
                };
                let raw = face.forward(
                    self.to_unit(xh),
                    frame.identity,
                    Tensor::cat(vec![e, identity.clone()], 1),
                    step,
                );
                let (s_face, c_face) = activate(&raw);
                sigma = head.replace(sigma, s_face);
                rgb = head.replace(rgb, c_face);
                stats.face_rows = h;
            }
        }
        let mut hands_out = None;
        if let Some(hands) = &self.hands {
            let idx = route.rows(PART_BIT_HANDS, SEG_HANDS);
            if !idx.rows.is_empty() {
                let h = idx.rows.len();
                let mut xh = x.clone().select(0, idx.indices(&device));
                if let Some(dh) = &self.hand_deform {
                    let pose = match leaves {
                        Some(l) => l.hand_pose.clone(),
                        None => floats(frame.hand_pose.clone(), [1, HAND_POSE_DIM], &device),
                    };
                    xh = xh.clone() + dh.forward(self.to_unit(xh), pose, step);
                }
                let raw = hands.forward(self.to_unit(xh), frame.identity, identity, step);
                let (s_hand, c_hand) = activate(&raw);
                stats.hand_rows = h;
                if self.settings.hand_background {
                    // A candidate whose label is not the hands gets no density: it
                    // composites to nothing in the second pass.
                    let s_hand = idx.keep_or(s_hand, 0.0);
                    hands_out = Some(HandSamples {
                        indices: idx.rows,
                        rgb: c_hand,
                        sigma: s_hand,
                    });
                } else {
                    sigma = idx.replace(sigma, s_hand);
                    rgb = idx.replace(rgb, c_hand);
                }
            }
        }
        Ok(FieldOutput {
            rgb,
            sigma,
            seg_logits,
            x_canonical: x,
            hands: hands_out,
            stats,
        })
    }
}

/// Row-wise argmax of a row-major `[n, c]` host matrix (first maximum wins): how
/// segmentation logits become the labels that route samples.
pub fn argmax_rows(values: &[f32], c: usize) -> Vec<usize> {
    values
        .chunks_exact(c)
        .map(|row| {
            let mut best = 0;
            for j in 1..c {
                if row[j] > row[best] {
                    best = j;
                }
            }
            best
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding::{EncodingConfig, HashGridConfig};
    use crate::skinning::{BoneSegment, N_BODY_JOINTS, SkinningConfig};
    use crate::util::host;
    use burn::optim::{AdamConfig, GradientsParams};

    pub(crate) fn prior() -> Vec<BoneSegment> {
        (0..N_BODY_JOINTS)
            .map(|b| {
                let y = -1.0 + b as f32 * 0.09;
                BoneSegment {
                    bone: b,
                    a: [-0.3, y, 0.0],
                    b: [0.3, y + 0.05, 0.0],
                }
            })
            .collect()
    }

    pub(crate) fn frame() -> FrameConditions {
        let mut t = [0.0f32; 16];
        for i in 0..4 {
            t[i * 5] = 1.0;
        }
        FrameConditions {
            identity: 0,
            canonical_from_posed: vec![t; N_BODY_JOINTS],
            body_pose: vec![0.05; 63],
            expression: [0.1; EXPRESSION_DIM],
            jaw: [0.2, 0.0, 0.0],
            hand_pose: vec![0.0; HAND_POSE_DIM],
            bone_capsules: vec![],
        }
    }

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
            let field = config.init(&prior(), &device).unwrap();
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
        let field = config.init(&prior(), &device).unwrap();
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
        let old_field = old.init(&prior(), &device).unwrap();
        assert_eq!(rows(&old_field.face.as_ref().unwrap().encoding), body);
        assert_eq!(rows(&old_field.hands.as_ref().unwrap().encoding), body);
    }

    #[test]
    fn non_candidates_never_reach_face_or_hands() {
        let device = Device::flex();
        let (pts, _) = batch(6, 8);
        let n = pts.len();
        let bones = vec![1u64 << 15; n];
        let frame = frame();
        let mut field = tiny_fast().init(&prior(), &device).unwrap();
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
        let f = frame();
        let input = FieldInput {
            points: &pts,
            bone_masks: &bones,
            part_masks: &parts,
            frame: &f,
            step: 0,
        };
        for background in [true, false] {
            device.seed(5);
            let mut field = tiny_fast()
                .with_hand_background(background)
                .init(&prior(), &device)
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
        let (bones, frame) = (vec![0u64; n], frame());
        let mut field = tiny_fast()
            .with_hand_background(false)
            .init(&prior(), &device)
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
        let full = tiny_fast().init(&prior(), &device).unwrap();
        let cfg = tiny_fast()
            .with_has_face(false)
            .with_has_hands(false)
            .with_non_rigid_start_step(None);
        let mut bare = cfg.init(&prior(), &device).unwrap();
        assert!(
            bare.face.is_none()
                && bare.hands.is_none()
                && bare.hand_deform.is_none()
                && bare.non_rigid.is_none()
        );
        assert!(bare.num_params() < full.num_params());
        let no_dh = tiny_fast()
            .with_use_d_hands(false)
            .init(&prior(), &device)
            .unwrap();
        assert!(no_dh.hand_deform.is_none() && no_dh.hands.is_some());
        let jawless = tiny_fast()
            .with_face_uses_jaw(false)
            .init(&prior(), &device)
            .unwrap();
        assert!(jawless.num_params() < full.num_params());

        force_body(&mut bare, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
        let (pts, _) = batch(2, 4);
        let n = pts.len();
        let (bones, parts, frame) = (vec![0u64; n], vec![0xffu8; n], frame());
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
        let field = tiny_fast().init(&prior(), &device).unwrap();
        let frame = frame();
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
        let field = tiny_fast().init(&prior(), &device).unwrap();
        let (pts, _) = batch(2, 4);
        let n = pts.len();
        let (bones, parts, frame) = (vec![1u64 << 3; n], vec![0u8; n], frame());
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

    #[test]
    fn rejects_bad_conditions() {
        let device = Device::flex();
        let field = tiny_fast().init(&prior(), &device).unwrap();
        let (pts, _) = batch(1, 2);
        let mut f = frame();
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
            ..frame()
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
        let f = frame();
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
        device.seed(5);
        let (pts, samples) = batch(24, 8);
        let r = samples.offsets.len() - 1;
        let target: Vec<f32> = (0..r * 3)
            .map(|i| 0.2 + 0.6 * ((i * 7 % 5) as f32 / 4.0))
            .collect();
        let target = floats(target, [r, 3], &device);

        let mut paper = FieldConfig::paper(1);
        paper.skinning = SkinningConfig::new().with_resolution(8);
        let mut optim = AdamConfig::new().init();
        let field = paper.init(&prior(), &device).unwrap();
        let (field, first) = train_step(field, &mut optim, &pts, &samples, &target, 200_000);
        let (_, second) = train_step(field, &mut optim, &pts, &samples, &target, 200_000);
        assert!(first.is_finite() && second.is_finite());

        let mut optim = AdamConfig::new().init();
        let mut field = tiny_fast().init(&prior(), &device).unwrap();
        let mut losses = Vec::new();
        for step in 0..25 {
            let (f, loss) = train_step(field, &mut optim, &pts, &samples, &target, step);
            field = f;
            losses.push(loss);
        }
        assert!(losses.iter().all(|l| l.is_finite()));
        assert!(losses[24] < 0.5 * losses[0], "{losses:?}");
    }
}
