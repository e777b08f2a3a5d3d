//! The TalkinNeRF field: D_r (inverse LBS) + D_nr, F_body with segmentation, and hard
//! routing of head samples to F_face and hand samples to D_hands + F_hands.
//!
//! Activations: `rgb = sigmoid`, `sigma = softplus` (the overflow-free form
//! `max(x,0) + ln(1+exp(-|x|))`: smooth, never negative, linear for large inputs, with a
//! gradient that never vanishes the way a ReLU's does on an all-negative init).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use crate::encoding::{Encoding, FrequencyEncoding};
use crate::error::{NetsError, check_len};
use crate::mlp::Mlp;
use crate::profile;
use crate::rows::{add_rows, gather_rows};
use crate::skinning::{BlendWeightVolume, N_SMPLX_JOINTS};
use crate::util::{floats, ints, softplus};
use crate::volume::{
    OwnedRaySamples, RaySamples, RenderWeights, RenderedRays, depth_columns, render_in_front,
    render_weighted,
};

mod config;
mod fork;
mod frame;
pub mod leaves;
mod routing;

pub use config::{Density, FieldConfig, FrameCodes, PART_LOG2_ENTRIES, POSED_TAU_M, UnitMap};
pub use frame::FrameConditions;
pub use leaves::{PoseGrads, PoseLeaves};
pub use routing::Routing;
use routing::{Routed, Router};

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
    face_uses_expression: bool,
    unit_map: UnitMap,
    pose_dim: usize,
    n_identities: usize,
    frame_code_deform: bool,
    density: Density,
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

/// One packed batch of samples of one frame.
#[derive(Clone, Copy, Debug)]
pub struct FieldInput<'a> {
    /// `[n]` observation-space sample positions.
    pub points: &'a [[f32; 3]],
    /// `[n]` candidate SMPL-X joints (bit j = joint j < 55), from the sampler's capsules.
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
        Ok(self.render_with_weights(samples)?.0)
    }

    /// [`FieldOutput::render`], and the body pass's compositing weights, from which the
    /// loss's terms on the weights' spread are taken ([`crate::volume::distortion`],
    /// [`crate::volume::hard_surface`]) without compositing twice.
    pub fn render_with_weights(
        &self,
        samples: &RaySamples,
    ) -> Result<(RenderedRays, RenderWeights), NetsError> {
        let weights = RenderWeights::new(self.sigma.clone(), samples)?;
        let body = render_weighted(&weights, self.rgb.clone(), self.seg_logits.clone(), samples)?;
        let rendered = match &self.hands {
            None => body,
            Some(h) => {
                let front = OwnedRaySamples::subset(samples, &h.indices);
                render_in_front(h.sigma.clone(), h.rgb.clone(), &front.view(), &body)?
            }
        };
        Ok((rendered, weights))
    }

    /// Per ray, the moments of depth under the weights it is rendered with (both
    /// passes): `[sum w, sum w d, sum w d^2]`, `d` measured from the ray's first sample
    /// ([`depth_columns`]); [`crate::volume::depth_spread`] makes them a thickness. `[r, 3]`
    pub fn depth_moments(&self, samples: &RaySamples) -> Result<Tensor<2>, NetsError> {
        let device = self.sigma.device();
        let columns = depth_columns(samples, &device);
        let body = RenderWeights::new(self.sigma.clone(), samples)?.integrate(columns.clone());
        let Some(h) = &self.hands else {
            return Ok(body);
        };
        let front = OwnedRaySamples::subset(samples, &h.indices);
        let weights = RenderWeights::new(h.sigma.clone(), &front.view())?;
        let rows = ints(h.indices.iter().map(|&i| i as i32).collect(), &device);
        let in_front = weights.integrate(columns.select(0, rows));
        Ok(in_front + weights.transmittance_end.unsqueeze_dim::<2>(1) * body)
    }
}

