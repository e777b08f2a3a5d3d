//! Pose refinement: learned per-frame corrections of the training fits (global
//! orientation, body and hand joints, jaw, expression, translation), because fits from
//! monocular video are noisy and the field would otherwise blur a misfit limb into the
//! canonical space.
//!
//! Each training frame owns a correction (zero at the start, [`layout`]). The step that
//! draws a frame differentiates its loss through the correction ([`chain`]) and moves it
//! with its own Adam at `--pose-lr` (`--pose-lr-jitter` for fits that jitter); then two
//! quadratic penalties take a plain (proximal) step: toward zero (`--pose-prior`, the fraction of the correction removed per visit,
//! plus up to `CLEAN_FIT_TRUST` for fits that do not jitter)
//! and toward the neighbouring frames' corrected poses (`--pose-smooth`, the fraction of
//! the way to their mean per visit, scaled by how jittery the subject's fits are:
//! `jitter_gains`; neighbours are the same subject's training frames next in time).
//! Corrections learn only after `--pose-warmup` steps, once the field
//! renders something worth matching. The per-frame sampler and conditions are rebuilt
//! from the corrected pose whenever a frame's correction moved, so the capsule intervals
//! follow the refined body; the occupancy grid lives in canonical space and needs nothing.

pub mod chain;
mod export;
mod options;
#[cfg(test)]
mod tests;

use talkin_avatar::refined::{RefinerState, layout};
use talkin_data::dataset::Dataset;
use talkin_human::body::FrameParams;

pub use export::{ExportSummary, export_poses};
pub use options::{RefineMode, RefineOptions};

/// Adam's moment decays and epsilon for the corrections.
const BETA_1: f64 = 0.9;
const BETA_2: f64 = 0.999;
const EPSILON: f64 = 1e-8;

/// A run's pose refinement.
#[derive(Clone, Debug)]
pub struct PoseRefiner {
    pub opts: RefineOptions,
    pub state: RefinerState,
    /// Per slot: the fit, flattened ([`layout::flatten`]).
    fits: Vec<[f64; layout::DIM]>,
    /// Per slot: the slots of its neighbours in time (same subject).
    neighbours: Vec<Vec<usize>>,
    /// Per slot and correction group ([`layout::GROUPS`]): how jittery its subject's fits
    /// are, 0 to 1 ([`jitter_gains`]). It sets Adam's rate (from `--pose-lr` to
    /// `--pose-lr-jitter`), the share of the smoothness pull that applies, and the extra
    /// trust in fits that do not jitter.
    jitter_gain: Vec<[f64; layout::GROUPS.len()]>,
    /// Slot of each dataset frame.
    slot_of: std::collections::HashMap<usize, usize>,
}

/// Extra pull toward the fit, per visit, for fits that move as smoothly as a random walk
/// or more (scaled down to 0 for fits that jitter like white noise, as the smoothness pull
/// is scaled up): fits without jitter are trusted. With Adam at 1e-3 from step 500 and no
/// such pull, clean fits drifted 4.3 mm a joint and test_same lost 0.59 dB (4-minute runs
/// on the default scene); the pull bounds a correction held by a steady gradient to
/// about 4 x the learning rate.
const CLEAN_FIT_TRUST: f64 = 0.25;

/// Two training frames further apart than this many times the subject's median spacing
/// are not neighbours (a cut between clips).
const MAX_GAP_FACTOR: f64 = 3.0;

/// Two training frames further apart than this (seconds) are not neighbours, however
/// evenly spaced: a body moves too far in half a second for the difference of two poses
/// to be a fitter's jitter. Frames sampled 2 s apart (ten spread over a ZJU-MoCap clip)
/// read as white jitter to the smoothness pull, which then averaged every pose toward
/// its neighbours' and set the person box back from 25.66 to 21.83 dB on those frames.
pub const MAX_NEIGHBOUR_GAP_S: f64 = 0.5;

impl PoseRefiner {
    /// Zero corrections for `frames` of `dataset`.
    pub fn new(dataset: &Dataset, frames: &[usize], opts: RefineOptions) -> PoseRefiner {
        let n = frames.len();
        let zeros = || vec![vec![0.0f32; layout::DIM]; n];
        let state = RefinerState {
            frames: frames.to_vec(),
            delta: zeros(),
            m: zeros(),
            v: zeros(),
            t: vec![0; n],
        };
        PoseRefiner::from_state(dataset, state, opts)
    }

