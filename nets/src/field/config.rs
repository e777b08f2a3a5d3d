//! The field's architecture as configuration (burn `Config`, saved beside every
//! checkpoint): the encodings, the nets' sizes, the skinning, the switches of the paper's
//! ablations and the two named architectures ([`FieldConfig::paper`],
//! [`FieldConfig::fast`]), and building a field from it.

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;

use super::{
    DeformNet, EXPRESSION_DIM, FieldSettings, HAND_POSE_DIM, JAW_DIM, N_SEG_CLASSES, RadianceNet,
    TalkinField,
};
use crate::encoding::{
    Encoding, EncodingConfig, FrequencyConfig, HannWindowConfig, HashGridConfig,
};
use crate::error::NetsError;
use crate::init::WeightRng;
use crate::mlp::{MlpConfig, MlpPath};
use crate::skinning::{BoneSegment, SkinningConfig};

/// Entries per level (log2) of the `fast` preset's F_face and F_hands tables. The head
/// and hands fill a few percent of the canonical cube, so a table a quarter of F_body's
/// holds their fine levels; every table row costs a training step its gradient, its sum
/// over the batch's chunks and Adam's pass, whether a sample touched it or not.
pub const PART_LOG2_ENTRIES: usize = 15;

/// Everything that decides the field's architecture; saved as JSON beside checkpoints.
#[derive(Config, Debug)]
pub struct FieldConfig {
    /// Point encoding of F_body (and of F_face and F_hands without `part_encoding`).
    pub encoding: EncodingConfig,
    /// Point encoding of F_face and F_hands, which see only the head's and hands' few
    /// samples; `None` (checkpoints written before the choice existed): `encoding`.
    #[config(default = "None")]
    pub part_encoding: Option<EncodingConfig>,
    /// F_body.
    pub body: MlpConfig,
    /// F_face.
    pub face: MlpConfig,
    /// F_hands.
    pub hands: MlpConfig,
    /// D_nr and D_hands.
    pub deform: MlpConfig,
    /// Sinusoidal bands of the deformation nets' input.
    #[config(default = 6)]
    pub deform_bands: usize,
    /// Hann window of D_nr's encoding (absolute steps).
    pub non_rigid_window: HannWindowConfig,
    /// Hann window of D_hands' encoding (absolute steps).
    pub hand_window: HannWindowConfig,
    /// The skinning-weight volume.
    pub skinning: SkinningConfig,
    /// Subjects (one learned code each).
    #[config(default = 1)]
    pub n_identities: usize,
    /// Identity code width.
    #[config(default = 32)]
    pub identity_dim: usize,
    /// Body pose condition of D_nr (21 x 3 axis-angle).
    #[config(default = 63)]
    pub pose_dim: usize,
    /// Canonical box (metres): the weight volume and the encodings live here.
    #[config(default = "[-1.0, -1.3, -0.5]")]
    pub aabb_min: [f32; 3],
    /// Canonical box maximum.
    #[config(default = "[1.0, 1.0, 0.5]")]
    pub aabb_max: [f32; 3],
    /// Step from which D_nr runs; `None`: D_nr is not built.
    #[config(default = "Some(100_000)")]
    pub non_rigid_start_step: Option<usize>,
    /// Build and route to F_face.
    #[config(default = true)]
    pub has_face: bool,
    /// Build and route to D_hands + F_hands.
    #[config(default = true)]
    pub has_hands: bool,
    /// Ablation "w/o D_hands" when false.
    #[config(default = true)]
    pub use_d_hands: bool,
    /// The body's rendered colour is the hands' background (paper); false is the ablation
    /// "w/o background": hand outputs replace the body's in a single pass.
    #[config(default = true)]
    pub hand_background: bool,
    /// Condition F_face on `e = [psi; jaw]` (13); false: psi only (10).
    #[config(default = true)]
    pub face_uses_jaw: bool,
    /// F_face reads the expression `psi`; false (a capture whose expression never
    /// changes): the jaw alone, or the identity alone without the jaw either.
    #[config(default = true)]
    pub face_uses_expression: bool,
    /// Per-frame latent codes ([`FrameCodes`]); `None` (checkpoints written before the
    /// codes existed, and runs without them): none.
    #[config(default = "None")]
    pub frame_codes: Option<FrameCodes>,
    /// How canonical points map into the nets' unit cube; `None` (checkpoints written
    /// before the choice existed) is [`UnitMap::PerAxis`].
    #[config(default = "None")]
    pub unit_map: Option<UnitMap>,
    /// Which products the MLPs run off the CPU; `None` (checkpoints written before the
    /// choice was recorded) is the default [`MlpPath`].
    #[config(default = "None")]
    pub mlp_path: Option<MlpPath>,
    /// How a net's raw output becomes density; `None` (checkpoints written before the
    /// choice existed) is [`Density::Softplus`].
    #[config(default = "None")]
    pub density: Option<Density>,
}

