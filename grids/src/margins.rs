//! Capsule margins decided by the data: clothes and hair stick out of any skeleton, so
//! each part's capsules grow until the training masks' foreground rays of that part hit
//! them.
//!
//! Instead of growing by doubling and bisection, the exact margin each ray needs is
//! computed (distance from the ray to the nearest capsule segment of its part, minus that
//! capsule's radius); a part's margin is then the `coverage_target` quantile of its rays'
//! needs. Same answer as a bisection with infinite steps, in one pass. The result is
//! checked by intersecting the rays with the inflated capsules, and the report says how
//! many rays each part covers before and after.

use std::fmt;
use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::intersect::{margin_to_hit, validate_capsules};
use crate::{Capsule, CapsuleBvh, GridError, Part, Ray};

/// A radius margin per part, metres, indexed by `part.label() - 1` (order of
/// [`Part::ALL`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartMargins(pub [f32; 4]);

impl PartMargins {
    pub const ZERO: PartMargins = PartMargins([0.0; 4]);

    pub const fn uniform(margin: f32) -> PartMargins {
        PartMargins([margin; 4])
    }

    pub const fn get(&self, part: Part) -> f32 {
        self.0[part as usize - 1]
    }

    pub fn set(&mut self, part: Part, margin: f32) {
        self.0[part as usize - 1] = margin;
    }

    /// The capsules with each radius grown by its part's margin.
    pub fn inflate(&self, capsules: &[Capsule]) -> Vec<Capsule> {
        capsules
            .iter()
            .map(|c| Capsule {
                radius: c.radius + self.get(c.part),
                ..*c
            })
            .collect()
    }
}

/// A foreground ray of a training image with the segmentation label of its pixel
/// (1..=4, see [`Part`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LabelledRay {
    pub ray: Ray,
    pub label: u8,
}

/// Options of [`fit_part_margins`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MarginFitOpts {
    /// Fraction of each part's rays that must hit a capsule of that part. 1.0 demands
    /// every foreground pixel; slightly less tolerates noisy real segmentations.
    pub coverage_target: f32,
    /// Largest margin any part may get, metres. Rays that would need more stay
    /// uncovered and are listed in the report.
    pub max_margin: f32,
}

impl Default for MarginFitOpts {
    fn default() -> Self {
        MarginFitOpts {
            coverage_target: 1.0,
            max_margin: 0.25,
        }
    }
}

/// The fit of one part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartFit {
    pub part: Part,
    /// Foreground rays labelled with this part.
    pub rays: usize,
    /// The margin chosen, metres.
    pub margin: f32,
    /// The largest margin any of its rays needs (infinite if the part has no capsule).
    pub largest_need: f32,
    /// Rays hitting a capsule of this part before / after inflation.
    pub covered_before: usize,
    pub covered_after: usize,
    /// Whether the margin stopped at `max_margin` short of the coverage target.
    pub capped: bool,
}

impl PartFit {
    /// Fraction covered before inflation (1 for a part without rays).
    pub fn coverage_before(&self) -> f32 {
        fraction(self.covered_before, self.rays)
    }

    /// Fraction covered after inflation (1 for a part without rays).
    pub fn coverage_after(&self) -> f32 {
        fraction(self.covered_after, self.rays)
    }
}

fn fraction(n: usize, of: usize) -> f32 {
    if of == 0 { 1.0 } else { n as f32 / of as f32 }
}

/// What [`fit_part_margins`] decided and how well it covers the rays.
#[derive(Clone, Debug, PartialEq)]
pub struct MarginReport {
    pub margins: PartMargins,
    /// One entry per part, in [`Part::ALL`] order.
    pub parts: [PartFit; 4],
    /// All foreground rays.
    pub rays: usize,
    /// Rays hitting any capsule (whatever its part) before / after inflation: what the
    /// sampler needs, since an arm pixel seen through a body capsule is still sampled.
    pub any_part_before: usize,
    pub any_part_after: usize,
    /// Indices of the rays that miss every inflated capsule of their own part.
    pub uncovered: Vec<u32>,
    /// Indices of the rays that miss every inflated capsule of any part.
    pub uncovered_any: Vec<u32>,
}

impl fmt::Display for MarginReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "part    rays   margin(m)  own-part coverage before -> after"
        )?;
        for p in &self.parts {
            writeln!(
                f,
                "{:<6} {:>6}   {:>8.4}   {:>6.2}% -> {:>6.2}%{}",
                p.part.name(),
                p.rays,
                p.margin,
                100.0 * p.coverage_before(),
                100.0 * p.coverage_after(),
                if p.capped { "  (capped)" } else { "" }
            )?;
        }
        write!(
            f,
            "any part: {:.2}% -> {:.2}% of {} rays; {} rays uncovered by their own part",
            100.0 * fraction(self.any_part_before, self.rays),
            100.0 * fraction(self.any_part_after, self.rays),
            self.rays,
            self.uncovered.len()
        )
    }
}

