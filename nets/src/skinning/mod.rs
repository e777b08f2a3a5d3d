//! D_r: inverse linear blend skinning over the SMPL-X joints with a learned blend-weight
//! volume in canonical space (HumanNeRF's motion-weight volume), initialised from a
//! bone-distance prior. The skinned joints are the 22 body joints, and with
//! [`SkinningConfig::finger_bones`] the 30 finger joints too: a finger then bends about its
//! own knuckles, so the canonical hand is the rest-pose hand, not the blur of every finger
//! pose seen (the jaw and eyes always follow the head).
//!
//! # Convention
//! The caller gives, per frame, 55 row-major 4x4 matrices `canonical_from_posed[j]`, one per
//! SMPL-X joint (`x_canonical_j = R_j x + t_j` in the paper's eq. 2: the inverse of joint
//! `j`'s skinning transform `posed_from_canonical`); the bottom row is ignored.
//!
//! # What is evaluated
//! HumanNeRF's observation-space weights (its eq. 5): every candidate bone `b` maps the
//! sample to its own canonical point `x_b = R_b x + t_b`, reads *its own* logit channel of
//! the volume there, `l_b = V_b(x_b)` (trilinear), and the weights are a softmax over the
//! candidate bones, `w_b = exp(l_b) / sum_k exp(l_k)`; then `x_canonical = sum_b w_b x_b`.
//! Reading each bone's weight at that bone's canonical point is what makes the weights live
//! in canonical space without an iterative root search, so no fixed-point step is needed.
//! Only the sample's candidate bones (the caller's 55-bit mask, each mapped to its
//! [`skinned_joint`]) are evaluated; a sample with no candidate falls back to the 22 body
//! joints.
//!
//! # The posed-space prior (`SkinningConfig::posed_tau`)
//! Initialised from distances to the canonical bones (HumanNeRF's prior), the weights are
//! wrong wherever limbs touch: a forearm held against the chest maps, through the chest's
//! transform, to a canonical point next to the chest whose chest weight is as high as the
//! forearm's own, and the blend lands between the two (centimetres off, differently in
//! every pose). With `posed_tau`, each candidate's logit also gets `-d_b / tau`, `d_b` the
//! signed distance in the *posed* frame to bone `b`'s nearest solid core (the caller's
//! [`BoneCapsule`]s), and the volume starts at zero as a learned correction: in contact
//! the limb whose core the sample is in (or nearest) wins, as it should.
//!
//! A temperature is a length, and a finger is a fifth of a forearm's thickness: with
//! finger bones, a sample with a finger among its candidates is weighed at
//! [`FINGER_TAU_FRACTION`] of the temperature. At the limbs' 5 mm, a fingertip 12 cm in
//! front of the face kept a few percent of the head's weight, and the head's canonical
//! point is half a metre from the hand's: the tip landed 22 mm from its own (median 15
//! mm); at 1 mm, 0.01 mm.

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

#[cfg(feature = "wgpu")]
use crate::device::is_cpu;
use crate::error::{NetsError, check_len};
use crate::rows::gather_rows;
use crate::util::{floats, ints};

#[cfg(feature = "wgpu")]
mod device;
mod pairs;
mod prior;

use prior::canonical_prior_logits;
pub use prior::{BoneCapsule, BoneSegment, ladder_prior};

/// Body joints driving D_r.
pub const N_BODY_JOINTS: usize = 22;
/// SMPL-X joints in the caller's candidate masks.
pub const N_SMPLX_JOINTS: usize = 55;
/// The head joint (jaw and eyes map here).
pub const HEAD_JOINT: usize = 15;
/// Left wrist (left fingers map here).
pub const LEFT_WRIST: usize = 20;
/// Right wrist (right fingers map here).
pub const RIGHT_WRIST: usize = 21;

/// The first finger joint (left index 1); joints 25-39 are the left hand's, 40-54 the
/// right's.
pub const FIRST_FINGER_JOINT: usize = 25;

