//! What a run is told: one struct that is the command line's options (`talkin train`,
//! `adapt` and the training benches flatten it). Field docs are the `--help` text. What a
//! run records of them is [`record`]'s own type.

mod file;
mod hash_grid;
pub mod record;

pub use file::RECIPE_FILE;
pub(crate) use file::write_recipe;

use std::path::PathBuf;
use std::str::FromStr;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Arg, ArgMatches, Args, FromArgMatches, ValueEnum};
use serde::{Deserialize, Serialize};
use talkin_data::dataset::{Dataset, Matting, mask_edge_px};
use talkin_grids::SamplerKind;
use talkin_nets::mlp::MlpPath;
use talkin_nets::{ComputeDevice, Density};

use crate::error::TrainError;
use crate::plan::record::Plan;
use crate::preset::Preset;
use crate::refine::RefineOptions;

/// Where `talkin lpips-weights` puts the converted LPIPS weights (a per-user cache).
pub use talkin_nets::loss::DEFAULT_LPIPS_DIR;

/// The widest frame code `--frame-codes` takes (the identity code is 32 wide).
pub const MAX_FRAME_CODE_DIM: usize = 64;

/// The widest mask edge `--mask-edge` takes (a wider one leaves thin limbs no rays).
pub const MAX_MASK_EDGE_PX: u32 = 16;

/// Sets one option of a recipe.
pub type SetOption = fn(&mut TrainOptions);

/// What a camera capture trains with where the command line names nothing else, by
/// the option's clap id, each measured on a real capture (docs/results.md, "A real
/// capture"): 512 random rays a step and no LPIPS patches (a 1024-ray step with one
/// AlexNet patch fits half the steps and paints a glowing sheath over black), every pixel
/// trained, the mask's edge included (scored over black the outline then gains), a
/// random background colour each step, and a code per training frame read by F_body and
/// D_nr, half the steps trained with the codes' mean instead (without it the field comes
/// to need each frame's own code over a long run and loses a decibel at four times the
/// 10-minute budget; "How thick, over budgets").
pub const CAPTURE_RECIPE: [(&str, SetOption); 7] = [
    ("batch_rays", |o| o.batch_rays = 512),
    ("patches", |o| o.patches = 0),
    ("mask_edge_px", |o| o.mask_edge_px = Some(0)),
    ("random_background", |o| o.random_background = true),
    ("frame_code_dim", |o| {
        o.frame_code_dim = CAPTURE_FRAME_CODE_DIM
    }),
    // After the width: codes named off (`--frame-codes 0`) leave D_nr without one.
    ("frame_code_deform", |o| {
        o.frame_code_deform = o.frame_code_dim > 0
    }),
    ("frame_code_dropout", |o| {
        o.frame_code_dropout = if o.frame_code_dim > 0 {
            CAPTURE_FRAME_CODE_DROPOUT
        } else {
            0.0
        }
    }),
];

/// The share of a capture's steps trained with the codes' mean.
pub const CAPTURE_FRAME_CODE_DROPOUT: f32 = 0.5;

/// The width of a camera capture's frame codes.
pub const CAPTURE_FRAME_CODE_DIM: usize = 16;