/// Fits one margin per part so that at least `coverage_target` of each part's rays hit
/// one of its inflated capsules, capped at `max_margin`. A part without rays keeps
/// margin 0. Fails on invalid rays or capsules and on labels outside 1..=4.
pub fn fit_part_margins(
    capsules: &[Capsule],
    rays: &[LabelledRay],
    opts: &MarginFitOpts,
) -> Result<MarginReport, GridError> {
    check_opts(opts)?;
    validate_capsules(capsules)?;
    validate_rays(rays)?;
    let needs: Vec<f32> = rays
        .par_iter()
        .map(|r| {
            capsules
                .iter()
                .filter(|c| c.part.label() == r.label)
                .map(|c| margin_to_hit(&r.ray, c))
                .fold(f32::INFINITY, f32::min)
        })
        .collect();

    let mut margins = PartMargins::ZERO;
    let mut capped = [false; 4];
    let mut largest_need = [0.0f32; 4];
    let mut counts = [0usize; 4];
    for (k, part) in Part::ALL.into_iter().enumerate() {
        let mut own: Vec<f32> = rays
            .iter()
            .zip(&needs)
            .filter(|(r, _)| r.label == part.label())
            .map(|(_, &n)| n)
            .collect();
        counts[k] = own.len();
        if own.is_empty() {
            continue;
        }
        own.sort_unstable_by(f32::total_cmp);
        largest_need[k] = *own.last().unwrap();
        let covered =
            ((opts.coverage_target as f64 * own.len() as f64).ceil() as usize).clamp(1, own.len());
        let need = own[covered - 1];
        // Slack so f32 rounding in the intersection test cannot undo the fit.
        let margin = need * (1.0 + 1e-5) + 1e-6;
        if margin > opts.max_margin {
            margins.0[k] = opts.max_margin;
            capped[k] = true;
        } else {
            margins.0[k] = margin;
        }
    }

    let covered_after = coverage(&margins.inflate(capsules), rays)?;
    let before = tally(rays, &coverage(capsules, rays)?);
    let after = tally(rays, &covered_after);
    let parts = std::array::from_fn(|k| PartFit {
        part: Part::ALL[k],
        rays: counts[k],
        margin: margins.0[k],
        largest_need: largest_need[k],
        covered_before: before.own_part[k],
        covered_after: after.own_part[k],
        capped: capped[k],
    });
    let uncovered = |any: bool| {
        covered_after
            .iter()
            .enumerate()
            .filter(|(_, c)| !if any { c.1 } else { c.0 })
            .map(|(i, _)| i as u32)
            .collect()
    };
    Ok(MarginReport {
        margins,
        parts,
        rays: rays.len(),
        any_part_before: before.any_part,
        any_part_after: after.any_part,
        uncovered: uncovered(false),
        uncovered_any: uncovered(true),
    })
}

/// How many rays capsules already grown cover: [`fit_part_margins`]'s check alone, without
/// the margins each ray needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RayCoverage {
    /// Rays hitting a capsule of their own part, in [`Part::ALL`] order.
    pub own_part: [usize; 4],
    /// Rays hitting any capsule.
    pub any_part: usize,
    /// All rays.
    pub rays: usize,
}

/// Counts the rays that hit a capsule of their own part and those that hit any, by real
/// intersection. Fails on invalid rays or capsules and on labels outside 1..=4, as
/// [`fit_part_margins`] does.
pub fn count_covered(capsules: &[Capsule], rays: &[LabelledRay]) -> Result<RayCoverage, GridError> {
    validate_capsules(capsules)?;
    validate_rays(rays)?;
    Ok(tally(rays, &coverage(capsules, rays)?))
}

/// [`coverage`]'s answers counted per part and in all.
fn tally(rays: &[LabelledRay], covered: &[(bool, bool)]) -> RayCoverage {
    let own_part = std::array::from_fn(|k| {
        let label = Part::ALL[k].label();
        rays.iter()
            .zip(covered)
            .filter(|(r, c)| r.label == label && c.0)
            .count()
    });
    RayCoverage {
        own_part,
        any_part: covered.iter().filter(|c| c.1).count(),
        rays: rays.len(),
    }
}

fn validate_rays(rays: &[LabelledRay]) -> Result<(), GridError> {
    for (index, r) in rays.iter().enumerate() {
        r.ray.validate(index)?;
        if Part::from_label(r.label).is_none() {
            return Err(GridError::BadLabel {
                index,
                label: r.label,
            });
        }
    }
    Ok(())
}

/// Per ray: (hits a capsule of its own part, hits any capsule), by real intersection.
fn coverage(capsules: &[Capsule], rays: &[LabelledRay]) -> Result<Vec<(bool, bool)>, GridError> {
    let bvh = CapsuleBvh::build(capsules)?;
    Ok(rays
        .par_iter()
        .map(|r| {
            // A hit of its own part answers both: the rest of the tree is not visited.
            let (mut own, mut any) = (false, false);
            let _ = bvh.try_for_each_hit(&r.ray, |h| {
                any = true;
                own = capsules[h.capsule as usize].part.label() == r.label;
                if own {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
            (own, any)
        })
        .collect())
}

fn check_opts(opts: &MarginFitOpts) -> Result<(), GridError> {
    if !(opts.coverage_target > 0.0 && opts.coverage_target <= 1.0) {
        return Err(GridError::BadOption {
            field: "coverage_target",
            value: opts.coverage_target,
            expected: "in (0, 1]",
        });
    }
    if !(opts.max_margin.is_finite() && opts.max_margin >= 0.0) {
        return Err(GridError::BadOption {
            field: "max_margin",
            value: opts.max_margin,
            expected: "finite and >= 0",
        });
    }
    Ok(())
}
