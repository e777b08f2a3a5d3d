//! Test-time temporal smoothing of a pose sequence (TalkinNeRF renders with a Gaussian
//! filter, window 5, sigma 1, over time): body pose, hand poses, jaw and eyes, expression,
//! translation and the camera.
//!
//! Rotations are smoothed as rotations: each frame's unit quaternion is sign-aligned to the
//! window's centre frame, the weighted sum is normalised and turned back into an
//! axis-angle vector. Averaging raw axis-angle vectors would be wrong wherever the same
//! rotation has two representations (near pi, `r` and `-r * (2pi - |r|) / |r|` are one
//! rotation, and their mean is close to the identity). Translations, expression
//! coefficients, camera centres and intrinsics are averaged linearly. At the ends of the
//! sequence the window is truncated and its weights renormalised.

use glam::{DMat3, DQuat, DVec3};

use crate::body::{FrameParams, N_JOINTS};
use crate::camera::{Camera, CameraError};

/// A Gaussian filter along time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoothing {
    /// Frames in the window (odd).
    pub window: usize,
    /// Standard deviation in frames.
    pub sigma: f64,
}

impl Smoothing {
    /// The paper's filter: window 5, sigma 1.
    pub const PAPER: Smoothing = Smoothing {
        window: 5,
        sigma: 1.0,
    };

    /// Weight of each window offset `-half..=half` (not normalised: edges renormalise).
    fn weights(&self) -> Result<Vec<f64>, SmoothError> {
        if self.window.is_multiple_of(2) || !(self.sigma.is_finite() && self.sigma > 0.0) {
            return Err(SmoothError::BadFilter {
                window: self.window,
                sigma: self.sigma,
            });
        }
        let half = (self.window / 2) as f64;
        Ok((0..self.window)
            .map(|i| {
                let d = i as f64 - half;
                (-d * d / (2.0 * self.sigma * self.sigma)).exp()
            })
            .collect())
    }
}

impl Default for Smoothing {
    fn default() -> Self {
        Smoothing::PAPER
    }
}

/// Why a sequence could not be smoothed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SmoothError {
    #[error(
        "smoothing: the window must be odd and sigma positive, found window {window}, sigma {sigma}"
    )]
    BadFilter { window: usize, sigma: f64 },
    #[error("frame {frame}: `{field}` is not finite: smoothing needs finite poses and cameras")]
    NonFinite { frame: usize, field: &'static str },
    #[error(
        "frame {frame}: the camera is {found:?} px but frame {other} in its smoothing window is \
         {expected:?} px: intrinsics of different image sizes cannot be averaged"
    )]
    CameraSize {
        frame: usize,
        other: usize,
        found: (u32, u32),
        expected: (u32, u32),
    },
    #[error("frame {frame}: the smoothed camera is invalid: {source}")]
    Camera {
        frame: usize,
        #[source]
        source: CameraError,
    },
}

/// The truncated window around frame `i` of `n`: (frame, weight) with weights summing to 1.
fn window(i: usize, n: usize, weights: &[f64]) -> Vec<(usize, f64)> {
    let half = weights.len() / 2;
    let taps: Vec<(usize, f64)> = (0..weights.len())
        .filter_map(|k| {
            let j = (i + k).checked_sub(half)?;
            (j < n).then_some((j, weights[k]))
        })
        .collect();
    let total: f64 = taps.iter().map(|t| t.1).sum();
    taps.into_iter().map(|(j, w)| (j, w / total)).collect()
}

/// Unit quaternion of an axis-angle vector (exact for any angle, including 0 and pi).
fn quat_from_axis_angle(r: DVec3) -> DQuat {
    DQuat::from_scaled_axis(r)
}

/// Axis-angle vector (angle in [0, pi]) of a unit quaternion; `atan2` keeps the angle
/// accurate near 0 and near pi.
fn axis_angle_from_quat(q: DQuat) -> DVec3 {
    let q = if q.w < 0.0 { -q } else { q };
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    if s == 0.0 {
        return DVec3::ZERO;
    }
    v * (2.0 * s.atan2(q.w) / s)
}

/// Weighted mean of unit quaternions, each sign-aligned to `centre` first.
fn mean_rotation(centre: DQuat, taps: impl Iterator<Item = (DQuat, f64)>) -> DQuat {
    let mut sum = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    for (q, w) in taps {
        let q = if q.dot(centre) < 0.0 { -q } else { q };
        sum += q * w;
    }
    // Every term lies in the centre's hemisphere and the centre's own weight is > 0, so
    // the sum's projection on the centre is positive and the sum is never zero.
    sum.normalize()
}

