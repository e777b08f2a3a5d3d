//! Early ray termination without a network: rays stop shortly after they enter a
//! *core*, a capsule the data says is solid (the surface never comes closer to its axis).
//! Everything behind a core entry is behind the person's surface, so its samples would
//! render with zero transmittance; dropping them loses nothing the image can show.

use rayon::prelude::*;

use crate::bvh::CapsuleBvh;
use crate::error::GridError;
use crate::ray::{Ray, validate_rays};
use crate::samples::PackedSamples;

/// Per ray, the `t` where it first enters a core of `cores` (infinity if it never does).
pub fn first_core_entry(cores: &CapsuleBvh, rays: &[Ray]) -> Result<Vec<f32>, GridError> {
    validate_rays(rays)?;
    Ok(rays
        .par_iter()
        .map(|ray| {
            let mut first = f32::INFINITY;
            cores.for_each_hit(ray, |h| first = first.min(h.t_in));
            first
        })
        .collect())
}

/// Drops the samples that start more than `tail` metres past their ray's first core
/// entry. `tail` keeps a little room behind the entry (e.g. one step) so the sample that
/// holds the surface in front of the core is never the one cut.
pub fn truncate_behind_cores(
    mut samples: PackedSamples,
    rays: &[Ray],
    cores: &CapsuleBvh,
    tail: f32,
) -> Result<PackedSamples, GridError> {
    if rays.len() != samples.num_rays() {
        return Err(GridError::LengthMismatch {
            what: "rays for the samples",
            expected: samples.num_rays(),
            got: rays.len(),
        });
    }
    let entry = first_core_entry(cores, rays)?;
    let mut keep = vec![true; samples.num_samples()];
    for (i, t_core) in entry.iter().enumerate() {
        for s in samples.range(i) {
            keep[s] = samples.t_start[s] <= t_core + tail;
        }
    }
    samples.retain(&keep);
    Ok(samples)
}

/// Samples inside the capsules of `bvh`, stopping `tail` metres past each ray's first
/// entry into a core of `cores`: [`truncate_behind_cores`] without generating the samples
/// it would drop.
pub fn sample_in_front_of_cores(
    bvh: &CapsuleBvh,
    cores: &CapsuleBvh,
    rays: &[Ray],
    tail: f32,
    opts: &crate::AcceleratedOpts,
) -> Result<PackedSamples, GridError> {
    let stop: Vec<f32> = first_core_entry(cores, rays)?
        .into_iter()
        .map(|t| t + tail)
        .collect();
    crate::sampler_reference::sample_in_capsules_before(bvh, rays, Some(&stop), opts)
}

#[cfg(test)]
mod tests {
    use glam::{Vec3, vec3};

    use super::*;
    use crate::sampler_reference::{AcceleratedOpts, sample_in_capsules};
    use crate::{Capsule, Part};

    #[test]
    fn samples_stop_one_tail_behind_the_core() {
        let limb = Capsule {
            a: vec3(0.0, -1.0, 0.0),
            b: vec3(0.0, 1.0, 0.0),
            radius: 0.2,
            part: Part::Arms,
            bone: 18,
        };
        let core = Capsule {
            radius: 0.1,
            ..limb
        };
        let bvh = CapsuleBvh::build(&[limb]).unwrap();
        let cores = CapsuleBvh::build(&[core]).unwrap();
        let rays = [
            Ray::new(vec3(0.0, 0.0, -2.0), Vec3::Z, 0.0, f32::INFINITY).unwrap(),
            // Passes through the shell but misses the core: untouched.
            Ray::new(vec3(0.15, 0.0, -2.0), Vec3::Z, 0.0, f32::INFINITY).unwrap(),
        ];
        let opts = AcceleratedOpts {
            step: 0.01,
            jitter: false,
            seed: 0,
        };
        let all = sample_in_capsules(&bvh, &rays, &opts).unwrap();
        let cut = truncate_behind_cores(all.clone(), &rays, &cores, 0.01).unwrap();
        cut.check_layout().unwrap();
        // Ray 0 enters the limb at 1.8 and the core at 1.9.
        assert_eq!(all.range(0).len(), 40);
        assert!(cut.range(0).all(|s| cut.t_start[s] <= 1.91 + 1e-5));
        assert_eq!(cut.range(0).len(), 12);
        assert_eq!(cut.range(1).len(), all.range(1).len());
        assert!(
            first_core_entry(
                &cores,
                &[Ray {
                    origin: Vec3::NAN,
                    ..rays[0]
                }]
            )
            .is_err()
        );
        // Generating only what survives gives the same samples as generating and cutting,
        // up to the one bin that straddles the stop.
        let direct = sample_in_front_of_cores(&bvh, &cores, &rays, 0.01, &opts).unwrap();
        direct.check_layout().unwrap();
        assert!(direct.range(0).all(|s| direct.t_end[s] <= 1.91 + 1e-5));
        assert!((direct.range(0).len() as i64 - cut.range(0).len() as i64).abs() <= 1);
        assert_eq!(direct.range(1).len(), cut.range(1).len());
    }
}