    /// Zero corrections for `frames` of `dataset` that trust no fit: every group learns at
    /// `--pose-lr-jitter` and none is pulled toward its fit beyond `--pose-prior` (a
    /// test-time fit of held-out frames, [`crate::fit_held_out_poses`]).
    pub fn untrusting(dataset: &Dataset, frames: &[usize], opts: RefineOptions) -> PoseRefiner {
        let mut r = PoseRefiner::new(dataset, frames, opts);
        r.jitter_gain = vec![[1.0; layout::GROUPS.len()]; frames.len()];
        r
    }

    /// The refiner a checkpoint recorded (its frames must be `dataset`'s).
    pub fn from_state(dataset: &Dataset, state: RefinerState, opts: RefineOptions) -> Self {
        let frames = &state.frames;
        let fits: Vec<[f64; layout::DIM]> = frames
            .iter()
            .map(|&i| layout::flatten(&dataset.frames[i].params))
            .collect();
        let slot_of = frames.iter().enumerate().map(|(s, &i)| (i, s)).collect();
        let neighbours = neighbours(dataset, frames);
        PoseRefiner {
            jitter_gain: jitter_gains(dataset, frames, &fits, &neighbours),
            neighbours,
            opts,
            state,
            fits,
            slot_of,
        }
    }

    /// Whether the corrections learn at step `step` (0-based: the step being taken).
    pub fn learning_at(&self, step: usize) -> bool {
        step >= self.opts.pose_warmup
    }

    /// The correction of dataset frame `i` (`None`: not a training frame).
    pub fn delta_of(&self, i: usize) -> Option<&[f32]> {
        self.slot_of
            .get(&i)
            .map(|&s| self.state.delta[s].as_slice())
    }

    /// Dataset frame `i`'s fit with its correction (the fit itself if it has none).
    pub fn params_of(&self, dataset: &Dataset, i: usize) -> FrameParams {
        let fit = &dataset.frames[i].params;
        match self.delta_of(i) {
            Some(d) => layout::corrected(fit, d),
            None => fit.clone(),
        }
    }

    /// One visit of dataset frame `i`: Adam on `grad` (the loss's gradient w.r.t. its
    /// correction; `None` before the warm-up ends), then the proximal steps of the prior
    /// and the smoothness penalty, which need no field and act from the first step. A
    /// gradient that is not finite leaves the correction as it was.
    pub fn update(&mut self, i: usize, grad: Option<&[f64; layout::DIM]>) {
        let Some(&s) = self.slot_of.get(&i) else {
            return;
        };
        if grad.is_some_and(|g| !g.iter().all(|v| v.is_finite())) {
            return;
        }
        let st = &mut self.state;
        let mut next: [f64; layout::DIM] = std::array::from_fn(|k| st.delta[s][k] as f64);
        if let Some(grad) = grad {
            st.t[s] += 1;
            let t = st.t[s] as i32;
            let (c1, c2) = (1.0 - BETA_1.powi(t), 1.0 - BETA_2.powi(t));
            for (g, (_, range, scale)) in layout::GROUPS.into_iter().enumerate() {
                let gain = self.jitter_gain[s][g];
                let lr = self.opts.pose_lr + (self.opts.pose_lr_jitter - self.opts.pose_lr) * gain;
                for k in range {
                    let m = BETA_1 * st.m[s][k] as f64 + (1.0 - BETA_1) * grad[k];
                    let v = BETA_2 * st.v[s][k] as f64 + (1.0 - BETA_2) * grad[k] * grad[k];
                    st.m[s][k] = m as f32;
                    st.v[s][k] = v as f32;
                    next[k] -= lr * scale * (m / c1) / ((v / c2).sqrt() + EPSILON);
                }
            }
        }
        // Proximal steps: toward the fit (harder for fits that look clean), then toward
        // the neighbours' corrected poses (harder for fits that jitter).
        for (g, (_, range, _)) in layout::GROUPS.into_iter().enumerate() {
            let trust = CLEAN_FIT_TRUST * (1.0 - self.jitter_gain[s][g]);
            let keep = 1.0 - (self.opts.pose_prior + trust).min(1.0);
            range.for_each(|k| next[k] *= keep);
        }
        let nb = &self.neighbours[s];
        if !nb.is_empty() && self.opts.pose_smooth > 0.0 {
            for (g, (_, range, _)) in layout::GROUPS.into_iter().enumerate() {
                let pull = self.opts.pose_smooth * self.jitter_gain[s][g];
                if pull == 0.0 {
                    continue;
                }
                for k in range {
                    let here = self.fits[s][k] + next[k];
                    let mean = nb
                        .iter()
                        .map(|&o| self.fits[o][k] + st.delta[o][k] as f64)
                        .sum::<f64>()
                        / nb.len() as f64;
                    next[k] += pull * (mean - here);
                }
            }
        }
        for k in 0..layout::DIM {
            st.delta[s][k] = next[k] as f32;
        }
    }
}