/// The named field of `p` that is not finite, if any.
fn non_finite_field(p: &FrameParams) -> Option<&'static str> {
    let all = |v: &[DVec3]| v.iter().all(|r| r.is_finite());
    [
        ("global_orient", p.global_orient.is_finite()),
        ("body_pose", all(&p.body_pose)),
        ("jaw_pose", p.jaw_pose.is_finite()),
        ("leye_pose", p.leye_pose.is_finite()),
        ("reye_pose", p.reye_pose.is_finite()),
        ("left_hand_pose", all(&p.left_hand_pose)),
        ("right_hand_pose", all(&p.right_hand_pose)),
        ("expression", p.expression.iter().all(|x| x.is_finite())),
        ("transl", p.transl.is_finite()),
    ]
    .into_iter()
    .find(|(_, ok)| !ok)
    .map(|(name, _)| name)
}

/// Smooths a sequence of frame parameters (in time order) with `filter`.
pub fn smooth_params(
    frames: &[FrameParams],
    filter: &Smoothing,
) -> Result<Vec<FrameParams>, SmoothError> {
    let weights = filter.weights()?;
    if let Some((frame, field)) = frames
        .iter()
        .enumerate()
        .find_map(|(i, p)| non_finite_field(p).map(|f| (i, f)))
    {
        return Err(SmoothError::NonFinite { frame, field });
    }
    let quats: Vec<[DQuat; N_JOINTS]> = frames
        .iter()
        .map(|p| p.local_rotations().map(quat_from_axis_angle))
        .collect();
    let n = frames.len();
    Ok((0..n)
        .map(|i| {
            let taps = window(i, n, &weights);
            let rotations: [DVec3; N_JOINTS] = std::array::from_fn(|j| {
                axis_angle_from_quat(mean_rotation(
                    quats[i][j],
                    taps.iter().map(|&(k, w)| (quats[k][j], w)),
                ))
            });
            let mut out = frames[i].clone();
            out.set_local_rotations(&rotations);
            out.transl = taps.iter().map(|&(k, w)| frames[k].transl * w).sum();
            out.expression = std::array::from_fn(|e| {
                taps.iter().map(|&(k, w)| frames[k].expression[e] * w).sum()
            });
            out
        })
        .collect())
}

