//! How far each capsule must grow, and how deep its solid core reaches, decided by a
//! subject's training frames. Real clothes and hair stick out of any skeleton; the data,
//! not a constant, says by how much.
//!
//! - With ground-truth depth (synthetic data), every training pixel's true surface point
//!   is known: each capsule grows until it holds the surface points of its part nearest
//!   to it (per capsule: a skirt widens the thighs, not the neck), and its core is kept
//!   clear of every surface point.
//! - With masks only (real data), each part's capsules grow until every foreground ray of
//!   that part hits one (grids' ray-coverage fit), and cores follow the skeleton prior.
//!   The skinning prior weighs bones by them, but rays do not stop at them
//!   ([`CapsuleShells::stopping_cores`]): nothing says how deep the surface lies, and a
//!   fit nearer the camera than the person puts a core in front of the visible surface.

use glam::Vec3;
use rayon::prelude::*;
use talkin_grids::intersect::distance_to_segment;
use talkin_grids::{
    Capsule, GridError, LabelledRay, MarginFitOpts, MarginReport, Part, PartMargins, RayCoverage,
    count_covered, fit_part_margins,
};

use super::frame::{FrameScene, foreground_rays};
use talkin_data::dataset::{Dataset, DatasetError, Split};
use talkin_human::body::{PosedSkeleton, canonical_params};

/// Added to every data-fitted capsule margin, metres: room for poses the training frames
/// did not show (cloth swings further in a wider gesture). Measured on the default
/// scene's held-out splits: body, arm and head surfaces stay inside the training need
/// plus 8 mm.
pub const MARGIN_SAFETY_M: f32 = 0.008;
/// The same for hand capsules: finger poses the training frames never showed put hand
/// surfaces up to 17.6 mm past the training need on the default scene's held-out
/// splits (wider curls, spread fingers), so hands get 20 mm.
pub const HAND_MARGIN_SAFETY_M: f32 = 0.02;
/// Without surface points, a core is this fraction of the bare capsule radius (the
/// inner part of a limb is flesh on any human): the skinning prior's, never a place rays
/// stop ([`CapsuleShells::stopping_cores`]).
pub const CORE_PRIOR: f32 = 0.6;
/// Taken off every depth-fitted core radius, metres, after [`CORE_SAFETY`]: held-out
/// camera-to-surface segments came up to 3.4 mm inside the training-fitted cores on the
/// default scene (a wider pose brings another limb's surface closer to an axis).
pub const CORE_MARGIN_M: f32 = 0.005;
/// With surface points, a core keeps this fraction of the closest distance at which any
/// training surface point came to the capsule's axis: nothing seen was ever inside it.
pub const CORE_SAFETY: f32 = 0.85;
/// Candidate core lengths: the core's segment is the capsule's shrunk by this fraction
/// at each end (joints are where other limbs' surfaces come close to an axis), and the
/// candidate with the largest volume wins.
pub const CORE_SHRINK: [f32; 3] = [0.0, 0.15, 0.3];

/// Per capsule (in `shell_capsules` order): how far it grows and the radius of its
/// solid core.
#[derive(Clone, Debug, PartialEq)]
pub struct CapsuleShells {
    pub margin: Vec<f32>,
    pub core: Vec<f32>,
    /// Fraction of the segment cut from each end of the core.
    pub core_shrink: Vec<f32>,
    /// Whether the shells came from ground-truth surface points (else from ray coverage).
    pub from_depth: bool,
}

impl CapsuleShells {
    /// The capsules grown by their margins.
    pub fn inflate(&self, bare: &[Capsule]) -> Vec<Capsule> {
        bare.iter()
            .zip(&self.margin)
            .map(|(c, m)| Capsule {
                radius: c.radius + m,
                ..*c
            })
            .collect()
    }

    /// The cores the samplers stop rays at: the solid cores where depth proved them, none
    /// without depth. A fit's error toward the camera is invisible to the masks, and on
    /// ZJU-MoCap 387 a prior core (0.6 of the bare radius) of a fit nearer the camera lay
    /// in front of an outstretched arm: the rays stopped there and the arm rendered as a
    /// black band (docs/results.md, "Frames that disagree").
    pub fn stopping_cores(&self, bare: &[Capsule]) -> Vec<Capsule> {
        if self.from_depth {
            self.cores(bare)
        } else {
            Vec::new()
        }
    }

    /// The solid cores (capsules with their core radius; zero-radius cores dropped): the
    /// skinning prior's geometry, and with depth where rays stop.
    pub fn cores(&self, bare: &[Capsule]) -> Vec<Capsule> {
        bare.iter()
            .zip(self.core.iter().zip(&self.core_shrink))
            .filter(|(_, (r, _))| **r > 0.0)
            .map(|(c, (r, f))| {
                let axis = c.b - c.a;
                Capsule {
                    a: c.a + axis * *f,
                    b: c.b - axis * *f,
                    radius: *r,
                    ..*c
                }
            })
            .collect()
    }
}