/// The SMPL-X joints that are fingers, as a candidate mask.
const FINGER_MASK: u64 = ((1u64 << N_SMPLX_JOINTS) - 1) & !((1u64 << FIRST_FINGER_JOINT) - 1);

/// The posed prior's temperature for a sample with a finger candidate, as a fraction of
/// the limbs' (module docs).
pub const FINGER_TAU_FRACTION: f32 = 0.2;

/// The body joint that drives SMPL-X joint `joint` without finger bones: itself for body
/// joints, the head for jaw and eyes (22-24), the wrists for the fingers (25-39 left, 40-54
/// right).
pub const fn body_ancestor(joint: usize) -> usize {
    match joint {
        0..=21 => joint,
        22..=24 => HEAD_JOINT,
        25..=39 => LEFT_WRIST,
        _ => RIGHT_WRIST,
    }
}

/// The joint whose transform and weight channel skin what SMPL-X joint `joint`'s capsules
/// hold: with `finger_bones`, a finger joint itself; else (and for the jaw and eyes always)
/// its [`body_ancestor`].
pub const fn skinned_joint(joint: usize, finger_bones: bool) -> usize {
    if finger_bones && joint >= FIRST_FINGER_JOINT && joint < N_SMPLX_JOINTS {
        joint
    } else {
        body_ancestor(joint)
    }
}

/// Candidate skinned joints (a mask over the SMPL-X joints) of a 55-bit SMPL-X candidate
/// mask; the 22 body joints when the mask names none or all of them. A mask naming every
/// joint carries no candidate information (HumanNeRF's dense samples): such a sample is
/// skinned as HumanNeRF's are, over the body joints, its fingers with their wrist; the
/// 30 finger bones would make a dense step 1.5x dearer for samples that are almost all
/// far from a hand.
pub fn skinned_candidates(mask: u64, finger_bones: bool) -> u64 {
    let all = (1u64 << N_SMPLX_JOINTS) - 1;
    let finger_bones = finger_bones && mask & all != all;
    let mut out = 0u64;
    let mut m = mask & all;
    while m != 0 {
        let j = m.trailing_zeros() as usize;
        out |= 1 << skinned_joint(j, finger_bones);
        m &= m - 1;
    }
    if out == 0 {
        (1 << N_BODY_JOINTS) - 1
    } else {
        out
    }
}

/// Configuration of [`BlendWeightVolume`].
#[derive(Config, Debug)]
pub struct SkinningConfig {
    /// Vertices per axis of the logit volume.
    #[config(default = 32)]
    pub resolution: usize,
    /// Prior logits are `-d^2 / (2 prior_sigma^2)`, `d` the distance to the bone (metres).
    #[config(default = 0.1)]
    pub prior_sigma: f64,
    /// Temperature (metres) of the posed-space prior (module docs). `None`: the volume
    /// holds the canonical bone-distance prior alone (HumanNeRF's; checkpoints written
    /// before the posed prior existed read as `None`).
    #[config(default = "None")]
    pub posed_tau: Option<f64>,
    /// Whether the 30 finger joints skin their own samples (module docs): 55 weight
    /// channels instead of 22. `None` (checkpoints written before finger skinning): no.
    #[config(default = "None")]
    pub finger_bones: Option<bool>,
}

impl SkinningConfig {
    /// Whether the finger joints are skinned ([`Self::finger_bones`]).
    pub fn skins_fingers(&self) -> bool {
        self.finger_bones == Some(true)
    }