/// Smooths a sequence of cameras (in time order): the rotation as a rotation, the camera
/// centre and the intrinsics linearly. Every camera in a window must have the same size.
pub fn smooth_cameras(cameras: &[Camera], filter: &Smoothing) -> Result<Vec<Camera>, SmoothError> {
    let weights = filter.weights()?;
    for (frame, c) in cameras.iter().enumerate() {
        if !c.intrinsics.is_finite() {
            return Err(SmoothError::NonFinite {
                frame,
                field: "camera.intrinsics",
            });
        }
        if !(c.camera_from_world.matrix3.is_finite() && c.camera_from_world.translation.is_finite())
        {
            return Err(SmoothError::NonFinite {
                frame,
                field: "camera.extrinsics",
            });
        }
    }
    let rotations: Vec<DQuat> = cameras
        .iter()
        .map(|c| DQuat::from_mat3(&c.camera_from_world.matrix3).normalize())
        .collect();
    let n = cameras.len();
    (0..n)
        .map(|i| {
            let taps = window(i, n, &weights);
            let size = |c: &Camera| (c.width, c.height);
            if let Some(&(other, _)) = taps
                .iter()
                .find(|&&(k, _)| size(&cameras[k]) != size(&cameras[i]))
            {
                return Err(SmoothError::CameraSize {
                    frame: i,
                    other,
                    found: size(&cameras[i]),
                    expected: size(&cameras[other]),
                });
            }
            let q = mean_rotation(rotations[i], taps.iter().map(|&(k, w)| (rotations[k], w)));
            let camera_from_world = DMat3::from_quat(q);
            let centre: DVec3 = taps
                .iter()
                .map(|&(k, w)| cameras[k].center_in_world() * w)
                .sum();
            let t = -(camera_from_world * centre);
            let mut k = [[0.0; 3]; 3];
            for &(j, w) in &taps {
                let kj = cameras[j].intrinsics_rows();
                for r in 0..2 {
                    for c in 0..3 {
                        k[r][c] += kj[r][c] * w;
                    }
                }
            }
            // The fixed entries stay exact: [0, 0, 1] and K[1][0] = 0.
            k[1][0] = 0.0;
            k[2] = [0.0, 0.0, 1.0];
            let mut e = [[0.0; 4]; 4];
            for r in 0..3 {
                let row = camera_from_world.row(r);
                e[r] = [row.x, row.y, row.z, t[r]];
            }
            e[3] = [0.0, 0.0, 0.0, 1.0];
            let c = &cameras[i];
            Camera::new(c.width, c.height, k, e)
                .map_err(|source| SmoothError::Camera { frame: i, source })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::rotation_from_axis_angle;
    use std::f64::consts::PI;

    fn max_rotation_diff(a: DVec3, b: DVec3) -> f64 {
        (rotation_from_axis_angle(a) - rotation_from_axis_angle(b))
            .to_cols_array()
            .iter()
            .fold(0.0, |m, x| m.max(x.abs()))
    }

    fn camera(eye: DVec3, focal: f64) -> Camera {
        Camera::look_at(64, 80, focal, eye, DVec3::new(0.0, 1.0, 0.0), DVec3::Y).unwrap()
    }

    fn posed(seed: f64) -> FrameParams {
        let mut p = FrameParams {
            global_orient: DVec3::new(0.1, 0.2 * seed, -0.3),
            ..Default::default()
        };
        for (i, r) in p.body_pose.iter_mut().enumerate() {
            *r = DVec3::new(0.05 * i as f64, -0.02 * seed, 0.3);
        }
        p.jaw_pose = DVec3::new(0.2, 0.0, 0.0);
        p.left_hand_pose[3] = DVec3::new(0.0, 0.0, 1.2);
        p.right_hand_pose[14] = DVec3::new(0.4, -0.5, 0.6);
        p.expression[2] = 0.7;
        p.transl = DVec3::new(0.1, -0.2, 0.3);
        p
    }

    #[test]
    fn constant_sequence_is_unchanged() {
        let p = posed(1.0);
        let frames = vec![p.clone(); 7];
        let out = smooth_params(&frames, &Smoothing::PAPER).unwrap();
        for q in &out {
            for (a, b) in q.local_rotations().iter().zip(p.local_rotations()) {
                assert!((*a - b).length() < 1e-12, "{a:?} vs {b:?}");
            }
            assert!((q.transl - p.transl).length() < 1e-12);
            assert!((q.expression[2] - 0.7).abs() < 1e-12);
        }
        let cam = camera(DVec3::new(0.2, 1.1, 3.0), 90.0);
        for c in smooth_cameras(&[cam; 6], &Smoothing::PAPER).unwrap() {
            assert!((c.center_in_world() - cam.center_in_world()).length() < 1e-12);
            assert!((c.intrinsics - cam.intrinsics).abs_diff_eq(DMat3::ZERO, 1e-12));
            assert!(
                c.camera_from_world
                    .matrix3
                    .abs_diff_eq(cam.camera_from_world.matrix3, 1e-12)
            );
        }
    }

    #[test]
    fn axis_angle_flips_near_pi_stay_the_same_rotation() {
        let axis = DVec3::new(1.0, -2.0, 0.5).normalize();
        // Exactly pi: r and -r are the same rotation. Just below pi: a * (pi - e) equals
        // -a * (pi + e). Raw averaging of either pair lands near the identity.
        for (r0, r1) in [
            (axis * PI, -axis * PI),
            (axis * (PI - 0.01), -axis * (PI + 0.01)),
        ] {
            assert!(max_rotation_diff(r0, r1) < 1e-12, "not the same rotation");
            let frames: Vec<FrameParams> = (0..9)
                .map(|i| {
                    let mut p = FrameParams::default();
                    let r = if i % 2 == 0 { r0 } else { r1 };
                    p.body_pose[15] = r;
                    p.global_orient = r;
                    p
                })
                .collect();
            for p in smooth_params(&frames, &Smoothing::PAPER).unwrap() {
                assert!(max_rotation_diff(p.body_pose[15], r0) < 1e-9, "{p:?}");
                assert!(max_rotation_diff(p.global_orient, r0) < 1e-9);
            }
        }
    }

    #[test]
    fn noise_is_reduced() {
        // Seeded LCG noise on a slow sine: the smoothed sequence is closer to the signal.
        let mut s: u64 = 42;
        let mut noise = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.2
        };
        let n = 60;
        let clean: Vec<FrameParams> = (0..n)
            .map(|i| {
                let t = i as f64 * 0.05;
                let mut p = FrameParams::default();
                p.body_pose[17] = DVec3::new(0.8 * t.sin(), 0.3, -0.5 * t.cos());
                p.expression[0] = t.sin();
                p.transl = DVec3::new(0.1 * t, 0.0, 0.0);
                p
            })
            .collect();
        let noisy: Vec<FrameParams> = clean
            .iter()
            .map(|p| {
                let mut q = p.clone();
                q.body_pose[17] += DVec3::new(noise(), noise(), noise());
                q.expression[0] += noise();
                q.transl += DVec3::new(noise(), noise(), noise());
                q
            })
            .collect();
        let smooth = smooth_params(&noisy, &Smoothing::PAPER).unwrap();
        let err = |seq: &[FrameParams]| {
            let (mut rot, mut expr, mut tr) = (0.0, 0.0, 0.0);
            for (p, c) in seq.iter().zip(&clean).skip(2).take(n - 4) {
                rot += max_rotation_diff(p.body_pose[17], c.body_pose[17]).powi(2);
                expr += (p.expression[0] - c.expression[0]).powi(2);
                tr += (p.transl - c.transl).length_squared();
            }
            (rot, expr, tr)
        };
        let (before, after) = (err(&noisy), err(&smooth));
        assert!(after.0 < 0.5 * before.0, "rotation {before:?} -> {after:?}");
        assert!(
            after.1 < 0.5 * before.1,
            "expression {before:?} -> {after:?}"
        );
        assert!(
            after.2 < 0.5 * before.2,
            "translation {before:?} -> {after:?}"
        );

        // Cameras: a jittered centre and focal length get closer to the clean path.
        let clean_cams: Vec<Camera> = (0..n)
            .map(|i| camera(DVec3::new(0.01 * i as f64, 1.1, 3.0), 90.0))
            .collect();
        let noisy_cams: Vec<Camera> = (0..n)
            .map(|i| {
                camera(
                    DVec3::new(0.01 * i as f64 + noise(), 1.1 + noise(), 3.0),
                    90.0 + 10.0 * noise(),
                )
            })
            .collect();
        let smooth_cams = smooth_cameras(&noisy_cams, &Smoothing::PAPER).unwrap();
        let cam_err = |seq: &[Camera]| -> f64 {
            seq.iter()
                .zip(&clean_cams)
                .skip(2)
                .take(n - 4)
                .map(|(a, b)| {
                    (a.center_in_world() - b.center_in_world()).length_squared()
                        + (a.intrinsics.x_axis.x - b.intrinsics.x_axis.x).powi(2) * 1e-2
                })
                .sum()
        };
        assert!(cam_err(&smooth_cams) < 0.5 * cam_err(&noisy_cams));
    }

    #[test]
    fn edges_renormalise_the_window() {
        let w = Smoothing::PAPER.weights().unwrap();
        for i in 0..4 {
            let taps = window(i, 4, &w);
            assert!((taps.iter().map(|t| t.1).sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(taps.iter().all(|&(j, _)| j < 4));
        }
        assert_eq!(window(0, 1, &w), vec![(0, 1.0)]);
        assert!(smooth_params(&[], &Smoothing::PAPER).unwrap().is_empty());
    }

    #[test]
    fn nan_input_and_bad_filters_are_errors() {
        let mut frames = vec![posed(0.0); 5];
        frames[3].left_hand_pose[2].y = f64::NAN;
        assert_eq!(
            smooth_params(&frames, &Smoothing::PAPER).unwrap_err(),
            SmoothError::NonFinite {
                frame: 3,
                field: "left_hand_pose"
            }
        );
        frames[3] = posed(0.0);
        frames[1].expression[4] = f64::INFINITY;
        let e = smooth_params(&frames, &Smoothing::PAPER).unwrap_err();
        assert!(e.to_string().contains("frame 1: `expression`"), "{e}");
        let even = Smoothing {
            window: 4,
            sigma: 1.0,
        };
        assert!(matches!(
            smooth_params(&[posed(0.0)], &even),
            Err(SmoothError::BadFilter { .. })
        ));
        let mut cams = vec![camera(DVec3::new(0.0, 1.0, 3.0), 90.0); 3];
        cams[2] = Camera::look_at(32, 80, 90.0, DVec3::Z * 3.0, DVec3::ZERO, DVec3::Y).unwrap();
        assert!(matches!(
            smooth_cameras(&cams, &Smoothing::PAPER),
            Err(SmoothError::CameraSize { frame: 0, .. })
        ));
    }
}
