//! One frame's samplers, built once and used by training, rendering and the benchmark:
//! the dense baseline in HumanNeRF's box (the posed joints +- 0.3 m in the body's frame)
//! and the accelerated pipeline (per ray, the exact grown-capsule intervals up to the
//! first core, culled per bin by the canonical occupancy grid through the bones' rigid
//! maps, and without cores stopped where the grid's densities spend the ray:
//! [`AcceleratedSampler`]).

use std::sync::{Arc, Mutex, OnceLock};

use glam::{Affine3A, Vec3};
use talkin_grids::intersect::validate_capsules;
use talkin_grids::{
    AcceleratedOpts, AcceleratedSampler, CanonicalCull, Capsule, CapsuleBvh, DenseOpts,
    DilatedOccupancy, GridError, OccupancyGrid, PackedSamples, Ray, SamplerKind, sample_dense,
};

use super::frame::{FrameScene, capsule_bounds, median_dense_step};
use super::shells::CapsuleShells;
use talkin_human::body::PosedSkeleton;
use talkin_nets::skinning::skinned_joint;

/// Dense samples per ray (the HumanNeRF baseline).
pub const DENSE_SAMPLES_PER_RAY: u32 = 128;

/// The dense box's margin around the posed joints (metres): HumanNeRF's `bbox_offset`.
pub const DENSE_BOX_MARGIN_M: f32 = 0.3;

/// Canonical slack (metres) the cull's dilation adds to a bin's reach: the bones' rigid
/// maps only approximate the skinning, and out-of-distribution poses put surface points
/// up to about a centimetre outside the band carved around the training surfaces. On
/// the default scene a dilation of the bin's reach alone (one canonical cell) lost 1
/// test_ood surface point of 2.33 M; with this slack (two cells) none.
pub const CULL_POSE_SLACK_M: f32 = 0.01;

/// A posed frame's acceleration structures and sampling box.
pub struct FrameSampler {
    pub scene: FrameScene,
    /// BVHs over the grown capsules and over their solid cores, built on first use: the
    /// exact reference the accelerated sampler is checked against (the benchmark uses
    /// them to tell which stage lost a surface point). Training and rendering never ask.
    bvhs: OnceLock<(CapsuleBvh, CapsuleBvh)>,
    /// The dense sampler's box, axis-aligned in the body's frame (`dense_from_world`):
    /// HumanNeRF's, the posed joints +- [`DENSE_BOX_MARGIN_M`] in the frame of the root
    /// joint (its axes turn with the global orientation, as HumanNeRF's body frame does).
    pub dense_min: Vec3,
    pub dense_max: Vec3,
    /// World -> the root joint's frame (rigid).
    pub dense_from_world: Affine3A,
    /// The accelerated step (metres): a dense sampler's step on the median foreground ray
    /// in the box of the grown capsules + 2 cm (see [`FrameSampler::new`]).
    pub step: f32,
    grown: Vec<Capsule>,
    cores: Vec<Capsule>,
    /// Per bone (0..64): posed -> canonical by its skinned joint's transform (its body
    /// ancestor's, or a finger's own where the field skins the fingers).
    canonical_from_posed: Vec<Affine3A>,
    /// The accelerated sampler for the canonical grid with this fingerprint.
    accelerated: Mutex<Option<(u64, Arc<AcceleratedSampler>)>>,
}