    /// Builds the volume over the canonical box, logits from the bone-distance prior. Bones
    /// without a segment get a very low logit (they only win where nothing else is a
    /// candidate).
    pub fn init(
        &self,
        aabb_min: [f32; 3],
        aabb_max: [f32; 3],
        prior: &[BoneSegment],
        device: &Device,
    ) -> Result<BlendWeightVolume, NetsError> {
        let r = self.resolution.max(2);
        if let Some(s) = prior.iter().find(|s| s.bone >= N_SMPLX_JOINTS) {
            return Err(NetsError::Index {
                what: "bone segment",
                index: s.bone,
                limit: N_SMPLX_JOINTS,
            });
        }
        let finger_bones = self.skins_fingers();
        let channels = channels(finger_bones);
        let posed_tau = match self.posed_tau {
            Some(t) if !(t.is_finite() && t > 0.0) => {
                return Err(NetsError::Config {
                    field: "skinning.posed_tau",
                    value: t.to_string(),
                    expected: "a finite temperature > 0 (metres)",
                });
            }
            t => t.map(|t| t as f32),
        };
        // With the posed prior the volume is a learned correction and starts at zero;
        // without it, it holds the canonical bone-distance prior.
        let logits = match posed_tau {
            Some(_) => vec![0.0; channels * r * r * r],
            None => {
                canonical_prior_logits(r, aabb_min, aabb_max, prior, self.prior_sigma, finger_bones)
            }
        };
        Ok(BlendWeightVolume {
            logits: Param::from_tensor(floats(logits, [channels * r * r * r], device)),
            resolution: r,
            aabb: aabb_min.iter().chain(&aabb_max).copied().collect(),
            posed_tau,
            finger_bones,
        })
    }
}

/// Result of [`BlendWeightVolume::inverse_lbs`].
#[derive(Clone, Debug)]
pub struct RigidWarp {
    /// Canonical positions (differentiable w.r.t. the volume). `[n, 3]`
    pub x_canonical: Tensor<2>,
    /// (sample, bone) pairs evaluated: the cost of the warp.
    pub n_pairs: usize,
}

/// Weight channels of the volume: one per body joint, or one per SMPL-X joint with finger
/// bones (a channel's index is its joint's; the jaw's and eyes' three are never read).
pub(crate) const fn channels(finger_bones: bool) -> usize {
    if finger_bones {
        N_SMPLX_JOINTS
    } else {
        N_BODY_JOINTS
    }
}

/// Learned skinning-weight logits, one channel per skinned joint, over the canonical box.
#[derive(Module, Debug)]
pub struct BlendWeightVolume {
    /// `[C * R^3]` (`C`: 22 joints, or 55 with finger bones), index
    /// `((joint * R + z) * R + y) * R + x`.
    pub logits: Param<Tensor<1>>,
    resolution: usize,
    /// `[min xyz, max xyz]`
    aabb: Vec<f32>,
    /// The posed-space prior's temperature (metres), if on.
    #[module(skip)]
    posed_tau: Option<f32>,
    /// Whether the finger joints are skinned (see [`SkinningConfig::finger_bones`]).
    #[module(skip)]
    finger_bones: bool,
}

impl BlendWeightVolume {
    /// Vertices per axis.
    pub fn resolution(&self) -> usize {
        self.resolution
    }

    /// Whether the finger joints are skinned (see [`SkinningConfig::finger_bones`]).
    pub fn finger_bones(&self) -> bool {
        self.finger_bones
    }

    /// Candidate skinned joints of a sample with SMPL-X candidate mask `mask`: what
    /// [`Self::inverse_lbs`] evaluates for it.
    pub fn candidates(&self, mask: u64) -> u64 {
        skinned_candidates(mask, self.finger_bones)
    }