/// Everything a run is told.
#[derive(Clone, Debug, PartialEq, Args)]
pub struct TrainOptions {
    /// Field preset: `fast` (hash grid, small MLPs) or `paper` (8x256 MLPs).
    #[arg(long, value_enum, default_value_t = Preset::Fast, help_heading = "Model and device")]
    pub preset: Preset,
    /// Where the field trains: `cpu`, or `wgpu` / `wgpu:N` (a GPU; builds with the `wgpu`
    /// feature). Not part of the recipe: a run resumes, renders and serves on any device.
    #[arg(long, default_value_t = ComputeDevice::Cpu, help_heading = "Model and device")]
    pub device: ComputeDevice,
    /// Sampler: `accelerated` (exact capsule intervals + occupancy grid) or `dense` (128
    /// per ray).
    #[arg(long, default_value_t = SamplerKind::Accelerated, help_heading = "Model and device")]
    pub sampler: SamplerKind,
    /// How hand samples are skinned: `bones` (each finger about its own knuckles, so the
    /// field learns the rest-pose hand) or `wrist` (the fingers move with their wrist and
    /// the hand networks learn every finger pose seen).
    #[arg(long, value_enum, default_value_t = FingerSkinning::Bones, help_heading = "Model and device")]
    pub skin_fingers: FingerSkinning,
    /// Off the CPU, whether the MLPs take the fused device op (`on`) or burn's composed
    /// ops (`off`: the baseline it is measured against). Recorded in the field's
    /// configuration; the CPU always takes its fused kernel.
    #[arg(long = "mlp-fused", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub mlp_fused: bool,
    /// Off the CPU, rows a slice of the composed MLP products (0: no slicing). Recorded in
    /// the field's configuration.
    #[arg(long = "mlp-slice-rows", value_name = "N", default_value_t = MlpPath::default().slice_rows, help_heading = "Model and device")]
    pub mlp_slice_rows: usize,
    /// How the nets' output becomes density: `softplus` (grows linearly with the output)
    /// or `exp` (instant-ngp's truncated exponential: a few units of output take a sample
    /// from empty to opaque).
    #[arg(long, value_name = "softplus|exp", default_value = "softplus", value_parser = PossibleValuesParser::new(["softplus", "exp"]).map(|s| if s == "exp" { Density::Exp } else { Density::Softplus }), help_heading = "Model and device")]
    pub density: Density,
    #[command(flatten, next_help_heading = "Run")]
    pub budget: Budget,
    /// Seed of the initialisation, the frame and ray choice and the sample jitter.
    #[arg(long, default_value_t = 0, help_heading = "Run")]
    pub seed: u64,
    /// Subjects to train on: `all` (every subject with training frames) or a
    /// comma-separated list of names.
    #[arg(long, default_value_t = Identities::All, help_heading = "Data")]
    pub identities: Identities,
    /// Random pixel rays per step (besides the LPIPS patches).
    #[arg(long = "batch", value_name = "N", default_value_t = TrainOptions::default().batch_rays, help_heading = "Rays")]
    pub batch_rays: usize,
    /// 32x32 LPIPS patches per step (the paper: 6; 0 turns the perceptual term off).
    #[arg(long, default_value_t = TrainOptions::default().patches, help_heading = "Rays")]
    pub patches: usize,
    /// Initial Adam learning rate (default: the preset's); decays x0.1 per 500k of the
    /// paper's iterations, onto which every run is mapped.
    #[arg(long, help_heading = "Optimizer")]
    pub lr: Option<f64>,
    /// Fraction of random rays drawn inside the person's bounding box (the paper: 80%).
    #[arg(long, default_value_t = TrainOptions::default().bbox_fraction, help_heading = "Rays")]
    pub bbox_fraction: f32,
    /// Weight of the silhouette term: the rendered opacity against the mask (mean squared
    /// error), on every ray off the pixel either side of the mask's cut. Without it the
    /// field paints the background's colour around the person and in front of it (over
    /// any other background a sheath); 0: off, the paper's loss.
    #[arg(long, default_value_t = TrainOptions::default().mask_weight, help_heading = "Loss")]
    pub mask_weight: f32,
    /// Weight of the distortion loss (Mip-NeRF 360's, on the body pass, distances in
    /// metres): it draws each ray's weight into one short stretch, a surface, instead of
    /// a cloud spread through the shells' depth; 0: off.
    #[arg(long, default_value_t = TrainOptions::default().distortion, help_heading = "Loss")]
    pub distortion: f32,
    /// Weight of the hard-surface term (InstantAvatar's): `-ln(e^-x + e^(x-1))` of every
    /// body sample's compositing weight and of every ray's opacity, which is least at 0
    /// and 1, so that one sample takes a ray (a surface) instead of many sharing it (a
    /// cloud); 0: off.
    #[arg(long = "hard-surface", value_name = "W", default_value_t = TrainOptions::default().hard_surface, help_heading = "Loss")]
    pub hard_surface: f32,
    /// Width of a per-frame latent code read by F_body beside the identity code (one
    /// code per training frame, with a Gaussian prior; every other frame renders with
    /// their mean); 0: no codes.
    #[arg(long = "frame-codes", value_name = "DIM", default_value_t = TrainOptions::default().frame_code_dim, help_heading = "Model and device")]
    pub frame_code_dim: usize,
    /// Fraction of steps that train with the codes' mean instead of the frame's own code
    /// (a seeded draw each step), so the field renders well as renders are made, with
    /// the mean, and cannot come to need a frame's own code over a long run; 0: every
    /// step its frame's code.
    #[arg(long = "frame-code-dropout", value_name = "P", default_value_t = TrainOptions::default().frame_code_dropout, help_heading = "Model and device")]
    pub frame_code_dropout: f32,
    /// D_nr reads the frame code too (a deformation code): `on` or `off`.
    #[arg(long = "frame-code-deform", value_name = "on|off", default_value = "off", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub frame_code_deform: bool,
    /// Composite each step's targets and render over a random colour instead of the
    /// dataset's background (HumanNeRF, InstantAvatar), on a dataset composited by its
    /// masks (camera frames) or matted with coverage masks (`synth`'s); a matted one with
    /// a matte keeps its background: `on` or `off`.
    #[arg(long = "random-background", value_name = "on|off", default_value = "off", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Loss")]
    pub random_background: bool,
    /// Leave the mask's edge out of the random rays: pixels within PX of the mask's cut,
    /// on either side, where a matting tool's mask is often a pixel or two off (Neural
    /// Body leaves out 2 px). Default: 0 on a matted dataset (exact masks), and on a
    /// `by_mask` one (camera frames) 1 px per whole 256 px of the frame's longer side
    /// (none below 256 px, where a pixel is a limb's edge).
    #[arg(long = "mask-edge", value_name = "PX", help_heading = "Rays")]
    pub mask_edge_px: Option<u32>,
    /// D_nr's learning rate as a fraction of the field's (HumanNeRF trains its non-rigid
    /// MLP at 0.1 of its rate): Adam moves every weight by about the rate per step
    /// whatever its gradient, and at the field's rate D_nr's start set a real capture's
    /// body back (0.1: +0.56 dB in the person box there, +0.29 dB on the demo scene).
    #[arg(long, default_value_t = TrainOptions::default().non_rigid_lr_scale, help_heading = "Optimizer")]
    pub non_rigid_lr_scale: f64,
    /// Occupancy-grid update period in steps (0: never; accelerated sampler only).
    #[arg(long, default_value_t = TrainOptions::default().occ_every, help_heading = "Occupancy grid")]
    pub occ_every: u32,
    /// Occupancy-grid cells along the canonical box's longest axis.
    #[arg(long, default_value_t = TrainOptions::default().grid_resolution, help_heading = "Occupancy grid")]
    pub grid_resolution: u32,
    /// Directory of the converted LPIPS weights (`talkin lpips-weights`; by default the per-user cache);
    /// without them the perceptual term is 1 - SSIM, and the run says so.
    #[arg(long = "lpips-dir", value_name = "DIR", default_value_os = DEFAULT_LPIPS_DIR.as_os_str(), help_heading = "Loss")]
    pub perceptual: Option<PathBuf>,
    /// Levels of the `fast` preset's hash grids (default: the preset's 12, or the plan's:
    /// the finest level at half a pixel's footprint on the person).
    #[arg(
        long = "hash-levels",
        value_name = "N",
        help_heading = "Model and device"
    )]
    pub hash_levels: Option<usize>,
    /// Entries per level of the `fast` preset's F_body table, as a power of two (F_face's
    /// and F_hands' are a quarter of it; default: the preset's 17, or the plan's).
    #[arg(
        long = "hash-table",
        value_name = "LOG2",
        help_heading = "Model and device"
    )]
    pub hash_table_log2: Option<usize>,
    /// Checkpoint every this many seconds of training (and always at the end).
    #[arg(long = "checkpoint-every", value_name = "SECONDS", default_value_t = TrainOptions::default().checkpoint_every_s, help_heading = "Run")]
    pub checkpoint_every_s: f64,
    /// The paper's ablation switches (all on: the full method): `--hand-deform`, and the
    /// ablation bench's.
    #[command(flatten)]
    pub ablation: Ablation,
    /// Train on each subject's first S seconds of training frames only (a short clip:
    /// the novel-identity experiment's clips).
    #[arg(long = "seconds-of-video", value_name = "S", help_heading = "Data")]
    pub clip_seconds: Option<f64>,
    #[command(flatten, next_help_heading = "Pose refinement")]
    pub refine: RefineOptions,
    /// The plan these options were decided by (the census of the training frames and each
    /// decision; `talkin train` makes one unless `--plan off`); `None`: the options as
    /// given.
    #[arg(skip)]
    pub plan: Option<Plan>,
}

