//! Canonical space for the grids: the subject's initial occupancy grid.

use glam::Vec3;
use talkin_grids::{Capsule, GridError, OccupancyGrid, Part};

use super::frame::capsule_bounds;
use super::frame::shell_capsules;
use super::shells::CapsuleShells;
use talkin_human::body::skeleton::body_ancestor;
use talkin_human::body::{FrameParams, Skeleton, canonical_params, joint};

/// How far (metres) the carved grid reaches past the training surface points of the
/// body and arms, for what the training frames did not show: cloth that swings further,
/// skin that slides against its bones in a wider pose. Measured on the default scene's
/// held-out splits: no reach lost 26 surface points, 1 cm lost 1, 2 cm none. The
/// sampler's cull adds its own reach (half a posed cell diagonal + a bin) on top.
pub const SURFACE_REACH_M: f32 = 0.02;

/// A subject's canonical occupancy grid, initialised from its skeleton.
pub struct CanonicalGrid;

impl CanonicalGrid {
    /// The grid over the subject's canonical space: the canonical-pose capsules inflated by
    /// their shells' margins, with, for every given frame, that frame's fingers, jaw and
    /// eyes (inverse LBS over the body joints alone does not undo them, so the grid holds
    /// their union; a field that skins the fingers needs only the rest-pose hand, and its
    /// occupancy updates clear the rest), plus each wrist's reach (a sphere of the hand's
    /// length) so novel finger poses are never culled. Marks are grown by one cell
    /// diagonal against discretisation.
    /// `resolution` is the cell count along the longest axis. With `surface` (canonical
    /// surface points of the training frames, see
    /// [`super::canonical_surface_points`]), the body and arm cells are carved to those
    /// points grown by [`SURFACE_REACH_M`]; hand and head cells keep their capsules.
    pub fn initial<'a>(
        skeleton: &Skeleton,
        frames: impl IntoIterator<Item = &'a FrameParams>,
        shells: &CapsuleShells,
        resolution: u32,
        surface: Option<&[Vec3]>,
    ) -> Result<OccupancyGrid, GridError> {
        let mut capsule_sets = vec![canonical_capsules(skeleton, &canonical_params(), shells)];
        for params in frames {
            let mut p = canonical_params();
            p.jaw_pose = params.jaw_pose;
            p.leye_pose = params.leye_pose;
            p.reye_pose = params.reye_pose;
            p.left_hand_pose = params.left_hand_pose;
            p.right_hand_pose = params.right_hand_pose;
            capsule_sets.push(canonical_capsules(skeleton, &p, shells));
        }
        let reach = wrist_reach(&capsule_sets[0]);
        let all: Vec<Capsule> = capsule_sets
            .iter()
            .flatten()
            .chain(&reach)
            .copied()
            .collect();
        let (lo, hi) = capsule_bounds(&all, 0.0);
        let extent = hi - lo;
        let cell = extent.max_element() / resolution.max(8) as f32;
        let (lo, hi) = (lo - Vec3::splat(2.0 * cell), hi + Vec3::splat(2.0 * cell));
        let res = ((hi - lo) / cell)
            .ceil()
            .as_uvec3()
            .max(glam::UVec3::ONE)
            .to_array();
        let mut grid = OccupancyGrid::new(lo, hi, res)?;
        let grow = cell * 3f32.sqrt();
        // Marking is a union, so each capsule once: the frames change only the fingers,
        // jaw and eyes, and every frame's set repeats the body's capsules.
        let marked = distinct(&all);
        grid.mark_capsules(&marked, grow)?;
        if let Some(points) = surface {
            let mut carved = OccupancyGrid::new(lo, hi, res)?;
            carved.mark(points);
            carved.dilate((SURFACE_REACH_M / cell).ceil() as u32);
            let kept: Vec<Capsule> = marked
                .iter()
                .filter(|c| !super::CARVED_PARTS.contains(&c.part))
                .copied()
                .collect();
            carved.mark_capsules(&kept, grow)?;
            grid.intersect(&carved)?;
        }
        // No sample can land outside these capsules: updates need not look there.
        grid.restrict_to_marked();
        Ok(grid)
    }
}

/// `capsules` without repeats (bit for bit), in their first order.
fn distinct(capsules: &[Capsule]) -> Vec<Capsule> {
    let key = |c: &Capsule| {
        let [ax, ay, az] = c.a.to_array().map(f32::to_bits);
        let [bx, by, bz] = c.b.to_array().map(f32::to_bits);
        (ax, ay, az, bx, by, bz, c.radius.to_bits(), c.part, c.bone)
    };
    let mut seen = std::collections::HashSet::with_capacity(capsules.len());
    capsules
        .iter()
        .filter(|c| seen.insert(key(c)))
        .copied()
        .collect()
}

fn canonical_capsules(
    skeleton: &Skeleton,
    params: &FrameParams,
    shells: &CapsuleShells,
) -> Vec<Capsule> {
    shells.inflate(&shell_capsules(skeleton, &skeleton.pose(params)))
}

/// A sphere per wrist, reaching its farthest finger capsule.
fn wrist_reach(capsules: &[Capsule]) -> Vec<Capsule> {
    [joint::LEFT_WRIST, joint::RIGHT_WRIST]
        .into_iter()
        .filter_map(|wrist| {
            let centre = capsules.iter().find(|c| c.bone as usize == wrist)?.a;
            let reach = capsules
                .iter()
                .filter(|c| c.part == Part::Hands && body_ancestor(c.bone as usize) == wrist)
                .map(|c| (c.a - centre).length().max((c.b - centre).length()) + c.radius)
                .fold(0.0f32, f32::max);
            Some(Capsule {
                a: centre,
                b: centre,
                radius: reach,
                part: Part::Hands,
                bone: wrist as u16,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_drops_only_exact_repeats_and_keeps_the_first_order() {
        let c = |x: f32, radius: f32, bone: u16| Capsule {
            a: Vec3::new(x, 0.0, 0.0),
            b: Vec3::new(x, 1.0, 0.0),
            radius,
            part: Part::Body,
            bone,
        };
        let nudged = f32::from_bits(0.1f32.to_bits() + 1);
        let hand = Capsule {
            part: Part::Hands,
            ..c(0.0, 0.1, 3)
        };
        let given = [
            c(0.0, 0.1, 3),
            c(1.0, 0.1, 3),
            c(0.0, 0.1, 3),
            c(0.0, nudged, 3),
            c(0.0, 0.1, 4),
            hand,
            c(1.0, 0.1, 3),
        ];
        let kept = distinct(&given);
        assert_eq!(
            kept,
            vec![given[0], given[1], given[3], given[4], given[5]],
            "{kept:?}"
        );
    }
}
