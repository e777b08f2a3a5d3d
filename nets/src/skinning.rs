//! D_r: inverse linear blend skinning over the 22 SMPL-X body joints with a learned
//! blend-weight volume in canonical space (HumanNeRF's motion-weight volume), initialised
//! from a bone-distance prior.
//!
//! # Convention
//! The caller gives, per frame, 22 row-major 4x4 matrices `canonical_from_posed[b]`
//! (`x_canonical_b = R_b x + t_b` in the paper's eq. 2: the inverse of bone `b`'s skinning
//! transform `posed_from_canonical`); the bottom row is ignored.
//!
//! # What is evaluated
//! HumanNeRF's observation-space weights (its eq. 5): every candidate bone `b` maps the
//! sample to its own canonical point `x_b = R_b x + t_b`, reads *its own* logit channel of
//! the volume there, `l_b = V_b(x_b)` (trilinear), and the weights are a softmax over the
//! candidate bones, `w_b = exp(l_b) / sum_k exp(l_k)`; then `x_canonical = sum_b w_b x_b`.
//! Reading each bone's weight at that bone's canonical point is what makes the weights live
//! in canonical space without an iterative root search, so no fixed-point step is needed.
//! Only the sample's candidate bones (the caller's 55-bit mask, mapped to body ancestors)
//! are evaluated; a sample with no candidate falls back to all 22.
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

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::error::{NetsError, check_len};
use crate::util::{floats, ints};

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

/// The body joint that drives SMPL-X joint `joint` in D_r: itself for body joints, the
/// head for jaw and eyes (22-24), the wrists for the fingers (25-39 left, 40-54 right).
pub const fn body_ancestor(joint: usize) -> usize {
    match joint {
        0..=21 => joint,
        22..=24 => HEAD_JOINT,
        25..=39 => LEFT_WRIST,
        _ => RIGHT_WRIST,
    }
}

/// Candidate body bones (22-bit mask) of a 55-bit SMPL-X candidate mask; all 22 when the
/// mask names none.
pub fn body_candidates(mask: u64) -> u32 {
    let mut out = 0u32;
    let mut m = mask & ((1u64 << N_SMPLX_JOINTS) - 1);
    while m != 0 {
        let j = m.trailing_zeros() as usize;
        out |= 1 << body_ancestor(j);
        m &= m - 1;
    }
    if out == 0 {
        (1 << N_BODY_JOINTS) - 1
    } else {
        out
    }
}

/// A segment of bone `bone` in canonical space (a bone may have several, e.g. the pelvis
/// to both hips; a leaf bone may give a point, `a == b`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoneSegment {
    /// Body joint index (< 22).
    pub bone: usize,
    /// Segment start (metres, canonical).
    pub a: [f32; 3],
    /// Segment end.
    pub b: [f32; 3],
}

/// A made-up prior for tests and benches, not a body: one horizontal segment per body
/// bone, 9 cm apart upwards from 1 m below the origin, inside the unit box.
#[doc(hidden)]
pub fn ladder_prior() -> Vec<BoneSegment> {
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

/// A solid core of body bone `bone` in the posed (observation) frame: the posed-space
/// prior's geometry (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoneCapsule {
    /// Body joint index (< 22).
    pub bone: usize,
    /// Segment start (metres, posed).
    pub a: [f32; 3],
    /// Segment end.
    pub b: [f32; 3],
    /// Radius (metres; 0 for a bare segment).
    pub radius: f32,
}

/// Logit of a bone with no capsule in the posed-space prior.
const NO_CAPSULE_LOGIT: f32 = -1e4;

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
}

impl SkinningConfig {
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
        if let Some(s) = prior.iter().find(|s| s.bone >= N_BODY_JOINTS) {
            return Err(NetsError::Index {
                what: "bone segment",
                index: s.bone,
                limit: N_BODY_JOINTS,
            });
        }
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
            Some(_) => vec![0.0; N_BODY_JOINTS * r * r * r],
            None => canonical_prior_logits(r, aabb_min, aabb_max, prior, self.prior_sigma),
        };
        Ok(BlendWeightVolume {
            logits: Param::from_tensor(floats(logits, [N_BODY_JOINTS * r * r * r], device)),
            resolution: r,
            aabb: aabb_min.iter().chain(&aabb_max).copied().collect(),
            posed_tau,
        })
    }
}