/// The most rows a slice of the composed MLP products may take (a batch is rarely more).
const MAX_SLICE_ROWS: usize = 1 << 20;

/// The MLP path these options choose ([`TrainOptions::mlp_fused`], `mlp_slice_rows`).
impl TrainOptions {
    pub fn mlp_path(&self) -> MlpPath {
        MlpPath {
            fused_on_device: self.mlp_fused,
            slice_rows: self.mlp_slice_rows,
        }
    }
}

/// How inverse LBS moves a hand's samples (`--skin-fingers`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum FingerSkinning {
    /// Over the 15 finger joints of the hand as well as the wrist.
    Bones,
    /// With the wrist only (finger joints map to their body ancestor).
    Wrist,
}

impl FingerSkinning {
    /// Whether the field skins the finger joints.
    pub fn finger_bones(self) -> bool {
        self == FingerSkinning::Bones
    }
}

/// The clap id of `--device`: where a run trains, not what it trains (a resume takes it).
pub const DEVICE_ARG: &str = "device";

/// How long to train: `--steps N` or `--minutes M` on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Budget {
    /// Optimizer steps (reproducible to the bit).
    Steps(usize),
    /// Wall-clock seconds of training (the schedule follows elapsed time; evaluation
    /// pauses in the benchmarks do not count).
    Seconds(f64),
}