impl FrameSampler {
    /// The samplers of `scene`'s capsules grown by `shells`. The accelerated step is the
    /// step 128 samples would take on the median of `step_rays` (the frame's foreground
    /// rays) through the grown capsules' box + 2 cm: as fine as a dense sampler in the
    /// tightest box around the person. HumanNeRF's looser box makes the dense baseline's
    /// own step coarser (about 1.4x on the default scene). The cull maps a bin into the
    /// canonical grid as the field skins it: a finger's bins by the finger's own transform
    /// with `finger_bones`, else by the wrist's.
    pub fn new(
        scene: FrameScene,
        shells: &CapsuleShells,
        step_rays: &[Ray],
        finger_bones: bool,
    ) -> Result<FrameSampler, GridError> {
        let grown = shells.inflate(&scene.capsules);
        let cores = shells.stopping_cores(&scene.capsules);
        validate_capsules(&grown)?;
        validate_capsules(&cores)?;
        let (box_min, box_max) = capsule_bounds(&grown, 0.02);
        let step = median_dense_step(step_rays, box_min, box_max, DENSE_SAMPLES_PER_RAY);
        let (dense_from_world, dense_min, dense_max) = joints_box(&scene.posed);
        let canonical_from_posed = (0..64)
            .map(|b| {
                let j = skinned_joint(b.min(54), finger_bones);
                scene.canonical_from_posed[j]
            })
            .collect();
        Ok(FrameSampler {
            scene,
            bvhs: OnceLock::new(),
            dense_min,
            dense_max,
            dense_from_world,
            step,
            grown,
            cores,
            canonical_from_posed,
            accelerated: Mutex::new(None),
        })
    }

    /// The BVH over the grown capsules and the one over their cores (built on first use).
    pub fn bvhs(&self) -> Result<&(CapsuleBvh, CapsuleBvh), GridError> {
        if let Some(built) = self.bvhs.get() {
            return Ok(built);
        }
        let built = (
            CapsuleBvh::build(&self.grown)?,
            CapsuleBvh::build(&self.cores)?,
        );
        Ok(self.bvhs.get_or_init(|| built))
    }

    /// The accelerated sampler culling with `grid` (the subject's canonical occupancy
    /// grid), made on first use and again only when the grid's bits change (occupancy
    /// updates); the dilated grid comes from `dilated`, the subject's, shared by its
    /// frames.
    pub fn prepare(
        &self,
        grid: &OccupancyGrid,
        dilated: &DilatedGrids,
    ) -> Result<Arc<AcceleratedSampler>, GridError> {
        let key = grid.fingerprint();
        let mut cached = self.accelerated.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((k, sampler)) = cached.as_ref()
            && *k == key
        {
            return Ok(sampler.clone());
        }
        let reach = AcceleratedSampler::cull_reach(self.step) + CULL_POSE_SLACK_M;
        let cull = CanonicalCull {
            grid: dilated.get(grid, reach)?,
            canonical_from_posed: self.canonical_from_posed.clone(),
            // Where cores end the rays (data with depth) they stop them; a stop where the
            // grid's densities spend a ray is for the rays no core can end.
            stop_where_spent: self.cores.is_empty(),
        };
        let sampler = Arc::new(AcceleratedSampler::new(
            &self.grown,
            &self.cores,
            Some(cull),
            self.step,
        )?);
        *cached = Some((key, sampler.clone()));
        Ok(sampler)
    }

    /// Samples `rays` with `kind`, stratified with jitter seeded by `jitter` (training), or
    /// at the regular bins' places for `None` (rendering: a jittered render is noisier,
    /// -0.12 dB on the demo's test_same). The accelerated sampler culls with `grid`, the
    /// subject's canonical occupancy grid, dilated through `dilated` (the subject's).
    pub fn sample(
        &self,
        kind: SamplerKind,
        rays: &[Ray],
        grid: &OccupancyGrid,
        dilated: &DilatedGrids,
        jitter: Option<u64>,
    ) -> Result<PackedSamples, GridError> {
        match kind {
            SamplerKind::Dense => sample_dense(
                &self.in_dense_frame(rays),
                self.dense_min,
                self.dense_max,
                &DenseOpts {
                    samples_per_ray: DENSE_SAMPLES_PER_RAY,
                    jitter: jitter.is_some(),
                    seed: jitter.unwrap_or(0),
                },
            ),
            SamplerKind::Accelerated => self
                .prepare(grid, dilated)?
                .sample(rays, &self.accelerated_opts(jitter)),
        }
    }