/// The whole TalkinNeRF field.
#[derive(Module, Debug)]
pub struct TalkinField {
    /// Identity codes. `[n_identities, identity_dim]`
    pub identity: Param<Tensor<2>>,
    /// Per-frame codes (`FieldConfig::frame_codes`). `[frames, frame_code_dim]`
    pub frame_codes: Option<Param<Tensor<2>>>,
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

/// The largest output [`Density::Exp`] exponentiates (`e^15` is 3.3e6 /m, opaque in
/// well under a micrometre): beyond it the density stops growing and overflow never comes.
pub const EXP_DENSITY_MAX_INPUT: f32 = 15.0;

/// Splits raw `[sigma, rgb]` into activated `(sigma [n], rgb [n, 3])`.
fn activate(raw: &Tensor<2>, density: Density) -> (Tensor<1>, Tensor<2>) {
    #[cfg(feature = "wgpu")]
    if density == Density::Softplus && !crate::device::is_cpu(&raw.device()) {
        // A device op each, cut and activation (`kernels::cube::heads`).
        use crate::kernels::cube::heads::{Activation, columns};
        let sigma = columns(raw.clone(), 0, 1, Activation::Softplus).squeeze_dim::<1>(1);
        return (sigma, columns(raw.clone(), 1, 3, Activation::Sigmoid));
    }
    activate_composed(raw, density)
}

/// [`activate`] as burn ops (the CPU's, and the device op's reference).
fn activate_composed(raw: &Tensor<2>, density: Density) -> (Tensor<1>, Tensor<2>) {
    let out = raw.clone().narrow(1, 0, 1);
    let sigma = match density {
        Density::Softplus => softplus(out),
        Density::Exp => out.clamp_max(EXP_DENSITY_MAX_INPUT).exp(),
    }
    .squeeze_dim::<1>(1);
    let rgb = sigmoid(raw.clone().narrow(1, 1, 3));
    (sigma, rgb)
}

/// The segmentation logits `[n, 5]` of F_body's raw output `[n, 9]`.
fn seg_logits_of(raw: Tensor<2>) -> Tensor<2> {
    #[cfg(feature = "wgpu")]
    if !crate::device::is_cpu(&raw.device()) {
        use crate::kernels::cube::heads::{Activation, columns};
        return columns(raw, 4, N_SEG_CLASSES, Activation::None);
    }
    raw.narrow(1, 4, N_SEG_CLASSES)
}

/// F_body's condition row: the frame code (if any) and the identity code. `[1, d]`
fn body_condition(code: Option<&Tensor<2>>, identity: &Tensor<2>) -> Tensor<2> {
    match code {
        Some(c) => Tensor::cat(vec![c.clone(), identity.clone()], 1),
        None => identity.clone(),
    }
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
    let scattered = add_rows(Tensor::<D>::zeros(base.shape(), &device), idx, values);
    base * keep + scattered
}

impl TalkinField {
    /// How this field's nets turn their raw output into density.
    pub fn density(&self) -> Density {
        self.settings.density
    }

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
            N_SMPLX_JOINTS,
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

        let warp = profile::timed("field: skinning", || {
            self.skinning.inverse_lbs_with(
                input.points,
                input.bone_masks,
                &frame.canonical_from_posed,
                &frame.bone_capsules,
                &device,
                leaves.map(|l| &l.canonical_from_posed),
            )
        })?;
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
        let code = self.frame_code(frame)?; // [1, code] or none
        let x = profile::timed("field: D_nr", || {
            self.deform(warp.x_canonical, input, code.as_ref(), leaves, &mut stats)
        }); // [n, 3]
        let identity = gather_rows(
            self.identity.val(),
            ints(vec![frame.identity as i32], &device),
        ); // [1, id]
        let body_condition = body_condition(code.as_ref(), &identity);
        let raw = profile::timed("field: F_body", || {
            self.body.forward(
                self.to_unit(x.clone()),
                frame.identity,
                body_condition,
                step,
            )
        }); // [n, 9]
        let (mut sigma, mut rgb) = activate(&raw, self.settings.density);
        let seg_logits = seg_logits_of(raw); // [n, 5]