impl Default for Budget {
    fn default() -> Self {
        Budget::Steps(1000)
    }
}

impl Budget {
    /// The clap ids of `--steps` and `--minutes`.
    pub const ARGS: [&str; 2] = ["steps", "minutes"];
}

impl FromArgMatches for Budget {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        Ok(
            match (
                m.get_one::<usize>(Budget::ARGS[0]),
                m.get_one::<f64>(Budget::ARGS[1]),
            ) {
                (_, Some(&minutes)) => Budget::Seconds(minutes * 60.0),
                (Some(&steps), None) => Budget::Steps(steps),
                (None, None) => Budget::default(),
            },
        )
    }

    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        *self = Budget::from_arg_matches(m)?;
        Ok(())
    }
}

impl Args for Budget {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        cmd.arg(
            Arg::new(Budget::ARGS[0])
                .long("steps")
                .value_name("N")
                .value_parser(clap::value_parser!(usize))
                .conflicts_with(Budget::ARGS[1])
                .help("Optimizer steps (default 1000 unless --minutes is given)"),
        )
        .arg(
            Arg::new(Budget::ARGS[1])
                .long("minutes")
                .value_name("M")
                .value_parser(clap::value_parser!(f64))
                .help("Train for this many minutes of wall-clock time instead of a step count"),
        )
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Budget::augment_args(cmd)
    }
}

/// Which subjects a run trains on; recorded as `null` (all) or a list of names.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(from = "Option<Vec<String>>", into = "Option<Vec<String>>")]
pub enum Identities {
    /// Every subject with training frames.
    #[default]
    All,
    /// These subjects, by name.
    Named(Vec<String>),
}

impl Identities {
    /// The names, or `None` for all.
    pub fn names(&self) -> Option<&[String]> {
        match self {
            Identities::All => None,
            Identities::Named(names) => Some(names),
        }
    }
}

impl From<Option<Vec<String>>> for Identities {
    fn from(names: Option<Vec<String>>) -> Self {
        names.map_or(Identities::All, Identities::Named)
    }
}