    /// `rays` in the dense box's frame. The map is rigid, so a sample's `t` along a mapped
    /// ray is its `t` along the original.
    fn in_dense_frame(&self, rays: &[Ray]) -> Vec<Ray> {
        let m = &self.dense_from_world;
        rays.iter()
            .map(|r| Ray {
                origin: m.transform_point3(r.origin),
                direction: m.transform_vector3(r.direction),
                ..*r
            })
            .collect()
    }

    /// The accelerated sampler's options: jittered with the seed, or regular for `None`.
    pub fn accelerated_opts(&self, jitter: Option<u64>) -> AcceleratedOpts {
        AcceleratedOpts {
            step: self.step,
            jitter: jitter.is_some(),
            seed: jitter.unwrap_or(0),
        }
    }
}

/// HumanNeRF's dense box (`skeleton_to_bbox`): world -> the root joint's frame, and the
/// posed joints' bounds in that frame +- [`DENSE_BOX_MARGIN_M`]. HumanNeRF takes SMPL's
/// 24 joints; these are SMPL-X's 55 (the same body joints, plus fingers, jaw and eyes,
/// which lie within a few centimetres of SMPL's hand and head joints).
fn joints_box(posed: &PosedSkeleton) -> (Affine3A, Vec3, Vec3) {
    let root = posed.world_from_joint[0];
    let world_from_root =
        Affine3A::from_mat3_translation(root.matrix3.as_mat3(), root.translation.as_vec3());
    let dense_from_world = world_from_root.inverse();
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for j in posed.joints() {
        let p = dense_from_world.transform_point3(j.as_vec3());
        (lo, hi) = (lo.min(p), hi.max(p));
    }
    let margin = Vec3::splat(DENSE_BOX_MARGIN_M);
    (dense_from_world, lo - margin, hi + margin)
}

/// A subject's canonical grid dilated for the accelerated sampler's cull, shared by every
/// frame of the subject: dilating is per grid, not per frame, so the last few results
/// are kept by the grid's fingerprint. Owned beside the grid it dilates (a
/// [`SubjectModel`](crate::subject::SubjectModel)'s, or a test's); a clone starts with
/// the same results and keeps its own from then on.
#[derive(Default)]
pub struct DilatedGrids {
    recent: Mutex<Vec<Arc<DilatedOccupancy>>>,
}

/// Dilated grids a [`DilatedGrids`] keeps (the oldest goes first).
const DILATED_GRIDS_KEPT: usize = 8;

impl DilatedGrids {
    /// `grid` dilated by at least `reach` (in whole cells).
    pub fn get(
        &self,
        grid: &OccupancyGrid,
        reach: f32,
    ) -> Result<Arc<DilatedOccupancy>, GridError> {
        let key = grid.fingerprint();
        // A little more than asked, so frames whose steps differ slightly share one; the
        // dilation is whole cells, so the cache is matched on the cell count: what a frame
        // gets depends only on the grid and its own step, never on what was cached before
        // (matching any larger reach made training depend on the order frames were seen).
        let ask = reach * 1.25;
        let cells = (ask / grid.cell_size().min_element()).ceil();
        let mut recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(d) = recent.iter().find(|d| {
            d.source_fingerprint() == key
                && (d.reach() / grid.cell_size().min_element()).round() == cells
        }) {
            return Ok(d.clone());
        }
        let d = Arc::new(DilatedOccupancy::new(grid, ask)?);
        if recent.len() >= DILATED_GRIDS_KEPT {
            recent.remove(0);
        }
        recent.push(d.clone());
        Ok(d)
    }
}

impl Clone for DilatedGrids {
    fn clone(&self) -> DilatedGrids {
        let recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        DilatedGrids {
            recent: Mutex::new(recent.clone()),
        }
    }
}

impl std::fmt::Debug for DilatedGrids {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        f.debug_struct("DilatedGrids")
            .field("kept", &recent.len())
            .finish()
    }
}