    /// The frame's posed capsules grouped by the skinned joint whose prior they make.
    fn capsules_by_bone<'c>(
        &self,
        bone_capsules: &'c [BoneCapsule],
    ) -> [Vec<&'c BoneCapsule>; N_SMPLX_JOINTS] {
        let mut by_bone: [Vec<&BoneCapsule>; N_SMPLX_JOINTS] = std::array::from_fn(|_| vec![]);
        for c in bone_capsules {
            by_bone[skinned_joint(c.bone, self.finger_bones)].push(c);
        }
        by_bone
    }

    /// Maps observation-space samples to canonical space (see the module docs).
    ///
    /// # Shapes
    /// - `points`: `[n]` observation-space positions; `bone_masks`: `[n]` 55-bit SMPL-X
    ///   candidate masks; `canonical_from_posed`: `[55]` row-major 4x4, one per SMPL-X
    ///   joint; `bone_capsules`: the frame's posed solid cores, each labelled with its
    ///   SMPL-X joint (any number; read only with the posed prior on)
    /// - output `x_canonical`: `[n, 3]`
    pub fn inverse_lbs(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        canonical_from_posed: &[[f32; 16]],
        bone_capsules: &[BoneCapsule],
        device: &Device,
    ) -> Result<RigidWarp, NetsError> {
        self.inverse_lbs_with(
            points,
            bone_masks,
            canonical_from_posed,
            bone_capsules,
            device,
            None,
        )
    }

    /// [`BlendWeightVolume::inverse_lbs`], with each candidate's canonical point
    /// `x_b = R_b x + t_b` taken from `transforms` (`[55, 12]`, the top rows of
    /// `canonical_from_posed`, e.g. leaves that require gradients) when given, so that the
    /// warp is differentiable in them. The trilinear corners and weights where each bone's
    /// logit is read stay those of the host transforms: the transforms' gradient flows
    /// through the blended points, not through where the weights are looked up.
    pub fn inverse_lbs_with(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        canonical_from_posed: &[[f32; 16]],
        bone_capsules: &[BoneCapsule],
        device: &Device,
        transforms: Option<&Tensor<2>>,
    ) -> Result<RigidWarp, NetsError> {
        let n = points.len();
        check_len("bone_masks", bone_masks.len(), n)?;
        check_len(
            "canonical_from_posed",
            canonical_from_posed.len(),
            N_SMPLX_JOINTS,
        )?;
        if n == 0 {
            return Ok(RigidWarp {
                x_canonical: Tensor::zeros([0, 3], device),
                n_pairs: 0,
            });
        }
        let finite = |c: &BoneCapsule| {
            c.a.iter()
                .chain(&c.b)
                .chain([&c.radius])
                .all(|v| v.is_finite())
        };
        if !bone_capsules.iter().all(finite) {
            return Err(NetsError::NonFinite {
                what: "bone_capsules",
            });
        }
        if let Some(c) = bone_capsules.iter().find(|c| c.bone >= N_SMPLX_JOINTS) {
            return Err(NetsError::Index {
                what: "bone capsule",
                index: c.bone,
                limit: N_SMPLX_JOINTS,
            });
        }
        #[cfg(feature = "wgpu")]
        if !is_cpu(device) {
            let transforms = match transforms {
                Some(rows) => rows.clone(),
                None => {
                    let rows = canonical_from_posed.iter().flat_map(|m| &m[..12]);
                    floats(rows.copied().collect(), [N_SMPLX_JOINTS, 12], device)
                }
            };
            let (x_canonical, n_pairs) =
                self.warp_on_device(points, bone_masks, bone_capsules, transforms, device);
            return Ok(RigidWarp {
                x_canonical,
                n_pairs,
            });
        }
        let mut p = self.pairs(points, bone_masks, canonical_from_posed, bone_capsules);
        let m = p.sample.len();
        let xb = match transforms {
            None => floats(std::mem::take(&mut p.x), [m, 3], device), // [m, 3]
            Some(rows) => {
                // [m, 3, 4] transforms times [m, 1, 4] homogeneous points, summed.
                let bones = ints(p.bone.iter().map(|&b| b as i32).collect::<Vec<_>>(), device);
                let mats = gather_rows(rows.clone(), bones).reshape([m, 3, 4]);
                let xh: Vec<f32> = p
                    .sample
                    .iter()
                    .flat_map(|&s| {
                        let x = points[s as usize];
                        [x[0], x[1], x[2], 1.0]
                    })
                    .collect();
                let xh = floats(xh, [m, 1, 4], device);
                (mats * xh).sum_dim(2).reshape([m, 3])
            }
        };
        let corner_w = floats(p.weights, [m, 8], device);
        let logits = (gather_rows(self.logits.val(), ints(p.rows, device)).reshape([m, 8])
            * corner_w)
            .sum_dim(1)
            .reshape([m])
            + floats(p.posed, [m], device); // [m]
        Ok(RigidWarp {
            x_canonical: blend_scattered(p.sample, n, logits, xb),
            n_pairs: m,
        })
    }
}