impl From<Identities> for Option<Vec<String>> {
    fn from(ids: Identities) -> Self {
        match ids {
            Identities::All => None,
            Identities::Named(names) => Some(names),
        }
    }
}

impl FromStr for Identities {
    type Err = String;

    /// `all`, or names separated by commas.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.trim() == "all" {
            return Ok(Identities::All);
        }
        let names: Vec<String> = s
            .split(',')
            .map(|n| n.trim().to_string())
            .filter(|n| !n.is_empty())
            .collect();
        if names.is_empty() {
            return Err("expected `all` or a comma-separated list of subject names".into());
        }
        Ok(Identities::Named(names))
    }
}

impl std::fmt::Display for Identities {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Identities::All => f.write_str("all"),
            Identities::Named(names) => f.write_str(&names.join(",")),
        }
    }
}

/// Switches on the field's parts: the paper's ablations (Tables 1 and 3; the ablation
/// bench sets the ones without a flag) and which networks and inputs a run builds (the
/// plan sets those from the data's census; each flag overrides it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Args)]
pub struct Ablation {
    /// D_hands, the paper's offset for hand samples from the hand pose: `on` or `off`.
    /// With `--skin-fingers bones` the finger bones already undo the fingers' motion, and
    /// D_hands moves the hands' scores by less than the noise of 2-minute runs
    /// (docs/results.md, "Ablations").
    #[arg(long = "hand-deform", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub use_d_hands: bool,
    /// D_nr, the non-rigid offset of every body sample from the body pose: `on` or `off`
    /// (inverse skinning alone carries the body; the pose-dependent folds of clothes are
    /// then averaged into one canonical body).
    #[arg(long = "non-rigid", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub non_rigid: bool,
    /// The body's rendered colour is the hands' background (off: "w/o background").
    #[arg(skip = true)]
    pub hand_background: bool,
    /// F_hands (and D_hands): `on`, or `off` (the hands are the body's, as F_body learns
    /// them). The plan turns it off where the hands cover too few pixels to teach it.
    #[arg(long = "hands", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub hands: bool,
    /// F_face: `on`, or `off` (the head is the body's). The plan turns it off where the
    /// head covers too few pixels to teach it.
    #[arg(long = "face", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub face: bool,
    /// F_face reads the expression psi: `on` or `off`. The plan turns it off where the
    /// fits' expression never changes.
    #[arg(long = "face-expression", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub face_uses_expression: bool,
    /// F_face reads the jaw's pose beside psi: `on` or `off` (the paper's "w/o jaw in
    /// e"). The plan turns it off where the fits' jaw never moves.
    #[arg(long = "face-jaw", value_name = "on|off", default_value = "on", value_parser = PossibleValuesParser::new(["on", "off"]).map(|s| s == "on"), action = clap::ArgAction::Set, help_heading = "Model and device")]
    pub face_uses_jaw: bool,
}

impl Default for Ablation {
    fn default() -> Self {
        Ablation {
            use_d_hands: true,
            non_rigid: true,
            hand_background: true,
            hands: true,
            face: true,
            face_uses_expression: true,
            face_uses_jaw: true,
        }
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            device: ComputeDevice::Cpu,
            preset: Preset::Fast,
            sampler: SamplerKind::Accelerated,
            skin_fingers: FingerSkinning::Bones,
            mlp_fused: true,
            mlp_slice_rows: MlpPath::default().slice_rows,
            density: Density::Softplus,
            budget: Budget::default(),
            seed: 0,
            identities: Identities::All,
            batch_rays: 1024,
            patches: 1,
            lr: None,
            bbox_fraction: 0.8,
            mask_weight: 1.0,
            distortion: 0.0,
            hard_surface: 0.0,
            random_background: false,
            frame_code_dim: 0,
            frame_code_deform: false,
            frame_code_dropout: 0.0,
            mask_edge_px: None,
            non_rigid_lr_scale: 0.1,
            occ_every: 64,
            grid_resolution: 128,
            hash_levels: None,
            hash_table_log2: None,
            perceptual: None,
            checkpoint_every_s: 120.0,
            ablation: Ablation::default(),
            clip_seconds: None,
            refine: RefineOptions::default(),
            plan: None,
        }
    }
}