/// How a net's raw output becomes density (per metre).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Density {
    /// `softplus(x)`: the density grows linearly with the output, so an opaque surface
    /// in one bin of a few millimetres (about 1000 /m) takes an output near 1000.
    #[default]
    Softplus,
    /// `exp(min(x, 15))` (instant-ngp's truncated exponential): each unit of output
    /// multiplies the density by e, so an output near 7 is a surface, and the gradient
    /// scales with the density.
    Exp,
}

impl Density {
    /// The density of one raw output on the host, as the field's forward computes it
    /// (NaN stays NaN).
    pub fn of(self, raw: f32) -> f32 {
        match self {
            Density::Softplus => raw.max(0.0) + (-raw.abs()).exp().ln_1p(),
            Density::Exp => raw.min(super::EXP_DENSITY_MAX_INPUT).exp(),
        }
    }
}

/// Per-frame latent codes: one per training frame, read by F_body (and by D_nr with
/// `deform`) beside the identity code, so that what changes from frame to frame need not
/// be averaged into the canonical body; frames the run did not train on read the codes'
/// mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrameCodes {
    /// Codes (the run's training frames, in order).
    pub count: usize,
    /// Width of a code.
    pub dim: usize,
    /// D_nr reads the code too (a deformation code).
    pub deform: bool,
}

/// How canonical points map into the unit cube the encodings and deformation nets see.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum UnitMap {
    /// Each axis of the canonical box stretched to [0, 1]: the demo's ~0.74 m deep box got
    /// ~2.9x finer hash cells in depth than in height.
    PerAxis,
    /// The box's bounding cube (same centre, its longest side): one scale on every axis,
    /// so the encodings resolve a centimetre alike along x, y and z (the presets).
    Isotropic,
}

/// The presets' posed-prior temperature (metres): 5 mm, so weights blend only within
/// millimetres of where two cores meet. Measured against the synthetic scene's true
/// canonical points (a throwaway diagnostic; the README's design note "A posed-space
/// prior"), 5 mm and 1 cm put the surface within the same 0.2-0.3 cm on the forearms;
/// 5 mm is tighter on the hands.
pub const POSED_TAU_M: f64 = 0.005;

impl FieldConfig {
    /// The paper's sizes: 8x256 MLPs with a skip at layer 4 and 10-band PE for the
    /// radiance nets, 6x128 deformation nets with 6 Hann-windowed bands, D_nr after 100k.
    pub fn paper(n_identities: usize) -> Self {
        let big = MlpConfig::new(8, 256).with_skips(vec![4]);
        FieldConfig::new(
            EncodingConfig::Frequency(FrequencyConfig::new(10)),
            big.clone(),
            big.clone(),
            big,
            MlpConfig::new(6, 128).with_skips(vec![4]),
            HannWindowConfig::new(100_000, 150_000),
            HannWindowConfig::new(0, 50_000),
            SkinningConfig::new()
                .with_posed_tau(Some(POSED_TAU_M))
                .with_finger_bones(Some(true)),
        )
        .with_n_identities(n_identities)
        .with_unit_map(Some(UnitMap::Isotropic))
    }

    /// The CPU default: a 12-level hash grid (2^17 entries per level, shared by the
    /// identities: 2^15 left the finer levels of three people's clothes colliding; the
    /// demo's test_same PSNR went 21.97 -> 22.24 dB in the same 8 minutes; F_face's and
    /// F_hands' tables 2^[`PART_LOG2_ENTRIES`]) and 2x64 MLPs, with the paper's step
    /// schedule (D_nr from 100k, the same Hann windows): training maps any run onto the
    /// paper's 400k iterations.
    pub fn fast(n_identities: usize) -> Self {
        let small = MlpConfig::new(2, 64);
        let grid = |log2_entries: usize| {
            EncodingConfig::HashGrid(
                HashGridConfig::new()
                    .with_n_levels(12)
                    .with_log2_hashmap_size(log2_entries)
                    .with_n_identities(n_identities.max(1)),
            )
        };
        FieldConfig::new(
            grid(17),
            small.clone(),
            small.clone(),
            small.clone(),
            small,
            HannWindowConfig::new(100_000, 150_000),
            HannWindowConfig::new(0, 50_000),
            SkinningConfig::new()
                .with_posed_tau(Some(POSED_TAU_M))
                .with_finger_bones(Some(true)),
        )
        .with_part_encoding(Some(grid(PART_LOG2_ENTRIES)))
        .with_n_identities(n_identities)
        .with_unit_map(Some(UnitMap::Isotropic))
    }

