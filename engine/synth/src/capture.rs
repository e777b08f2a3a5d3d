//! The capture-like scene: what a camera and a fitter give where the built-in scene is
//! clean, each flaw a setting of its own so that one can be changed at a time.
//!
//! - **The performance** of a one-camera capture such as ZJU-MoCap's: the person turns in
//!   place through a full circle over the clip while gesturing wide (punches, raised arms)
//!   and kicking now and then, seen whole (feet included) by one fixed camera.
//! - **Skin that bends** ([`CaptureConfig::smooth_skin_m`]): near every joint the surface
//!   follows a blend of the two bones' motions over a few centimetres, as skin and cloth
//!   do, instead of moving rigidly with the nearer bone (the renderer's `rest_point`).
//! - **Fits that are off** ([`CaptureConfig::fit_bias_deg`], `fit_bias_m`): the dataset's
//!   poses carry a smooth offset per joint and on the translation, varying over seconds as
//!   a fitter's errors do (a fit smoothed in time drifts, it does not jitter); the images
//!   are rendered from the true poses, which are written beside the dataset
//!   ([`TRUE_FITS_FILE`]) to measure a refinement against.
//! - **Masks only** ([`CaptureConfig::masks_only`]): no depth and no labels, as from a
//!   matting tool.
//!
//! Splits: every sixth frame of the clip is `test_same`; `test_ood` is a separate clip
//! (novel poses) with its own offsets.

use glam::DVec3;

use crate::talk::{Style, scene_rng, talking_clip};
use talkin_grids::SplitMix64;
use talkin_human::body::skeleton::joint::*;
use talkin_human::body::{FrameParams, axis_angle_from_rotation, rotation_from_axis_angle};

/// Frames a second of the capture clip (a 50 fps capture taken every 8th frame or so:
/// far enough apart that poses differ, near enough that the turn is followed).
pub const CAPTURE_FPS: f64 = 6.0;

/// The file beside `dataset.json` with the true poses when the fits are biased: the
/// layout of `talkin export-poses` (`{"frames": [{"params": {...}}, ...]}`, dataset order).
pub const TRUE_FITS_FILE: &str = "true_fits.json";

/// The flaws of the capture-like scene (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CaptureConfig {
    /// Width (metres) over which skin bends at a joint; 0: rigid, bone by bone.
    pub smooth_skin_m: f32,
    /// RMS offset of every joint's rotation in the fits (degrees); 0: exact fits.
    pub fit_bias_deg: f64,
    /// RMS offset of the fits' translation (metres).
    pub fit_bias_m: f64,
    /// Write masks only (no depth, no segmentation labels).
    pub masks_only: bool,
}

impl Default for CaptureConfig {
    /// Every flaw on at the levels of the measured scene (docs/design.md, "Real
    /// captures").
    fn default() -> Self {
        CaptureConfig {
            smooth_skin_m: 0.04,
            fit_bias_deg: 3.0,
            fit_bias_m: 0.01,
            masks_only: true,
        }
    }
}

impl CaptureConfig {
    /// Every flaw off: the capture's performance and framing over the clean scene.
    pub fn clean() -> Self {
        CaptureConfig {
            smooth_skin_m: 0.0,
            fit_bias_deg: 0.0,
            fit_bias_m: 0.0,
            masks_only: false,
        }
    }

    /// Whether the fits are biased.
    pub fn biased(&self) -> bool {
        self.fit_bias_deg > 0.0 || self.fit_bias_m > 0.0
    }
}

/// A smooth signal with unit RMS: three sinusoids of periods 2.5 s, 6 s and 15 s with
/// random amplitudes and phases.
struct Drift {
    parts: [(f64, f64, f64); 3],
    norm: f64,
}

impl Drift {
    fn new(rng: &mut SplitMix64) -> Drift {
        let parts = [2.5, 6.0, 15.0].map(|period| {
            (
                rng.uniform(-1.0, 1.0),
                std::f64::consts::TAU / period,
                rng.uniform(0.0, std::f64::consts::TAU),
            )
        });
        // The RMS over time of a sum of sinusoids: sqrt(sum a^2 / 2).
        let norm = (parts.iter().map(|p| p.0 * p.0).sum::<f64>() / 2.0)
            .sqrt()
            .max(1e-9);
        Drift { parts, norm }
    }