        // Hard routing: candidates (the sampler's capsules) whose body label is the part.
        let route = Router::new(input.part_masks, &seg_logits, routing);
        let face = profile::timed("field: F_face", || {
            self.face_pass(&route, &x, &identity, input, leaves)
        });
        if let Some((head, s_face, c_face)) = face {
            stats.face_rows = head.rows.len();
            sigma = head.replace(sigma, s_face);
            rgb = head.replace(rgb, c_face);
        }
        let mut hands_out = None;
        let hands = profile::timed("field: D_hands, F_hands", || {
            self.hands_pass(&route, &x, identity, input, leaves)
        });
        if let Some((idx, s_hand, c_hand)) = hands {
            stats.hand_rows = idx.rows.len();
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
        Ok(FieldOutput {
            rgb,
            sigma,
            seg_logits,
            x_canonical: x,
            hands: hands_out,
            stats,
        })
    }

    /// F_body's condition row for a subject's identity row `[1, id]` (`[id]`'s row of
    /// [`TalkinField::identity`]) at a frame the run did not train on: the codes' mean
    /// beside it, or the identity alone without codes. `[1, d]`
    pub fn body_condition_unseen(&self, identity: Tensor<2>) -> Tensor<2> {
        let mean = self.frame_codes.as_ref().map(|c| c.val().mean_dim(0));
        body_condition(mean.as_ref(), &identity)
    }

    /// Frames with codes (0 without them).
    pub fn n_frame_codes(&self) -> usize {
        self.frame_codes.as_ref().map_or(0, |c| c.val().dims()[0])
    }

    /// The frame's code row `[1, d]`: its own, or for a frame without one the mean of
    /// the codes; `None` for a field without codes.
    fn frame_code(&self, frame: &FrameConditions) -> Result<Option<Tensor<2>>, NetsError> {
        let Some(codes) = &self.frame_codes else {
            return Ok(None);
        };
        let codes = codes.val();
        Ok(Some(match frame.frame_code {
            Some(i) if i < codes.dims()[0] => {
                gather_rows(codes, ints(vec![i as i32], &self.device()))
            }
            Some(i) => {
                return Err(NetsError::Index {
                    what: "frame code",
                    index: i,
                    limit: codes.dims()[0],
                });
            }
            None => codes.mean_dim(0),
        }))
    }

    /// The squared norm of the frame's own code (`[1]`), for its prior; `None` for a
    /// frame without a code or a field without codes.
    pub fn frame_code_norm2(&self, frame: &FrameConditions) -> Option<Tensor<1>> {
        let codes = self.frame_codes.as_ref()?.val();
        let i = frame.frame_code.filter(|&i| i < codes.dims()[0])?;
        let row = gather_rows(codes, ints(vec![i as i32], &self.device()));
        Some(row.powi_scalar(2).sum())
    }

    /// The field with `n` frame codes, each the mean of its current ones (a run that
    /// goes on training on other frames: an adaptation); unchanged without codes.
    pub fn reset_frame_codes(mut self, n: usize) -> TalkinField {
        if let Some(codes) = &self.frame_codes {
            let mean = codes.val().mean_dim(0).detach(); // [1, d]
            self.frame_codes = Some(Param::from_tensor(mean.repeat_dim(0, n.max(1))));
        }
        self
    }