/// HumanNeRF's initialisation: per bone, `-d^2 / (2 sigma^2)` at every vertex, `d` the
/// distance to the bone's nearest canonical segment; bones without one get -1e4.
fn canonical_prior_logits(
    r: usize,
    aabb_min: [f32; 3],
    aabb_max: [f32; 3],
    prior: &[BoneSegment],
    sigma: f64,
) -> Vec<f32> {
    let inv = 1.0 / (2.0 * sigma * sigma);
    let mut logits = vec![-1e4f32; N_BODY_JOINTS * r * r * r];
    for z in 0..r {
        for y in 0..r {
            for x in 0..r {
                let p: [f64; 3] = std::array::from_fn(|a| {
                    let t = [x, y, z][a] as f64 / (r - 1) as f64;
                    aabb_min[a] as f64 + t * (aabb_max[a] as f64 - aabb_min[a] as f64)
                });
                for s in prior {
                    let d2 = segment_distance2(p, s.a, s.b);
                    let slot = &mut logits[((s.bone * r + z) * r + y) * r + x];
                    *slot = slot.max((-d2 * inv) as f32);
                }
            }
        }
    }
    logits
}

/// Signed distance from `p` to capsule `c` (negative inside), in f64 for the products.
fn capsule_distance(p: [f32; 3], c: &BoneCapsule) -> f32 {
    let p = p.map(|v| v as f64);
    (segment_distance2(p, c.a, c.b).sqrt() - c.radius as f64) as f32
}