impl BlendWeightVolume {
    /// Each sample's skinning weights as the warp blends them: `(skinned joint, weight)`
    /// over its candidates (see the module docs), summing to one, read on the host. At
    /// the canonical pose (identity `canonical_from_posed`, canonical cores) these are the
    /// weights of forward skinning from canonical space, what an exported rig carries.
    ///
    /// # Shapes
    /// As [`BlendWeightVolume::inverse_lbs`]; output `[n]` lists of pairs.
    pub fn blend_weights(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        canonical_from_posed: &[[f32; 16]],
        bone_capsules: &[BoneCapsule],
    ) -> Result<Vec<Vec<(usize, f32)>>, NetsError> {
        check_len("bone_masks", bone_masks.len(), points.len())?;
        check_len(
            "canonical_from_posed",
            canonical_from_posed.len(),
            N_SMPLX_JOINTS,
        )?;
        let volume = crate::device::read_floats(self.logits.val())
            .ok()
            .filter(|v| v.iter().all(|l| l.is_finite()))
            .ok_or(NetsError::NonFinite {
                what: "skinning logits",
            })?;
        let p = self.pairs(points, bone_masks, canonical_from_posed, bone_capsules);
        let mut out: Vec<Vec<(usize, f32)>> = vec![Vec::new(); points.len()];
        for (j, &s) in p.sample.iter().enumerate() {
            let logit: f32 = (0..8)
                .map(|k| p.weights[8 * j + k] * volume[p.rows[8 * j + k] as usize])
                .sum::<f32>()
                + p.posed[j];
            out[s as usize].push((p.bone[j], logit));
        }
        for pairs in &mut out {
            let max = pairs.iter().map(|p| p.1).fold(f32::NEG_INFINITY, f32::max);
            let mut total = 0.0;
            for p in pairs.iter_mut() {
                p.1 = (p.1 - max).exp();
                total += p.1;
            }
            for p in pairs.iter_mut() {
                p.1 /= total;
            }
        }
        Ok(out)
    }
}

/// The softmax blend `x_canonical = sum_b w_b x_b` over each sample's candidates, as sums
/// of the pairs into their samples' rows (`select_assign`): parallel on the CPU, one GPU
/// thread for the batch (a GPU takes the device kernel, `device.rs`).
///
/// # Shapes
/// - `sample`: `[m]` each pair's sample, ascending; every sample has at least one pair
/// - `logits`: `[m]`; `xb`: `[m, 3]`; output `[n, 3]`
fn blend_scattered(sample: Vec<i32>, n: usize, logits: Tensor<1>, xb: Tensor<2>) -> Tensor<2> {
    let device = &logits.device();
    // The per-sample max is a constant shift, taken on the device (no readback).
    let sample = ints(sample, device);
    let max = Tensor::<1>::full([n], f32::NEG_INFINITY, device).select_assign(
        0,
        sample.clone(),
        logits.clone().detach(),
        IndexingUpdateOp::Max,
    ); // [n]
    let shift = max.select(0, sample.clone()); // [m]
    let e = (logits - shift).exp(); // [m], max 1 per sample
    let denom = Tensor::<1>::zeros([n], device).select_assign(
        0,
        sample.clone(),
        e.clone(),
        IndexingUpdateOp::Add,
    );
    let w = e / denom.select(0, sample.clone()); // [m]
    Tensor::<2>::zeros([n, 3], device).select_assign(
        0,
        sample,
        xb * w.unsqueeze_dim(1),
        IndexingUpdateOp::Add,
    )
}

#[cfg(test)]
mod tests;