/// The margins of one subject and how well they cover its training masks.
#[derive(Clone, Debug)]
pub struct SubjectMargins {
    /// Per-part margins from ray coverage (what masks alone decide).
    pub part_margins: PartMargins,
    pub shells: CapsuleShells,
    /// Per part (in `Part::ALL` order): (foreground rays, rays hitting a bare capsule of
    /// their part, rays hitting a grown capsule of their part), over the training frames.
    pub coverage: [(usize, usize, usize); 4],
    /// Training foreground rays that miss every grown capsule of any part.
    pub uncovered_any: usize,
}

/// What one training frame says about the capsules.
struct FrameFit {
    ray_fit: MarginReport,
    /// Per capsule: the largest (distance - radius) of its part's surface points that
    /// are nearest to it, and per core candidate the smallest distance of any surface
    /// point to the shrunk segment.
    need: Vec<f32>,
    closest: Vec<[f32; 3]>,
    has_depth: bool,
}

/// Fits the subject's shells over its `train` frames.
pub fn fit_subject_margins(
    dataset: &Dataset,
    subject: usize,
    opts: &MarginFitOpts,
) -> Result<SubjectMargins, DatasetError> {
    let skeleton = &dataset.subjects[subject].skeleton;
    let canonical = skeleton.pose(&canonical_params());
    let frames: Vec<usize> = dataset
        .split_indices(Split::Train)
        .into_iter()
        .filter(|&i| dataset.frames[i].subject == subject)
        .collect();
    let fits: Vec<FrameFit> = frames
        .par_iter()
        .map(|&i| fit_frame(dataset, &canonical, i, opts))
        .collect::<Result<_, _>>()?;
    let pooled = pool_fits(&fits);
    let from_depth = !fits.is_empty() && fits.iter().all(|f| f.has_depth);
    let bare = super::frame::shell_capsules(skeleton, &canonical);
    let margin = capsule_margins(&bare, &pooled, from_depth);
    let cores = capsule_cores(&bare, &pooled.closest, &margin, from_depth);
    let shells = CapsuleShells {
        margin,
        core: cores.iter().map(|c| c.0).collect(),
        core_shrink: cores.iter().map(|c| c.1).collect(),
        from_depth,
    };
    let mut coverage = pooled.coverage;
    let uncovered_any = coverage_after(dataset, &canonical, &frames, &shells, &mut coverage)?;
    Ok(SubjectMargins {
        part_margins: pooled.part_margins,
        shells,
        coverage,
        uncovered_any,
    })
}

/// The frames' fits pooled: each part's widest margin, each capsule's largest need and
/// closest surface per core candidate, and each part's rays and rays covered before.
struct PooledFits {
    part_margins: PartMargins,
    need: Vec<f32>,
    closest: Vec<[f32; 3]>,
    coverage: [(usize, usize, usize); 4],
}

fn pool_fits(fits: &[FrameFit]) -> PooledFits {
    let n_caps = fits.first().map_or(0, |f| f.need.len());
    let mut part_margins = PartMargins::ZERO;
    let mut need = vec![f32::NEG_INFINITY; n_caps];
    let mut closest = vec![[f32::INFINITY; 3]; n_caps];
    let mut coverage = [(0, 0, 0); 4];
    for f in fits {
        for (k, part) in Part::ALL.into_iter().enumerate() {
            part_margins.set(
                part,
                part_margins.get(part).max(f.ray_fit.margins.get(part)),
            );
            coverage[k].0 += f.ray_fit.parts[k].rays;
            coverage[k].1 += f.ray_fit.parts[k].covered_before;
        }
        for c in 0..n_caps {
            need[c] = need[c].max(f.need[c]);
            for k in 0..CORE_SHRINK.len() {
                closest[c][k] = closest[c][k].min(f.closest[c][k]);
            }
        }
    }
    PooledFits {
        part_margins,
        need,
        closest,
        coverage,
    }
}

/// Each capsule's margin: from depth, the largest need over the frames plus a safety;
/// from masks, its part's margin.
fn capsule_margins(bare: &[Capsule], pooled: &PooledFits, from_depth: bool) -> Vec<f32> {
    (0..pooled.need.len())
        .map(|c| {
            if from_depth {
                let safety = match bare[c].part {
                    Part::Hands => HAND_MARGIN_SAFETY_M,
                    _ => MARGIN_SAFETY_M,
                };
                pooled.need[c].max(0.0) + safety
            } else {
                pooled.part_margins.get(bare[c].part)
            }
        })
        .collect()
}

