//! One frame's samplers, built once and used by training, rendering and the benchmark:
//! the dense baseline in the posed box and the accelerated pipeline (capsule intervals,
//! core truncation, occupancy-grid culling).

use glam::Vec3;
use talkin_grids::{
    AcceleratedOpts, CapsuleBvh, DenseOpts, GridError, OccupancyGrid, PackedSamples, Ray,
    SamplerKind, cull_with_grid, sample_dense, sample_in_front_of_cores,
};

use super::canonical::PosedToCanonical;
use super::frame::{FrameScene, capsule_bounds, median_dense_step};
use super::margins::CapsuleShells;

/// Dense samples per ray (the HumanNeRF baseline).
pub const DENSE_SAMPLES_PER_RAY: u32 = 128;

/// A posed frame's acceleration structures and sampling box.
pub struct FrameSampler {
    pub scene: FrameScene,
    /// BVH over the grown capsules, and over their solid cores.
    pub bvh: CapsuleBvh,
    pub core_bvh: CapsuleBvh,
    /// The dense sampler's box: the grown capsules plus 2 cm.
    pub box_min: Vec3,
    pub box_max: Vec3,
    /// The accelerated step (metres).
    pub step: f32,
}

impl FrameSampler {
    /// Builds the BVHs of `scene`'s capsules grown by `shells`. `step` is the accelerated
    /// step; `None` takes the dense step on the median of `step_rays` (the frame's
    /// foreground rays), so both samplers sample the body equally finely.
    pub fn new(
        scene: FrameScene,
        shells: &CapsuleShells,
        step_rays: &[Ray],
    ) -> Result<FrameSampler, GridError> {
        let inflated = shells.inflate(&scene.capsules);
        let bvh = CapsuleBvh::build(&inflated)?;
        let core_bvh = CapsuleBvh::build(&shells.cores(&scene.capsules))?;
        let (box_min, box_max) = capsule_bounds(&inflated, 0.02);
        let step = median_dense_step(step_rays, box_min, box_max, DENSE_SAMPLES_PER_RAY);
        Ok(FrameSampler {
            scene,
            bvh,
            core_bvh,
            box_min,
            box_max,
            step,
        })
    }

    /// Samples `rays` with `kind` (jittered with `seed`). The accelerated sampler culls
    /// with `grid`, the subject's canonical occupancy grid.
    pub fn sample(
        &self,
        kind: SamplerKind,
        rays: &[Ray],
        grid: &OccupancyGrid,
        seed: u64,
    ) -> Result<PackedSamples, GridError> {
        match kind {
            SamplerKind::Dense => sample_dense(
                rays,
                self.box_min,
                self.box_max,
                &DenseOpts {
                    samples_per_ray: DENSE_SAMPLES_PER_RAY,
                    jitter: true,
                    seed,
                },
            ),
            SamplerKind::Accelerated => {
                let samples = sample_in_front_of_cores(
                    &self.bvh,
                    &self.core_bvh,
                    rays,
                    self.step,
                    &self.accelerated_opts(seed),
                )?;
                let map = PosedToCanonical::new(&self.scene);
                cull_with_grid(samples, rays, grid, |p, b| map.map(p, b))
            }
        }
    }

    /// The accelerated sampler's options for `seed`.
    pub fn accelerated_opts(&self, seed: u64) -> AcceleratedOpts {
        AcceleratedOpts {
            step: self.step,
            jitter: true,
            seed,
        }
    }
}