    fn at(&self, t: f64) -> f64 {
        self.parts
            .iter()
            .map(|(a, w, ph)| a * (w * t + ph).sin())
            .sum::<f64>()
            / self.norm
    }
}

/// A kick: one leg raised forward (or to the side) and back over `duration` seconds.
struct Kick {
    start: f64,
    duration: f64,
    side: usize,
    /// Hip flexion at the top (rad), its sideways share, knee bend at the top.
    lift: f64,
    sideways: f64,
    knee: f64,
}

/// The capture performance: `n` frames at [`CAPTURE_FPS`] (module docs). `wide`: larger
/// kicks and arm raises (the novel-pose split).
pub fn capture_clip(seed: u64, n: usize, wide: bool) -> Vec<FrameParams> {
    let duration = n as f64 / CAPTURE_FPS;
    // The arms, hands, head and face of a wide talking performance, slowed to the
    // capture's frame rate.
    let upper = talking_clip(
        seed,
        n,
        Style {
            tempo: 0.3,
            wide: true,
        },
    );
    let mut rng = scene_rng(seed ^ 0xC0A7_0000_0000_0001);
    let mut kicks = Vec::new();
    let mut t = rng.uniform(0.5, 1.5);
    while t < duration {
        let big = if wide { 1.4 } else { 1.0 };
        kicks.push(Kick {
            start: t,
            duration: rng.uniform(1.0, 1.8),
            side: (rng.next_f64() < 0.5) as usize,
            lift: rng.uniform(0.8, 1.3) * big,
            sideways: rng.uniform(0.0, 0.5),
            knee: rng.uniform(0.1, 0.9),
        });
        t += rng.uniform(2.0, 3.5);
    }
    let sway = Drift::new(&mut rng);
    let turn_start = rng.uniform(0.0, std::f64::consts::TAU);
    upper
        .into_iter()
        .enumerate()
        .map(|(i, mut p)| {
            let t = i as f64 / CAPTURE_FPS;
            // One full turn over the clip, at an uneven pace.
            let yaw = turn_start + std::f64::consts::TAU * t / duration + 0.25 * sway.at(t);
            let talk_orient = rotation_from_axis_angle(p.global_orient);
            p.global_orient =
                axis_angle_from_rotation(glam::DMat3::from_rotation_y(yaw) * talk_orient);
            // Knees a little soft; a kick raises one leg and bends its knee.
            for side in 0..2 {
                p.body_pose[LEFT_KNEE + side - 1] = DVec3::new(0.12, 0.0, 0.0);
            }
            for k in &kicks {
                let u = (t - k.start) / k.duration;
                if !(0.0..=1.0).contains(&u) {
                    continue;
                }
                let s = (std::f64::consts::PI * u).sin().powi(2);
                let sign = if k.side == 0 { 1.0 } else { -1.0 };
                // Hip: flexion is a rotation about -x (the thigh forward and up), a share
                // of it sideways about z.
                p.body_pose[LEFT_HIP + k.side - 1] = DVec3::new(
                    -k.lift * s * (1.0 - k.sideways),
                    0.0,
                    sign * k.lift * s * k.sideways,
                );
                p.body_pose[LEFT_KNEE + k.side - 1] = DVec3::new(0.12 + k.knee * s, 0.0, 0.0);
                // The torso leans back a little (a rotation about -x).
                p.body_pose[SPINE1 - 1].x -= 0.15 * s;
            }
            p
        })
        .collect()
}

