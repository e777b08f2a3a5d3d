//! The subject's 55 rest joints when a format gives only the 22 body joints of the T-pose
//! (HumanNeRF's `tpose_joints`, SMPL's first 22): the body joints are kept as given and the
//! jaw, eyes and fingers are completed, from a built-in template scaled to the subject's
//! bones ([`complete_from_body`]) or, with an SMPL-X model file, from the body shape whose
//! joints fit the given ones best ([`fit_body_joints`]).

use glam::DVec3;

use talkin_data::smplx_model::{ModelError, SmplxModel};
use talkin_human::body::{N_BODY_JOINTS, N_JOINTS, PARENTS, joint, skeleton::body_ancestor};

/// Offsets of joints 22..54 from their parents in an adult T-pose (arms along +-x, y up,
/// facing +z), for the left side; the right side mirrors x. Face offsets are measured with
/// a 0.10 m neck-to-head bone, finger offsets with a 0.25 m forearm.
fn template_offset(j: usize) -> DVec3 {
    let v = DVec3::new;
    match j {
        joint::JAW => v(0.0, -0.02, 0.05),
        joint::LEFT_EYE => v(0.03, 0.05, 0.08),
        joint::RIGHT_EYE => v(-0.03, 0.05, 0.08),
        _ => {
            let side = if j < joint::RIGHT_HAND_FIRST {
                1.0
            } else {
                -1.0
            };
            let first = if side > 0.0 {
                joint::LEFT_HAND_FIRST
            } else {
                joint::RIGHT_HAND_FIRST
            };
            let (finger, segment) = ((j - first) / 3, (j - first) % 3);
            // Index, middle, pinky, ring and thumb knuckles from the wrist.
            let knuckles = [
                v(0.09, 0.0, 0.03),
                v(0.095, 0.0, 0.01),
                v(0.08, 0.0, -0.03),
                v(0.09, 0.0, -0.01),
                v(0.03, -0.01, 0.04),
            ];
            let o = match segment {
                0 => knuckles[finger],
                1 => v(0.03, 0.0, 0.0),
                _ => v(0.025, 0.0, 0.0),
            };
            v(o.x * side, o.y, o.z)
        }
    }
}

/// 55 rest joints from the 22 given body joints: jaw, eyes and fingers from the template,
/// scaled by the subject's neck-to-head and elbow-to-wrist bones.
pub fn complete_from_body(body: &[DVec3; N_BODY_JOINTS]) -> [DVec3; N_JOINTS] {
    let face = (body[joint::HEAD] - body[joint::NECK]).length() / 0.10;
    let left = (body[joint::LEFT_WRIST] - body[joint::LEFT_ELBOW]).length() / 0.25;
    let right = (body[joint::RIGHT_WRIST] - body[joint::RIGHT_ELBOW]).length() / 0.25;
    let mut rest = [DVec3::ZERO; N_JOINTS];
    rest[..N_BODY_JOINTS].copy_from_slice(body);
    for j in N_BODY_JOINTS..N_JOINTS {
        let scale = match body_ancestor(j) {
            joint::HEAD => face,
            joint::LEFT_WRIST => left,
            _ => right,
        };
        rest[j] = rest[PARENTS[j] as usize] + template_offset(j) * scale;
    }
    rest
}

/// Shape coefficients fitted to the given body joints.
pub const FIT_BETAS: usize = 10;