impl TrainOptions {
    /// The initial learning rate: the option, else the preset's.
    pub fn initial_lr(&self) -> f64 {
        self.lr.unwrap_or(self.preset.learning_rate())
    }

    /// The perceptual term's weights directory, if the recipe has the term at all.
    pub fn perceptual_dir(&self) -> Option<&PathBuf> {
        self.perceptual.as_ref().filter(|_| self.patches > 0)
    }

    /// This recipe for `dataset`. On a camera capture (`"matting": "by_mask"`, what
    /// `import` writes) every option of [`CAPTURE_RECIPE`] the command line did not name
    /// (`named(id)` false for its clap id) takes the capture's value; the built-in scene
    /// and matted data keep the recipe as given.
    pub fn for_dataset(mut self, dataset: &Dataset, named: impl Fn(&str) -> bool) -> Self {
        if dataset.matting == Matting::ByMask {
            for (id, set) in CAPTURE_RECIPE {
                if !named(id) {
                    set(&mut self);
                }
            }
        }
        self
    }

    /// The mask edge left out of frame `i`'s random rays (`--mask-edge`), in pixels.
    pub fn mask_edge_in(&self, dataset: &Dataset, i: usize) -> u32 {
        self.mask_edge_px.unwrap_or_else(|| match dataset.matting {
            Matting::Matted | Matting::Reshown { .. } => 0,
            Matting::ByMask => {
                let camera = &dataset.frames[i].camera;
                mask_edge_px(camera.width, camera.height)
            }
        })
    }