/// Per capsule: (core radius, shrink) of the largest-volume candidate; without depth the
/// generic prior.
fn capsule_cores(
    bare: &[Capsule],
    closest: &[[f32; 3]],
    margin: &[f32],
    from_depth: bool,
) -> Vec<(f32, f32)> {
    (0..closest.len())
        .map(|c| {
            if !from_depth {
                return (CORE_PRIOR * bare[c].radius, 0.0, 0.0);
            }
            let length = (bare[c].b - bare[c].a).length();
            CORE_SHRINK
                .iter()
                .enumerate()
                .map(|(k, &f)| {
                    // Never past the grown capsule: a capsule no training pixel saw (a shin
                    // below the frame) has no surface near it, yet no proof of solidity.
                    let grown = bare[c].radius + margin[c];
                    let r = ((CORE_SAFETY * closest[c][k]).min(CORE_SAFETY * grown)
                        - CORE_MARGIN_M)
                        .max(0.0);
                    (r, f, r * r * (length * (1.0 - 2.0 * f) + 4.0 / 3.0 * r))
                })
                .fold((0.0f32, 0.0f32, -1.0f32), |best, cand| {
                    if cand.2 > best.2 { cand } else { best }
                })
        })
        .map(|(r, f, _)| (r, f))
        .collect()
}

/// Coverage after: every training frame re-checked with the grown capsules; adds each
/// part's covered rays to `coverage` and returns the rays no capsule covers.
fn coverage_after(
    dataset: &Dataset,
    canonical: &PosedSkeleton,
    frames: &[usize],
    shells: &CapsuleShells,
    coverage: &mut [(usize, usize, usize); 4],
) -> Result<usize, DatasetError> {
    let checks: Vec<RayCoverage> = frames
        .par_iter()
        .map(|&i| {
            let (scene, rays, _) = frame_scene_and_rays(dataset, canonical, i)?;
            count_covered(&shells.inflate(&scene.capsules), &rays)
                .map_err(|e| grid_error(dataset, i, e))
        })
        .collect::<Result<_, _>>()?;
    let mut uncovered_any = 0;
    for check in &checks {
        for k in 0..4 {
            coverage[k].2 += check.own_part[k];
        }
        uncovered_any += check.rays - check.any_part;
    }
    Ok(uncovered_any)
}

fn fit_frame(
    dataset: &Dataset,
    canonical: &PosedSkeleton,
    i: usize,
    opts: &MarginFitOpts,
) -> Result<FrameFit, DatasetError> {
    let (scene, rays, pixels) = frame_scene_and_rays(dataset, canonical, i)?;
    let ray_fit =
        fit_part_margins(&scene.capsules, &rays, opts).map_err(|e| grid_error(dataset, i, e))?;
    let caps = &scene.capsules;
    let mut need = vec![f32::NEG_INFINITY; caps.len()];
    let mut closest = vec![[f32::INFINITY; 3]; caps.len()];
    let depth = dataset.depth(i)?;
    // Each axis's midpoint and half length: no point of a segment comes nearer the axis
    // than its distance to the midpoint less the half length.
    let middles: Vec<(Vec3, f32)> = caps
        .iter()
        .map(|c| (0.5 * (c.a + c.b), 0.5 * c.a.distance(c.b)))
        .collect();
    if let Some(depth) = &depth {
        let forward = dataset.frames[i].camera.forward_in_world().as_vec3();
        for (l, &px) in rays.iter().zip(&pixels) {
            let Some(z) = depth[px as usize] else {
                continue;
            };
            let p: Vec3 = l.ray.at(z / l.ray.direction.dot(forward));
            let mut nearest = (f32::INFINITY, usize::MAX);
            for (c, cap) in caps.iter().enumerate() {
                let axis = cap.b - cap.a;
                // The ray is free space up to its surface point: a core may not reach
                // the segment camera -> surface (this also keeps the surface point out).
                // A segment that cannot come nearer than every core's nearest so far
                // changes none of them: the exact distances are skipped.
                let (middle, half) = middles[c];
                let farthest = closest[c].iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
                let at_least = segment_distance(middle, middle, l.ray.origin, p) - half;
                if at_least - BOUND_SLACK_M <= farthest {
                    for (k, f) in CORE_SHRINK.iter().enumerate() {
                        let free =
                            segment_distance(l.ray.origin, p, cap.a + axis * *f, cap.b - axis * *f);
                        closest[c][k] = closest[c][k].min(free);
                    }
                }
                if cap.part.label() == l.label {
                    let d = distance_to_segment(p, cap.a, cap.b) - cap.radius;
                    if d < nearest.0 {
                        nearest = (d, c);
                    }
                }
            }
            if nearest.1 != usize::MAX {
                need[nearest.1] = need[nearest.1].max(nearest.0);
            }
        }
    }
    Ok(FrameFit {
        ray_fit,
        need,
        closest,
        has_depth: depth.is_some(),
    })
}