    /// Width of F_face's expression condition (`[psi; jaw]`, or what of it it reads).
    pub fn expression_dim(&self) -> usize {
        (if self.face_uses_expression {
            EXPRESSION_DIM
        } else {
            0
        }) + if self.face_uses_jaw { JAW_DIM } else { 0 }
    }

    /// Builds the field; `prior` initialises the skinning weights and `rng` draws the
    /// rest. Modules the config switches off are not built.
    pub fn init(
        &self,
        prior: &[BoneSegment],
        device: &Device,
        rng: &mut WeightRng,
    ) -> Result<TalkinField, NetsError> {
        let skinning = self
            .skinning
            .init(self.aabb_min, self.aabb_max, prior, device)?;
        // The draws keep the order burn's lazily initialised layers gave them, so a seed
        // gives the field it always gave: the identity codes and the encodings' tables
        // first, then every layer in the order the field lists its modules.
        let identity = rng.tensor(
            [self.n_identities.max(1), self.identity_dim],
            Distribution::Normal(0.0, 0.1),
            device,
        );
        let part_encoding = self.part_encoding.as_ref().unwrap_or(&self.encoding);
        let mlp_path = self.mlp_path.unwrap_or_default();
        let body_encoding = self.encoding.init(device, rng);
        let face_encoding = self.has_face.then(|| part_encoding.init(device, rng));
        let hands_encoding = self.has_hands.then(|| part_encoding.init(device, rng));
        let radiance = |encoding: Encoding,
                        mlp: &MlpConfig,
                        d_cond: usize,
                        d_out: usize,
                        rng: &mut WeightRng| {
            let d_in = encoding.output_dim() + d_cond + self.identity_dim;
            RadianceNet {
                mlp: mlp.init(d_in, d_out, None, device, rng).with_path(mlp_path),
                encoding,
            }
        };
        let deform = |window: HannWindowConfig, d_cond: usize, rng: &mut WeightRng| {
            let encoding = FrequencyConfig::new(self.deform_bands)
                .with_window(Some(window))
                .init();
            let d_in = encoding.output_dim(3) + d_cond;
            DeformNet {
                mlp: self
                    .deform
                    .init(d_in, 3, Some(1e-5), device, rng)
                    .with_path(mlp_path),
                encoding,
            }
        };
        let codes = self.frame_codes.filter(|c| c.count > 0 && c.dim > 0);
        let code_dim = codes.map_or(0, |c| c.dim);
        let deform_code_dim = codes.filter(|c| c.deform).map_or(0, |c| c.dim);
        let non_rigid = self
            .non_rigid_start_step
            .map(|_| deform(self.non_rigid_window, self.pose_dim + deform_code_dim, rng));
        let body = radiance(body_encoding, &self.body, code_dim, 4 + N_SEG_CLASSES, rng);
        let face = face_encoding.map(|e| radiance(e, &self.face, self.expression_dim(), 4, rng));
        let hand_deform = (self.has_hands && self.use_d_hands)
            .then(|| deform(self.hand_window, HAND_POSE_DIM, rng));
        let hands = hands_encoding.map(|e| radiance(e, &self.hands, 0, 4, rng));
        // Zeros, not drawn: the codes take nothing from the RNG (what a wider first layer
        // of F_body and D_nr draws still differs).
        let frame_codes =
            codes.map(|c| Param::from_tensor(Tensor::zeros([c.count, c.dim], device)));
        Ok(TalkinField {
            identity: Param::from_tensor(identity),
            frame_codes,
            skinning,
            non_rigid,
            body,
            face,
            hand_deform,
            hands,
            settings: FieldSettings {
                aabb_min: self.aabb_min,
                aabb_max: self.aabb_max,
                non_rigid_start_step: self.non_rigid_start_step,
                hand_background: self.hand_background,
                face_uses_jaw: self.face_uses_jaw,
                face_uses_expression: self.face_uses_expression,
                unit_map: self.unit_map.unwrap_or(UnitMap::PerAxis),
                pose_dim: self.pose_dim,
                n_identities: self.n_identities.max(1),
                frame_code_deform: deform_code_dim > 0,
                density: self.density.unwrap_or_default(),
            },
        })
    }
}