    /// Checks every option; errors name the flag as the user types it.
    pub fn check(&self) -> Result<(), TrainError> {
        let bad = |flag, problem: &str| {
            Err(TrainError::BadOption {
                flag,
                problem: problem.to_string(),
            })
        };
        match self.budget {
            Budget::Steps(0) => return bad("--steps", "must be at least 1"),
            Budget::Seconds(s) if !(s.is_finite() && s > 0.0) => {
                return bad("--minutes", "must be a positive number");
            }
            _ => {}
        }
        if self.batch_rays == 0 && self.patches == 0 {
            return bad(
                "--batch",
                "a step needs rays: --batch or --patches must be > 0",
            );
        }
        if !(self.initial_lr().is_finite() && self.initial_lr() > 0.0) {
            return bad("--lr", "must be a positive number");
        }
        if self.mlp_slice_rows > MAX_SLICE_ROWS {
            return bad(
                "--mlp-slice-rows",
                &format!("must be at most {MAX_SLICE_ROWS} (0 turns slicing off)"),
            );
        }
        if !(self.mask_weight.is_finite() && self.mask_weight >= 0.0) {
            return bad("--mask-weight", "must be a finite number >= 0");
        }
        if self.frame_code_dim > MAX_FRAME_CODE_DIM {
            return bad(
                "--frame-codes",
                &format!("must be at most {MAX_FRAME_CODE_DIM}"),
            );
        }
        if self.frame_code_deform && self.frame_code_dim == 0 {
            return bad(
                "--frame-code-deform",
                "needs codes: give --frame-codes DIM > 0",
            );
        }
        if !(0.0..=1.0).contains(&self.frame_code_dropout) {
            return bad("--frame-code-dropout", "must be a fraction in [0, 1]");
        }
        if self.frame_code_dropout > 0.0 && self.frame_code_dim == 0 {
            return bad(
                "--frame-code-dropout",
                "needs codes: give --frame-codes DIM > 0",
            );
        }
        if !(self.distortion.is_finite() && self.distortion >= 0.0) {
            return bad("--distortion", "must be a finite number >= 0");
        }
        if !(self.hard_surface.is_finite() && self.hard_surface >= 0.0) {
            return bad("--hard-surface", "must be a finite number >= 0");
        }
        if let Some(px) = self.mask_edge_px
            && px > MAX_MASK_EDGE_PX
        {
            return bad(
                "--mask-edge",
                &format!("must be at most {MAX_MASK_EDGE_PX} px"),
            );
        }
        if !(self.non_rigid_lr_scale.is_finite() && self.non_rigid_lr_scale > 0.0) {
            return bad("--non-rigid-lr-scale", "must be a positive number");
        }
        if !(0.0..=1.0).contains(&self.bbox_fraction) {
            return bad("--bbox-fraction", "must lie in [0, 1]");
        }
        if self.grid_resolution < 8 || self.grid_resolution > 512 {
            return bad("--grid-resolution", "must be in 8..=512");
        }
        if let Err((flag, problem)) = self.check_hash_grid() {
            return bad(flag, &problem);
        }
        if self.checkpoint_every_s.is_nan() || self.checkpoint_every_s <= 0.0 {
            return bad("--checkpoint-every", "must be positive");
        }
        if let Some(c) = self.clip_seconds
            && !(c.is_finite() && c > 0.0)
        {
            return bad("--seconds-of-video", "must be a positive number of seconds");
        }
        if let Err((flag, problem)) = self.refine.check() {
            return bad(flag, problem);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        recipe: TrainOptions,
    }

    fn parse(args: &[&str]) -> Result<TrainOptions, clap::Error> {
        Cli::try_parse_from(std::iter::once("talkin").chain(args.iter().copied())).map(|c| c.recipe)
    }

    #[test]
    fn the_named_clap_ids_are_the_options() {
        use clap::CommandFactory;
        let cmd = Cli::command();
        let long_of = |id: &str| {
            cmd.get_arguments()
                .find(|a| a.get_id() == id)
                .and_then(|a| a.get_long())
        };
        assert_eq!(long_of(DEVICE_ARG), Some("device"));
        assert_eq!(long_of(Budget::ARGS[0]), Some("steps"));
        assert_eq!(long_of(Budget::ARGS[1]), Some("minutes"));
    }

    #[test]
    fn bad_options_name_their_flag() {
        let flag_of = |opts: TrainOptions| match opts.check() {
            Err(TrainError::BadOption { flag, .. }) => flag,
            other => panic!("{other:?}"),
        };
        for w in [-0.1, f32::NAN, f32::INFINITY] {
            let opts = TrainOptions {
                mask_weight: w,
                ..TrainOptions::default()
            };
            assert_eq!(flag_of(opts), "--mask-weight");
            let opts = TrainOptions {
                distortion: w,
                ..TrainOptions::default()
            };
            assert_eq!(flag_of(opts), "--distortion");
        }
        let opts = TrainOptions {
            frame_code_deform: true,
            ..TrainOptions::default()
        };
        assert_eq!(flag_of(opts), "--frame-code-deform");
        // A fraction, and only of codes there are.
        for (p, dim) in [(-0.1, 8), (1.5, 8), (f32::NAN, 8), (0.5, 0)] {
            let opts = TrainOptions {
                frame_code_dropout: p,
                frame_code_dim: dim,
                ..TrainOptions::default()
            };
            assert_eq!(flag_of(opts), "--frame-code-dropout");
        }
        let opts = TrainOptions {
            frame_code_dim: MAX_FRAME_CODE_DIM + 1,
            ..TrainOptions::default()
        };
        assert_eq!(flag_of(opts), "--frame-codes");
        let opts = TrainOptions {
            mlp_slice_rows: MAX_SLICE_ROWS + 1,
            ..TrainOptions::default()
        };
        assert_eq!(flag_of(opts), "--mlp-slice-rows");
        let opts = TrainOptions {
            lr: Some(0.0),
            ..TrainOptions::default()
        };
        assert_eq!(flag_of(opts), "--lr");
        for c in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let opts = TrainOptions {
                clip_seconds: Some(c),
                ..TrainOptions::default()
            };
            assert_eq!(flag_of(opts), "--seconds-of-video");
        }
        assert!(TrainOptions::default().check().is_ok());
    }

    /// The command line's defaults are the struct's, but for the LPIPS directory.
    #[test]
    fn command_line_defaults_are_the_defaults() {
        let parsed = parse(&[]).unwrap();
        assert_eq!(
            parsed,
            TrainOptions {
                perceptual: Some(DEFAULT_LPIPS_DIR.clone()),
                ..TrainOptions::default()
            }
        );
    }

