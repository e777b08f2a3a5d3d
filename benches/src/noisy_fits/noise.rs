//! Known, seeded noise on a dataset's training fits, and how far a set of fits is from
//! the truth.

use glam::DVec3;
use talkin_grids::SplitMix64;
use talkin_human::body::{
    FrameParams, Skeleton, axis_angle_from_rotation, rotation_from_axis_angle,
};

/// Translation noise (RMS, metres) at 6 degrees; it scales with the level.
pub const TRANSL_RMS_AT_6_DEG_M: f64 = 0.02;
/// Expression noise (standard deviation per coefficient) at 6 degrees.
pub const EXPRESSION_SD_AT_6_DEG: f64 = 0.1;

/// A standard normal draw (Box-Muller).
fn normal(rng: &mut SplitMix64) -> f64 {
    let u1 = rng.next_f64().max(1e-300);
    let u2 = rng.next_f64();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A rotation of RMS angle `rms` radians (isotropic Gaussian axis-angle), composed onto
/// `r` (axis-angle) on the joint's side.
fn turn(r: DVec3, rms: f64, rng: &mut SplitMix64) -> DVec3 {
    let sd = rms / 3f64.sqrt();
    let n = DVec3::new(normal(rng), normal(rng), normal(rng)) * sd;
    axis_angle_from_rotation(rotation_from_axis_angle(r) * rotation_from_axis_angle(n))
}

/// `params` with noise of level `deg` degrees: every body joint (1..22), finger joint and
/// the jaw turned by an RMS `deg`, the translation moved by an RMS of 2 cm x `deg` / 6
/// and each expression coefficient by 0.1 x `deg` / 6. The global orientation and eyes
/// are kept. Seeded by `seed`.
pub fn noisy(params: &FrameParams, deg: f64, seed: u64) -> FrameParams {
    let mut rng = SplitMix64::new(seed);
    let rms = deg.to_radians();
    let scale = deg / 6.0;
    let mut p = params.clone();
    for r in p
        .body_pose
        .iter_mut()
        .chain(p.left_hand_pose.iter_mut())
        .chain(p.right_hand_pose.iter_mut())
    {
        *r = turn(*r, rms, &mut rng);
    }
    p.jaw_pose = turn(p.jaw_pose, rms, &mut rng);
    let t_sd = TRANSL_RMS_AT_6_DEG_M * scale / 3f64.sqrt();
    p.transl += DVec3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)) * t_sd;
    for e in &mut p.expression {
        *e += normal(&mut rng) * EXPRESSION_SD_AT_6_DEG * scale;
    }
    p
}

/// Mean distance (metres) between the 55 posed joints of `a` and `b` on `skeleton`.
pub fn joint_position_error(skeleton: &Skeleton, a: &FrameParams, b: &FrameParams) -> f64 {
    let (pa, pb) = (skeleton.pose(a).joints(), skeleton.pose(b).joints());
    pa.iter()
        .zip(&pb)
        .map(|(x, y)| (*x - *y).length())
        .sum::<f64>()
        / pa.len() as f64
}

/// Mean angle (degrees) between the local rotations of `a` and `b` over the joints the
/// noise turns (body 1..22, fingers, jaw).
pub fn joint_rotation_error(a: &FrameParams, b: &FrameParams) -> f64 {
    let pairs = |p: &FrameParams| -> Vec<DVec3> {
        p.body_pose
            .iter()
            .chain(&p.left_hand_pose)
            .chain(&p.right_hand_pose)
            .chain(std::iter::once(&p.jaw_pose))
            .copied()
            .collect()
    };
    let (ra, rb) = (pairs(a), pairs(b));
    let angles: Vec<f64> = ra
        .iter()
        .zip(&rb)
        .map(|(x, y)| {
            let d = rotation_from_axis_angle(*x).transpose() * rotation_from_axis_angle(*y);
            axis_angle_from_rotation(d).length().to_degrees()
        })
        .collect();
    angles.iter().sum::<f64>() / angles.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_its_level_and_zero_is_exact() {
        let p = FrameParams::default();
        assert_eq!(noisy(&p, 0.0, 1), p);
        // RMS of the turned joints' angles over many draws: the level.
        let mut sq = 0.0;
        let mut n = 0;
        for seed in 0..50 {
            let q = noisy(&p, 6.0, seed);
            let e = joint_rotation_error(&p, &q);
            assert!(e > 2.0 && e < 9.0, "{e}");
            for r in q.body_pose.iter().chain(&q.left_hand_pose) {
                sq += r.length_squared();
                n += 1;
            }
        }
        let rms = (sq / n as f64).sqrt().to_degrees();
        assert!((rms - 6.0).abs() < 0.4, "{rms}");
        assert_eq!(noisy(&p, 6.0, 3), noisy(&p, 6.0, 3));
    }
}