/// How far (metres) a lower bound must clear the nearest distance so far before the
/// exact distances are skipped: far above the rounding of either.
const BOUND_SLACK_M: f32 = 1e-4;

/// Distance between segments `p0-p1` and `q0-q1` (closest points, clamped; robust to
/// zero-length segments).
pub fn segment_distance(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> f32 {
    let (d1, d2, r) = (p1 - p0, q1 - q0, p0 - q0);
    let (a, e, f) = (d1.dot(d1), d2.dot(d2), d2.dot(r));
    let eps = 1e-12;
    let (s, t) = if a <= eps && e <= eps {
        (0.0, 0.0)
    } else if a <= eps {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(r);
        if e <= eps {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let mut s = if denom > eps {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    ((p0 + d1 * s) - (q0 + d2 * t)).length()
}

/// A frame's posed scene, labelled foreground rays and their pixel indices.
pub(crate) fn frame_scene_and_rays(
    dataset: &Dataset,
    canonical: &PosedSkeleton,
    i: usize,
) -> Result<(FrameScene, Vec<LabelledRay>, Vec<u32>), DatasetError> {
    let frame = &dataset.frames[i];
    let images = dataset.images(i)?;
    let scene = FrameScene::new(
        &dataset.subjects[frame.subject].skeleton,
        canonical,
        &frame.params,
    );
    let (rays, pixels) =
        foreground_rays(&frame.camera, &images).map_err(|e| grid_error(dataset, i, e))?;
    Ok((scene, rays, pixels))
}

/// A geometry error about frame `i` (non-finite camera or pose reaching the grids).
pub fn grid_error(dataset: &Dataset, i: usize, e: GridError) -> DatasetError {
    DatasetError::Invalid {
        file: dataset.root.join(talkin_data::dataset::INDEX_FILE),
        field: format!("frames[{i}]"),
        problem: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: the minimum over a fine grid of parameter pairs.
    fn reference(p0: Vec3, p1: Vec3, q0: Vec3, q1: Vec3) -> f32 {
        let n = 400;
        let mut best = f32::INFINITY;
        for i in 0..=n {
            let a = p0 + (p1 - p0) * (i as f32 / n as f32);
            best = best.min(distance_to_segment(a, q0, q1));
        }
        best
    }

    #[test]
    fn segment_distance_matches_brute_force() {
        let v = Vec3::new;
        let cases = [
            (
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(0.5, 1.0, -1.0),
                v(0.5, 1.0, 1.0),
            ),
            (
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(2.0, 0.5, 0.0),
                v(3.0, 0.5, 0.0),
            ),
            (
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(0.0, 0.2, 0.0),
                v(1.0, 0.2, 0.0),
            ),
            (
                v(0.3, 0.3, 0.3),
                v(0.3, 0.3, 0.3),
                v(0.0, 0.0, 0.0),
                v(0.0, 1.0, 0.0),
            ),
            (
                v(0.0, 0.0, 0.0),
                v(0.0, 0.0, 0.0),
                v(1.0, 1.0, 1.0),
                v(1.0, 1.0, 1.0),
            ),
            (
                v(-1.0, 2.0, 0.5),
                v(1.0, -2.0, 0.1),
                v(0.2, 0.1, -0.3),
                v(-0.4, 0.8, 0.9),
            ),
        ];
        for (p0, p1, q0, q1) in cases {
            let d = segment_distance(p0, p1, q0, q1);
            assert!(
                (d - reference(p0, p1, q0, q1)).abs() < 2e-3,
                "{p0} {p1} {q0} {q1}: {d}"
            );
        }
    }

    /// The bound the core fit skips by: no point of a segment comes nearer an axis, or
    /// any piece of it, than its distance to the axis's midpoint less half its length.
    #[test]
    fn the_midpoint_bound_never_exceeds_the_exact_distance() {
        let mut rng = talkin_grids::SplitMix64::new(11);
        let mut point =
            || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0 - Vec3::splat(2.0);
        let mut tight = 0;
        for _ in 0..20_000 {
            let (p0, p1, a, b) = (point(), point(), point(), point());
            let (middle, half) = (0.5 * (a + b), 0.5 * a.distance(b));
            let bound = segment_distance(middle, middle, p0, p1) - half;
            for f in CORE_SHRINK {
                let axis = b - a;
                let exact = segment_distance(p0, p1, a + axis * f, b - axis * f);
                assert!(
                    bound <= exact + 1e-5,
                    "{p0} {p1} {a} {b}: {bound} > {exact}"
                );
                tight += usize::from(f == 0.0 && exact - bound < 0.05);
            }
        }
        assert!(tight > 100, "{tight} near-tight cases");
    }
}