    #[test]
    fn flags_fill_the_recipe() {
        let o = parse(&[
            "--preset",
            "paper",
            "--sampler",
            "dense",
            "--minutes",
            "1.5",
            "--identities",
            "ada, bo",
            "--batch",
            "64",
            "--seconds-of-video",
            "3",
            "--skin-fingers",
            "wrist",
        ])
        .unwrap();
        assert_eq!(o.skin_fingers, FingerSkinning::Wrist);
        assert_eq!(parse(&[]).unwrap().skin_fingers, FingerSkinning::Bones);
        assert_eq!(parse(&[]).unwrap().ablation, Ablation::default());
        let no_d_hands = parse(&["--hand-deform", "off"]).unwrap().ablation;
        assert!(!no_d_hands.use_d_hands && no_d_hands.hand_background && no_d_hands.face_uses_jaw);
        assert!(
            parse(&["--hand-deform", "on"])
                .unwrap()
                .ablation
                .use_d_hands
        );
        assert!(parse(&["--hand-deform", "no"]).is_err());
        assert_eq!(o.preset, Preset::Paper);
        assert_eq!(o.sampler, SamplerKind::Dense);
        assert_eq!(o.budget, Budget::Seconds(90.0));
        assert_eq!(
            o.identities,
            Identities::Named(vec!["ada".into(), "bo".into()])
        );
        assert_eq!(o.batch_rays, 64);
        assert_eq!(o.clip_seconds, Some(3.0));
        assert_eq!(parse(&["--steps", "7"]).unwrap().budget, Budget::Steps(7));
        assert!(parse(&["--steps", "7", "--minutes", "1"]).is_err());
        assert!(parse(&["--preset", "slow"]).is_err());
        assert!(parse(&["--identities", ","]).is_err());
    }

    /// A camera capture takes the capture recipe wherever the command line named nothing,
    /// and every id in it is a real option's (a renamed field would leave it unapplied).
    #[test]
    fn a_capture_takes_the_capture_recipe_where_nothing_was_named() {
        use clap::CommandFactory;
        let ids: Vec<String> = Cli::command()
            .get_arguments()
            .map(|a| a.get_id().to_string())
            .collect();
        for (id, _) in CAPTURE_RECIPE {
            assert!(ids.iter().any(|i| i == id), "`{id}` is no option's id");
        }
        let dataset = |matting| Dataset {
            root: PathBuf::new(),
            background: [1.0; 3],
            matting,
            masks: Default::default(),
            subjects: vec![],
            frames: vec![],
        };
        let given = TrainOptions::default();
        let matted = given
            .clone()
            .for_dataset(&dataset(Matting::Matted), |_| false);
        assert_eq!(matted, given);
        let capture = given
            .clone()
            .for_dataset(&dataset(Matting::ByMask), |_| false);
        assert_eq!((capture.batch_rays, capture.patches), (512, 0));
        assert_eq!(capture.mask_edge_px, Some(0));
        assert!(capture.random_background && capture.frame_code_deform);
        assert_eq!(capture.frame_code_dim, CAPTURE_FRAME_CODE_DIM);
        assert_eq!(capture.frame_code_dropout, CAPTURE_FRAME_CODE_DROPOUT);
        assert!(capture.check().is_ok());
        // What the command line named stays as given.
        let named = parse(&["--batch", "2048", "--mask-edge", "2"])
            .unwrap()
            .for_dataset(&dataset(Matting::ByMask), |id| {
                id == "batch_rays" || id == "mask_edge_px"
            });
        assert_eq!((named.batch_rays, named.patches), (2048, 0));
        assert_eq!(named.mask_edge_px, Some(2));
        let without_codes = parse(&["--frame-codes", "0"])
            .unwrap()
            .for_dataset(&dataset(Matting::ByMask), |id| id == "frame_code_dim");
        assert!(!without_codes.frame_code_deform && without_codes.check().is_ok());
        assert_eq!(without_codes.frame_code_dropout, 0.0);
    }
}