/// Per slot and correction group, the share of the smoothness pull that applies: how
/// jittery the subject's fits of that group are. The ratio `q` of the power of the fits'
/// second differences in time to that of their first differences is 3 for white jitter
/// (each pose independent of the last), 2 for a random walk and near 0 for smooth
/// motion; the gain is `clamp(q - 2, 0, 1)`: fits rougher than a random walk are taken as
/// jitter and smoothed, motion at least as smooth is left to the images. On the default
/// scene the clean fits give q = 0.3 (body and hands) and 1.6-2.1 (the talking jaw), and
/// 6 degrees of noise 2.8-2.9 (see docs/design.md, pose refinement).
fn jitter_gains(
    dataset: &Dataset,
    frames: &[usize],
    fits: &[[f64; layout::DIM]],
    neighbours: &[Vec<usize>],
) -> Vec<[f64; layout::GROUPS.len()]> {
    let n_groups = layout::GROUPS.len();
    let mut out = vec![[0.0; layout::GROUPS.len()]; frames.len()];
    let mut subjects: Vec<usize> = frames.iter().map(|&i| dataset.frames[i].subject).collect();
    subjects.sort_unstable();
    subjects.dedup();
    for subject in subjects {
        let slots: Vec<usize> = (0..frames.len())
            .filter(|&s| dataset.frames[frames[s]].subject == subject)
            .collect();
        let (mut p1, mut p2) = (vec![0.0f64; n_groups], vec![0.0f64; n_groups]);
        for &s in &slots {
            // Each neighbour pair once (first differences), each frame with two
            // neighbours as a middle (second differences).
            for (g, (_, range, _)) in layout::GROUPS.into_iter().enumerate() {
                for &o in neighbours[s].iter().filter(|&&o| o > s) {
                    p1[g] += range
                        .clone()
                        .map(|k| (fits[o][k] - fits[s][k]).powi(2))
                        .sum::<f64>();
                }
                if let [a, b] = neighbours[s][..] {
                    p2[g] += range
                        .map(|k| (fits[a][k] - 2.0 * fits[s][k] + fits[b][k]).powi(2))
                        .sum::<f64>();
                }
            }
        }
        let gains: [f64; layout::GROUPS.len()] = std::array::from_fn(|g| {
            if p1[g] > 1e-18 {
                (p2[g] / p1[g] - 2.0).clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
        for &s in &slots {
            out[s] = gains;
        }
    }
    out
}

/// Per slot, the slots of the same subject's training frames just before and after it
/// in time, unless further than [`MAX_GAP_FACTOR`] times that subject's median spacing
/// or than [`MAX_NEIGHBOUR_GAP_S`].
fn neighbours(dataset: &Dataset, frames: &[usize]) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); frames.len()];
    let mut subjects: Vec<usize> = frames.iter().map(|&i| dataset.frames[i].subject).collect();
    subjects.sort_unstable();
    subjects.dedup();
    for subject in subjects {
        let mut slots: Vec<usize> = (0..frames.len())
            .filter(|&s| dataset.frames[frames[s]].subject == subject)
            .collect();
        let time = |s: usize| dataset.frames[frames[s]].time;
        slots.sort_by(|&a, &b| time(a).total_cmp(&time(b)).then(a.cmp(&b)));
        let mut gaps: Vec<f64> = slots.windows(2).map(|w| time(w[1]) - time(w[0])).collect();
        if gaps.is_empty() {
            continue;
        }
        gaps.sort_by(f64::total_cmp);
        let limit = (MAX_GAP_FACTOR * gaps[gaps.len() / 2]).min(MAX_NEIGHBOUR_GAP_S);
        for w in slots.windows(2) {
            let gap = time(w[1]) - time(w[0]);
            if gap <= limit && gap > 0.0 {
                out[w[0]].push(w[1]);
                out[w[1]].push(w[0]);
            }
        }
    }
    out
}