/// `fits` (the true poses of a clip at `times` seconds) with smooth offsets: every body
/// joint and the global orientation turned by an RMS `deg` about a drifting axis, the
/// translation moved by an RMS `metres` (module docs). Seeded by `seed`.
pub fn biased_fits(
    fits: &[FrameParams],
    times: &[f64],
    deg: f64,
    metres: f64,
    seed: u64,
) -> Vec<FrameParams> {
    let mut rng = scene_rng(seed ^ 0xB1A5_0000_0000_0001);
    // Per joint (orientation and 21 body joints) and axis, then translation per axis.
    let drifts: Vec<Drift> = (0..22 * 3 + 3).map(|_| Drift::new(&mut rng)).collect();
    // An RMS angle `deg` over three axes: each axis carries deg / sqrt(3).
    let per_axis = deg.to_radians() / 3f64.sqrt();
    let per_axis_m = metres / 3f64.sqrt();
    fits.iter()
        .zip(times)
        .map(|(p, &t)| {
            let mut q = p.clone();
            let offset = |j: usize| {
                DVec3::new(
                    drifts[3 * j].at(t),
                    drifts[3 * j + 1].at(t),
                    drifts[3 * j + 2].at(t),
                ) * per_axis
            };
            let turn = |r: DVec3, o: DVec3| {
                axis_angle_from_rotation(rotation_from_axis_angle(r) * rotation_from_axis_angle(o))
            };
            q.global_orient = turn(q.global_orient, offset(0));
            for (j, r) in q.body_pose.iter_mut().enumerate() {
                *r = turn(*r, offset(j + 1));
            }
            q.transl +=
                DVec3::new(drifts[66].at(t), drifts[67].at(t), drifts[68].at(t)) * per_axis_m;
            q
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clip_turns_a_full_circle_and_kicks() {
        let clip = capture_clip(3, 60, false);
        assert_eq!(clip, capture_clip(3, 60, false));
        assert!(clip.iter().all(|p| p.is_finite()));
        // The body's forward direction sweeps every quadrant.
        let mut quadrants = [false; 4];
        for p in &clip {
            let f = rotation_from_axis_angle(p.global_orient) * DVec3::Z;
            let q = (f.z.atan2(f.x) + std::f64::consts::PI) / std::f64::consts::FRAC_PI_2;
            quadrants[(q as usize).min(3)] = true;
        }
        assert_eq!(quadrants, [true; 4]);
        // Some frame raises a thigh by 30 degrees or more.
        let lift = clip
            .iter()
            .flat_map(|p| [p.body_pose[LEFT_HIP - 1], p.body_pose[RIGHT_HIP - 1]])
            .map(|r| r.length())
            .fold(0.0, f64::max);
        assert!(lift > 30f64.to_radians(), "{lift}");
    }

    #[test]
    fn biased_fits_are_off_by_the_asked_rms_and_smooth() {
        let clip = capture_clip(1, 120, false);
        let times: Vec<f64> = (0..clip.len()).map(|i| i as f64 / CAPTURE_FPS).collect();
        let biased = biased_fits(&clip, &times, 3.0, 0.01, 9);
        let angle = |a: DVec3, b: DVec3| {
            let r = rotation_from_axis_angle(a).transpose() * rotation_from_axis_angle(b);
            axis_angle_from_rotation(r).length()
        };
        let mut sq = 0.0;
        let mut steps = 0.0;
        let mut n = 0.0;
        for (i, (p, q)) in clip.iter().zip(&biased).enumerate() {
            for j in 0..21 {
                let e = angle(p.body_pose[j], q.body_pose[j]);
                sq += e * e;
                n += 1.0;
                if i > 0 {
                    let (p0, q0) = (&clip[i - 1], &biased[i - 1]);
                    let d = angle(p0.body_pose[j], q0.body_pose[j]);
                    steps += (e - d).abs();
                }
            }
        }
        let rms = (sq / n).sqrt().to_degrees();
        // 20 s of three slow sinusoids per axis: near the asked RMS.
        assert!((rms - 3.0).abs() < 1.0, "{rms}");
        // Smooth: the error moves by a small fraction of itself between frames.
        let mean_step = (steps / n).to_degrees();
        assert!(mean_step < 0.5, "{mean_step}");
        // Unbiased settings give the fits back.
        let same = biased_fits(&clip, &times, 0.0, 0.0, 9);
        for (p, q) in clip.iter().zip(&same) {
            assert!((p.transl - q.transl).length() < 1e-12);
            assert!(angle(p.global_orient, q.global_orient) < 1e-9);
        }
    }
}