fn segment_distance2(p: [f64; 3], a: [f32; 3], b: [f32; 3]) -> f64 {
    let ab: [f64; 3] = std::array::from_fn(|i| b[i] as f64 - a[i] as f64);
    let ap: [f64; 3] = std::array::from_fn(|i| p[i] - a[i] as f64);
    let len2: f64 = ab.iter().map(|v| v * v).sum();
    let t = if len2 > 0.0 {
        (ap.iter().zip(&ab).map(|(u, v)| u * v).sum::<f64>() / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (0..3).map(|i| (ap[i] - t * ab[i]).powi(2)).sum()
}

/// Result of [`BlendWeightVolume::inverse_lbs`].
#[derive(Clone, Debug)]
pub struct RigidWarp {
    /// Canonical positions (differentiable w.r.t. the volume). `[n, 3]`
    pub x_canonical: Tensor<2>,
    /// (sample, bone) pairs evaluated: the cost of the warp.
    pub n_pairs: usize,
}

/// Learned skinning-weight logits, one channel per body bone, over the canonical box.
#[derive(Module, Debug)]
pub struct BlendWeightVolume {
    /// `[22 * R^3]`, index `((bone * R + z) * R + y) * R + x`.
    pub logits: Param<Tensor<1>>,
    resolution: usize,
    /// `[min xyz, max xyz]`
    aabb: Vec<f32>,
    /// The posed-space prior's temperature (metres), if on.
    #[module(skip)]
    posed_tau: Option<f32>,
}

/// Host-side (sample, bone) pairs with their canonical points and volume corners.
pub(crate) struct Pairs {
    pub sample: Vec<i32>,
    pub bone: Vec<usize>,
    /// `[m * 3]`
    pub x: Vec<f32>,
    /// `[m * 8]`
    pub rows: Vec<i32>,
    /// `[m * 8]`
    pub weights: Vec<f32>,
    /// `[m]` the posed-space prior's logit (0 when off).
    pub posed: Vec<f32>,
}

impl BlendWeightVolume {
    /// Vertices per axis.
    pub fn resolution(&self) -> usize {
        self.resolution
    }

    pub(crate) fn pairs(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        canonical_from_posed: &[[f32; 16]],
        bone_capsules: &[BoneCapsule],
    ) -> Pairs {
        let r = self.resolution;
        let mut p = Pairs {
            sample: vec![],
            bone: vec![],
            x: vec![],
            rows: vec![],
            weights: vec![],
            posed: vec![],
        };
        let mut by_bone: [Vec<&BoneCapsule>; N_BODY_JOINTS] = Default::default();
        for c in bone_capsules {
            by_bone[c.bone].push(c);
        }
        for (s, (x, &mask)) in points.iter().zip(bone_masks).enumerate() {
            let mut bones = body_candidates(mask);
            while bones != 0 {
                let b = bones.trailing_zeros() as usize;
                bones &= bones - 1;
                let m = &canonical_from_posed[b];
                let xc: [f32; 3] = std::array::from_fn(|i| {
                    (m[4 * i] as f64 * x[0] as f64
                        + m[4 * i + 1] as f64 * x[1] as f64
                        + m[4 * i + 2] as f64 * x[2] as f64
                        + m[4 * i + 3] as f64) as f32
                });
                let mut cell = [0usize; 3];
                let mut frac = [0f32; 3];
                for a in 0..3 {
                    let span = self.aabb[3 + a] - self.aabb[a];
                    let u =
                        ((xc[a] - self.aabb[a]) / span * (r - 1) as f32).clamp(0.0, (r - 1) as f32);
                    let c = (u.floor() as usize).min(r - 2);
                    cell[a] = c;
                    frac[a] = u - c as f32;
                }
                for k in 0..8 {
                    let d = [k & 1, (k >> 1) & 1, k >> 2];
                    let mut w = 1.0;
                    for a in 0..3 {
                        w *= if d[a] == 1 { frac[a] } else { 1.0 - frac[a] };
                    }
                    let (x, y, z) = (cell[0] + d[0], cell[1] + d[1], cell[2] + d[2]);
                    p.rows.push((((b * r + z) * r + y) * r + x) as i32);
                    p.weights.push(w);
                }
                p.sample.push(s as i32);
                p.bone.push(b);
                p.x.extend(xc);
                p.posed.push(match self.posed_tau {
                    Some(tau) => by_bone[b].iter().fold(NO_CAPSULE_LOGIT, |l, c| {
                        l.max(-capsule_distance(*x, c) / tau)
                    }),
                    None => 0.0,
                });
            }
        }
        p
    }

    /// Maps observation-space samples to canonical space (see the module docs).
    ///
    /// # Shapes
    /// - `points`: `[n]` observation-space positions; `bone_masks`: `[n]` 55-bit SMPL-X
    ///   candidate masks; `canonical_from_posed`: `[22]` row-major 4x4; `bone_capsules`:
    ///   the frame's posed solid cores (any number; read only with the posed prior on)
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
    /// `x_b = R_b x + t_b` taken from `transforms` (`[22, 12]`, the top rows of
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
            N_BODY_JOINTS,
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
        if let Some(c) = bone_capsules.iter().find(|c| c.bone >= N_BODY_JOINTS) {
            return Err(NetsError::Index {
                what: "bone capsule",
                index: c.bone,
                limit: N_BODY_JOINTS,
            });
        }
        let p = self.pairs(points, bone_masks, canonical_from_posed, bone_capsules);
        let m = p.sample.len();
        let xb = match transforms {
            None => floats(p.x, [m, 3], device), // [m, 3]
            Some(rows) => {
                // [m, 3, 4] transforms times [m, 1, 4] homogeneous points, summed.
                let bones = ints(p.bone.iter().map(|&b| b as i32).collect::<Vec<_>>(), device);
                let mats = rows.clone().select(0, bones).reshape([m, 3, 4]);
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
        let logits = (self
            .logits
            .val()
            .select(0, ints(p.rows, device))
            .reshape([m, 8])
            * corner_w)
            .sum_dim(1)
            .reshape([m])
            + floats(p.posed, [m], device); // [m]
        // Softmax over each sample's candidates; the per-sample max is a constant shift,
        // taken on the device (no readback mid-forward on a GPU).
        let sample = ints(p.sample, device);
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

        let x_canonical = Tensor::<2>::zeros([n, 3], device).select_assign(
            0,
            sample,
            xb * w.unsqueeze_dim(1),
            IndexingUpdateOp::Add,
        );
        Ok(RigidWarp {
            x_canonical,
            n_pairs: m,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::host;

    fn identity_transforms() -> Vec<[f32; 16]> {
        (0..N_BODY_JOINTS)
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

    #[test]
    fn ancestors_and_candidates() {
        assert_eq!(body_ancestor(22), HEAD_JOINT);
        assert_eq!(body_ancestor(24), HEAD_JOINT);
        assert_eq!(body_ancestor(25), LEFT_WRIST);
        assert_eq!(body_ancestor(39), LEFT_WRIST);
        assert_eq!(body_ancestor(40), RIGHT_WRIST);
        assert_eq!(body_ancestor(54), RIGHT_WRIST);
        assert_eq!(body_candidates(0), (1 << 22) - 1);
        assert_eq!(
            body_candidates((1 << 30) | (1 << 23) | 1),
            (1 << 20) | (1 << 15) | 1
        );
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
        let moved = |k: usize, b: usize| -> [f32; 3] {
            std::array::from_fn(|i| pts[k][i] + t[b][4 * i + 3])
        };
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
            run(capsule(22, 0.1)),
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

    /// A config written before the posed prior existed reads as the canonical prior alone.
    #[test]
    fn configs_without_posed_tau_read_as_off() {
        let old: SkinningConfig =
            serde_json::from_str(r#"{"resolution": 32, "prior_sigma": 0.1}"#).unwrap();
        assert_eq!(old.posed_tau, None);
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
                                pairs.weights[i * 8 + k] as f64
                                    * logits[pairs.rows[i * 8 + k] as usize]
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
}