    /// D_nr on the rigidly warped canonical points, once its start step is reached.
    fn deform(
        &self,
        x: Tensor<2>,
        input: &FieldInput,
        code: Option<&Tensor<2>>,
        leaves: Option<&PoseLeaves>,
        stats: &mut RoutingStats,
    ) -> Tensor<2> {
        let started = self
            .settings
            .non_rigid_start_step
            .is_some_and(|s| input.step >= s);
        let (Some(nr), true) = (&self.non_rigid, started) else {
            return x;
        };
        let pose = match leaves {
            Some(l) => l.body_pose.clone(),
            None => floats(
                input.frame.body_pose.clone(),
                [1, self.settings.pose_dim],
                &self.device(),
            ),
        };
        let condition = match code {
            Some(c) if self.settings.frame_code_deform => Tensor::cat(vec![pose, c.clone()], 1),
            _ => pose,
        };
        stats.non_rigid_rows = x.dims()[0];
        x.clone() + nr.forward(self.to_unit(x), condition, input.step)
    }

    /// The part's routed rows (candidate bit `bit`, label `label`) and their points of
    /// `x` (`[h, 3]`); `None` when no sample is routed there.
    fn routed(
        &self,
        route: &Router,
        bit: u8,
        label: usize,
        x: &Tensor<2>,
    ) -> Option<(Routed, Tensor<2>)> {
        let rows = route.rows(bit, label);
        if rows.rows.is_empty() {
            return None;
        }
        let points = gather_rows(x.clone(), rows.indices(&self.device()));
        Some((rows, points))
    }

    /// F_face on the head's routed rows: the rows, their density `[h]` and colour
    /// `[h, 3]` (`None` without F_face or rows).
    fn face_pass(
        &self,
        route: &Router,
        x: &Tensor<2>,
        identity: &Tensor<2>,
        input: &FieldInput,
        leaves: Option<&PoseLeaves>,
    ) -> Option<(Routed, Tensor<1>, Tensor<2>)> {
        let face = self.face.as_ref()?;
        let (head, xh) = self.routed(route, PART_BIT_HEAD, SEG_HEAD, x)?; // [h, 3]
        let device = self.device();
        let frame = input.frame;
        let (expression, jaw) = (
            self.settings.face_uses_expression,
            self.settings.face_uses_jaw,
        );
        let mut parts = Vec::with_capacity(3);
        match leaves {
            Some(l) => {
                if expression {
                    parts.push(l.expression.clone());
                }
                if jaw {
                    parts.push(l.jaw.clone());
                }
            }
            None => {
                let mut e = Vec::new();
                if expression {
                    e.extend(frame.expression);
                }
                if jaw {
                    e.extend(frame.jaw);
                }
                if !e.is_empty() {
                    let d_e = e.len();
                    parts.push(floats(e, [1, d_e], &device));
                }
            }
        }
        parts.push(identity.clone());
        let raw = face.forward(
            self.to_unit(xh),
            frame.identity,
            Tensor::cat(parts, 1),
            input.step,
        );
        let (sigma, rgb) = activate(&raw, self.settings.density);
        Some((head, sigma, rgb))
    }

    /// D_hands and F_hands on the hands' routed rows: the rows, their density `[h]` and
    /// colour `[h, 3]` (`None` without F_hands or rows).
    fn hands_pass(
        &self,
        route: &Router,
        x: &Tensor<2>,
        identity: Tensor<2>,
        input: &FieldInput,
        leaves: Option<&PoseLeaves>,
    ) -> Option<(Routed, Tensor<1>, Tensor<2>)> {
        let hands = self.hands.as_ref()?;
        let (idx, mut xh) = self.routed(route, PART_BIT_HANDS, SEG_HANDS, x)?; // [h, 3]
        let device = self.device();
        if let Some(dh) = &self.hand_deform {
            let pose = match leaves {
                Some(l) => l.hand_pose.clone(),
                None => floats(input.frame.hand_pose.clone(), [1, HAND_POSE_DIM], &device),
            };
            xh = xh.clone() + dh.forward(self.to_unit(xh), pose, input.step);
        }
        let raw = hands.forward(self.to_unit(xh), input.frame.identity, identity, input.step);
        let (sigma, rgb) = activate(&raw, self.settings.density);
        Some((idx, sigma, rgb))
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
mod tests;