/// 55 rest joints from the 22 given body joints and an SMPL-X model: the betas (the first
/// `FIT_BETAS`) and a translation whose model joints best fit the given ones in least
/// squares; the body joints are kept as given, the others placed as the fitted model
/// places them relative to their body joint. Returns the joints, the betas and the RMS
/// fit residual in metres.
pub fn fit_body_joints(
    model: &SmplxModel,
    body: &[DVec3; N_BODY_JOINTS],
) -> Result<([DVec3; N_JOINTS], Vec<f64>, f64), ModelError> {
    let nb = FIT_BETAS.min(model.n_shape());
    let base = model.rest_joints(&[])?;
    let mut basis = Vec::with_capacity(nb);
    for c in 0..nb {
        let mut e = vec![0.0; c + 1];
        e[c] = 1.0;
        let j = model.rest_joints(&e)?;
        basis.push(std::array::from_fn::<DVec3, N_JOINTS, _>(|i| {
            j[i] - base[i]
        }));
    }
    // Unknowns: betas (nb), then the translation (3). Rows: 22 joints x 3 axes.
    let n = nb + 3;
    let mut ata = vec![vec![0.0; n]; n];
    let mut atb = vec![0.0; n];
    for j in 0..N_BODY_JOINTS {
        for axis in 0..3 {
            let mut row = vec![0.0; n];
            for (c, b) in basis.iter().enumerate() {
                row[c] = b[j][axis];
            }
            row[nb + axis] = 1.0;
            let rhs = body[j][axis] - base[j][axis];
            for r in 0..n {
                atb[r] += row[r] * rhs;
                for c in 0..n {
                    ata[r][c] += row[r] * row[c];
                }
            }
        }
    }
    // A whisper of ridge keeps unobservable directions at zero.
    for (c, row) in ata.iter_mut().enumerate().take(nb) {
        row[c] += 1e-10;
    }
    let x = solve(ata, atb).unwrap_or_else(|| vec![0.0; n]);
    let betas = x[..nb].to_vec();
    let fitted = model.rest_joints(&betas)?;
    let shift = DVec3::new(x[nb], x[nb + 1], x[nb + 2]);
    let residual = (0..N_BODY_JOINTS)
        .map(|j| (fitted[j] + shift - body[j]).length_squared())
        .sum::<f64>()
        / N_BODY_JOINTS as f64;
    let mut rest = [DVec3::ZERO; N_JOINTS];
    rest[..N_BODY_JOINTS].copy_from_slice(body);
    for j in N_BODY_JOINTS..N_JOINTS {
        let a = body_ancestor(j);
        rest[j] = body[a] + (fitted[j] - fitted[a]);
    }
    Ok((rest, betas, residual.sqrt()))
}

/// Solves the square system `a x = b` by Gaussian elimination with partial pivoting;
/// `None` if it is singular.
pub(crate) fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for r in col + 1..n {
            let f = a[r][col] / a[col][col];
            for c in col..n {
                a[r][c] -= f * a[col][c];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|c| a[r][c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve_matches_a_known_system() {
        let a = vec![
            vec![2.0, 1.0, 0.0],
            vec![1.0, 3.0, 1.0],
            vec![0.0, 1.0, 4.0],
        ];
        let x = [1.0, -2.0, 0.5];
        let b = (0..3)
            .map(|r| (0..3).map(|c| a[r][c] * x[c]).sum())
            .collect();
        let got = solve(a, b).unwrap();
        for i in 0..3 {
            assert!((got[i] - x[i]).abs() < 1e-12);
        }
        assert!(solve(vec![vec![1.0, 2.0], vec![2.0, 4.0]], vec![1.0, 2.0]).is_none());
    }

    #[test]
    fn completion_keeps_the_body_and_scales_the_hands() {
        let mut body = [DVec3::ZERO; N_BODY_JOINTS];
        for j in 1..N_BODY_JOINTS {
            body[j] = body[PARENTS[j] as usize] + DVec3::new(0.02 * j as f64, 0.1, 0.0);
        }
        body[joint::LEFT_WRIST] = body[joint::LEFT_ELBOW] + DVec3::new(0.5, 0.0, 0.0);
        let rest = complete_from_body(&body);
        assert_eq!(&rest[..N_BODY_JOINTS], &body[..]);
        // A forearm twice the template's doubles the hand.
        let knuckle = rest[joint::LEFT_HAND_FIRST] - rest[joint::LEFT_WRIST];
        assert!((knuckle - DVec3::new(0.18, 0.0, 0.06)).length() < 1e-12);
    }
}
