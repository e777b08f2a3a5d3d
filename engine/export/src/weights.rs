//! Each vertex's skinning: the learned weights the renderer's inverse skinning blends
//! with ([`talkin_nets::skinning::BlendWeightVolume::blend_weights`]), read at the
//! canonical pose (where every candidate bone maps the vertex to itself, so the weights
//! of inverse and forward skinning agree), cut to the four largest and renormalised: what
//! glTF's `JOINTS_0`/`WEIGHTS_0` hold.

use glam::Vec3;
use rayon::prelude::*;

use crate::ExportError;
use crate::canonical::CanonicalSubject;

/// Joints per vertex in glTF's first set.
pub const JOINTS_PER_VERTEX: usize = 4;

/// Per vertex, four SMPL-X joints and their weights (summing to one, largest first;
/// unused slots weigh 0 and name joint 0, as glTF asks).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    pub joints: Vec<[u8; JOINTS_PER_VERTEX]>,
    pub weights: Vec<[f32; JOINTS_PER_VERTEX]>,
}

/// The skinning of canonical `positions` of `subject`.
pub fn skin_weights(
    subject: &CanonicalSubject,
    positions: &[Vec3],
) -> Result<SkinWeights, ExportError> {
    let points: Vec<[f32; 3]> = positions.iter().map(|p| p.to_array()).collect();
    let masks: Vec<u64> = positions
        .par_iter()
        .map(|&p| subject.candidates(p).0)
        .collect();
    let conditions = subject.conditions();
    let all = subject.avatar().field.skinning.blend_weights(
        &points,
        &masks,
        &conditions.canonical_from_posed,
        &conditions.bone_capsules,
    )?;
    let (joints, weights) = all.into_iter().map(largest_four).unzip();
    Ok(SkinWeights { joints, weights })
}

/// The four largest of `weights` (joint, weight), renormalised to sum to one in f32.
pub fn largest_four(
    mut weights: Vec<(usize, f32)>,
) -> ([u8; JOINTS_PER_VERTEX], [f32; JOINTS_PER_VERTEX]) {
    weights.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    weights.truncate(JOINTS_PER_VERTEX);
    weights.retain(|w| w.1 > 0.0);
    let total: f32 = weights.iter().map(|w| w.1).sum();
    let mut joints = [0u8; JOINTS_PER_VERTEX];
    let mut out = [0f32; JOINTS_PER_VERTEX];
    if weights.is_empty() || !total.is_finite() {
        // No weight at all: the root carries the vertex.
        out[0] = 1.0;
    } else {
        for (k, w) in weights.iter().enumerate() {
            joints[k] = w.0 as u8;
            out[k] = w.1 / total;
        }
        // The largest absorbs the rounding, so the sum is one in f32.
        out[0] = 1.0 - out[1..].iter().sum::<f32>();
    }
    (joints, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_largest_renormalised_with_joint_0_in_spare_slots() {
        let (j, w) = largest_four(vec![(3, 0.1), (9, 0.4), (16, 0.05), (13, 0.3), (0, 0.15)]);
        assert_eq!(j, [9, 13, 0, 3]);
        let total: f32 = 0.4 + 0.3 + 0.15 + 0.1;
        assert!((w[1] - 0.3 / total).abs() < 1e-6);
        assert_eq!(w.iter().sum::<f32>(), 1.0);
        let (j, w) = largest_four(vec![(20, 1.0)]);
        assert_eq!(w, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(j, [20, 0, 0, 0]);
        let (j, w) = largest_four(vec![(0, 0.0), (5, 0.0)]);
        assert_eq!((j, w), ([0, 0, 0, 0], [1.0, 0.0, 0.0, 0.0]));
    }
}
