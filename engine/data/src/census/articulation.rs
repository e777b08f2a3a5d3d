//! How much a subject's fitted articulation moves over its frames: each joint's spread
//! is the RMS angle between its rotation in a frame and its mean rotation.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};
use talkin_human::body::FrameParams;
use talkin_human::body::{axis_angle_from_rotation, rotation_from_axis_angle};

/// Spreads in degrees (the largest of a group's joints) and of the expression.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Articulation {
    /// The 30 finger joints.
    pub fingers_deg: f64,
    /// The two wrists (relative to the forearms).
    pub wrists_deg: f64,
    /// The jaw.
    pub jaw_deg: f64,
    /// The expression: the largest standard deviation of one coefficient.
    pub expression: f64,
    /// The body's joints below the wrists (hips to elbows, spine, neck, head).
    pub body_deg: f64,
}

/// SMPL-X's body-pose slots (joints 1..22) of the wrists.
const WRISTS: [usize; 2] = [19, 20];

impl Articulation {
    /// The spreads over `frames` (zeros for none or one).
    pub fn of(frames: &[&FrameParams]) -> Articulation {
        let fingers = (0..15)
            .flat_map(|j| {
                [
                    spread_deg(frames.iter().map(|p| p.left_hand_pose[j])),
                    spread_deg(frames.iter().map(|p| p.right_hand_pose[j])),
                ]
            })
            .fold(0.0, f64::max);
        let wrists = WRISTS
            .iter()
            .map(|&w| spread_deg(frames.iter().map(|p| p.body_pose[w])))
            .fold(0.0, f64::max);
        let body = (0..WRISTS[0])
            .map(|j| spread_deg(frames.iter().map(|p| p.body_pose[j])))
            .fold(0.0, f64::max);
        let n_expr = frames.first().map_or(0, |p| p.expression.len());
        let expression = (0..n_expr)
            .map(|k| std_dev(frames.iter().map(|p| p.expression[k])))
            .fold(0.0, f64::max);
        Articulation {
            fingers_deg: fingers,
            wrists_deg: wrists,
            jaw_deg: spread_deg(frames.iter().map(|p| p.jaw_pose)),
            expression,
            body_deg: body,
        }
    }
}

/// RMS angle (degrees) between each rotation and their mean (a few steps of the Karcher
/// mean, from the first: axis-angle vectors near pi that name nearly one rotation do not
/// average to the identity); 0 for fewer than two, and non-finite fits are left out (a
/// fit that is not a rotation says nothing about motion).
fn spread_deg(rotations: impl Iterator<Item = DVec3>) -> f64 {
    let rs: Vec<DMat3> = rotations
        .filter(|r| r.is_finite())
        .map(rotation_from_axis_angle)
        .collect();
    if rs.len() < 2 {
        return 0.0;
    }
    let mut mean = rs[0];
    for _ in 0..4 {
        let step = rs
            .iter()
            .map(|r| axis_angle_from_rotation(mean.transpose() * *r))
            .sum::<DVec3>()
            / rs.len() as f64;
        mean *= rotation_from_axis_angle(step);
    }
    let sum2: f64 = rs
        .iter()
        .map(|r| angle_of(mean.transpose() * *r).powi(2))
        .sum();
    (sum2 / rs.len() as f64).sqrt().to_degrees()
}

/// The rotation angle of `m` (radians), clamped against rounding.
fn angle_of(m: DMat3) -> f64 {
    let trace = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
}

/// The population standard deviation; 0 for fewer than two or non-finite values.
fn std_dev(values: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.len() < 2 {
        return 0.0;
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn still_fits_do_not_move_and_one_moving_frame_does() {
        let still = FrameParams::default();
        let frames = vec![&still; 5];
        assert_eq!(Articulation::of(&frames), Articulation::default());
        assert_eq!(Articulation::of(&[]), Articulation::default());
        assert_eq!(Articulation::of(&[&still]), Articulation::default());
        let mut bent = FrameParams {
            jaw_pose: DVec3::new(0.2, 0.0, 0.0),
            ..FrameParams::default()
        };
        bent.left_hand_pose[4] = DVec3::new(0.0, 0.0, 0.5);
        bent.expression[3] = 1.0;
        let mut frames = vec![&still; 9];
        frames.push(&bent);
        let a = Articulation::of(&frames);
        // One frame of ten bent by 28.6 degrees, measured from the mean (a tenth of the way):
        // RMS = sqrt((9 * 2.86^2 + 25.8^2) / 10) = 8.6 degrees.
        assert!((a.fingers_deg - 8.59).abs() < 0.05, "{a:?}");
        assert!(a.jaw_deg > 3.0 && a.expression > 0.29 && a.expression < 0.31);
        assert_eq!((a.wrists_deg, a.body_deg), (0.0, 0.0));
        for x in [a.fingers_deg, a.jaw_deg, a.expression] {
            assert!(x.is_finite());
        }
    }

    #[test]
    fn rotations_near_pi_and_non_finite_fits_stay_finite() {
        let jaw = |x: f64| FrameParams {
            jaw_pose: DVec3::new(x, 0.0, 0.0),
            ..FrameParams::default()
        };
        let (a, b) = (
            jaw(std::f64::consts::PI - 1e-9),
            jaw(-(std::f64::consts::PI - 1e-9)),
        );
        let mut c = jaw(f64::NAN);
        c.expression[0] = f64::INFINITY;
        let s = Articulation::of(&[&a, &b, &c]);
        // +pi and -pi about one axis are one rotation: no spread.
        assert!(s.jaw_deg < 1e-3, "{s:?}");
        assert!(s.expression.is_finite(), "{s:?}");
    }
}
