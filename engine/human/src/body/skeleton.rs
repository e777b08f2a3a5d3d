//! The SMPL-X skeleton: 55 joints, their names, parents and body-part labels.
//!
//! Conventions (SMPL-X): y up, the subject faces +z, +x points to the subject's left, and
//! the zero pose is the T-pose.

use talkin_grids::Part;

/// Number of SMPL-X joints.
pub const N_JOINTS: usize = 55;
/// Joints 0..22 are the body joints that drive inverse LBS (the paper's K = 22).
pub const N_BODY_JOINTS: usize = 22;
/// Joints per hand (index, middle, pinky, ring, thumb; three each).
pub const N_HAND_JOINTS: usize = 15;

/// Joint names in SMPL-X order.
pub const JOINT_NAMES: [&str; N_JOINTS] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "jaw",
    "left_eye",
    "right_eye",
    "left_index1",
    "left_index2",
    "left_index3",
    "left_middle1",
    "left_middle2",
    "left_middle3",
    "left_pinky1",
    "left_pinky2",
    "left_pinky3",
    "left_ring1",
    "left_ring2",
    "left_ring3",
    "left_thumb1",
    "left_thumb2",
    "left_thumb3",
    "right_index1",
    "right_index2",
    "right_index3",
    "right_middle1",
    "right_middle2",
    "right_middle3",
    "right_pinky1",
    "right_pinky2",
    "right_pinky3",
    "right_ring1",
    "right_ring2",
    "right_ring3",
    "right_thumb1",
    "right_thumb2",
    "right_thumb3",
];

/// Parent of each joint; `-1` for the root (pelvis). Parents always precede children.
pub const PARENTS: [i32; N_JOINTS] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15, 20, 25,
    26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38, 21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49,
    50, 21, 52, 53,
];

/// Named joint indices used by the body model, the generator and the crops.
pub mod joint {
    pub const PELVIS: usize = 0;
    pub const LEFT_HIP: usize = 1;
    pub const RIGHT_HIP: usize = 2;
    pub const SPINE1: usize = 3;
    pub const LEFT_KNEE: usize = 4;
    pub const RIGHT_KNEE: usize = 5;
    pub const SPINE2: usize = 6;
    pub const LEFT_ANKLE: usize = 7;
    pub const RIGHT_ANKLE: usize = 8;
    pub const SPINE3: usize = 9;
    pub const LEFT_FOOT: usize = 10;
    pub const RIGHT_FOOT: usize = 11;
    pub const NECK: usize = 12;
    pub const LEFT_COLLAR: usize = 13;
    pub const RIGHT_COLLAR: usize = 14;
    pub const HEAD: usize = 15;
    pub const LEFT_SHOULDER: usize = 16;
    pub const RIGHT_SHOULDER: usize = 17;
    pub const LEFT_ELBOW: usize = 18;
    pub const RIGHT_ELBOW: usize = 19;
    pub const LEFT_WRIST: usize = 20;
    pub const RIGHT_WRIST: usize = 21;
    pub const JAW: usize = 22;
    pub const LEFT_EYE: usize = 23;
    pub const RIGHT_EYE: usize = 24;
    /// First joint of the left hand (left_index1); the right hand starts 15 later.
    pub const LEFT_HAND_FIRST: usize = 25;
    pub const RIGHT_HAND_FIRST: usize = 40;
}

/// Parent of joint `j`, `None` for the root.
pub fn parent(j: usize) -> Option<usize> {
    usize::try_from(PARENTS[j]).ok()
}

/// Children of joint `j`, in index order.
pub fn children(j: usize) -> impl Iterator<Item = usize> {
    (0..N_JOINTS).filter(move |&c| PARENTS[c] == j as i32)
}

/// Index of a joint by name.
pub fn joint_index(name: &str) -> Option<usize> {
    JOINT_NAMES.iter().position(|n| *n == name)
}

/// The body joint (0..22) whose transform a joint follows in inverse LBS: hand joints
/// follow their wrist, jaw and eyes the head (hand joints in the canonical transform hurt,
/// the paper's ablation).
pub fn body_ancestor(j: usize) -> usize {
    match j {
        0..N_BODY_JOINTS => j,
        joint::JAW | joint::LEFT_EYE | joint::RIGHT_EYE => joint::HEAD,
        25..40 => joint::LEFT_WRIST,
        _ => joint::RIGHT_WRIST,
    }
}

/// The body part a joint's bone (the segment from the joint towards its children) belongs
/// to, following the DensePose grouping of the dataset's segmentation.
pub fn part_of_joint(j: usize) -> Part {
    use joint::*;
    match j {
        HEAD | JAW | LEFT_EYE | RIGHT_EYE => Part::Head,
        LEFT_SHOULDER | RIGHT_SHOULDER | LEFT_ELBOW | RIGHT_ELBOW => Part::Arms,
        LEFT_WRIST | RIGHT_WRIST => Part::Hands,
        25..N_JOINTS => Part::Hands,
        _ => Part::Body,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parents_precede_children_and_names_are_unique() {
        for j in 1..N_JOINTS {
            let p = parent(j).expect("only the root has no parent");
            assert!(p < j, "joint {j} has parent {p}");
        }
        assert_eq!(parent(0), None);
        let mut names = JOINT_NAMES.to_vec();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), N_JOINTS);
    }

    #[test]
    fn hands_hang_off_the_wrists() {
        assert_eq!(joint_index("left_index1"), Some(joint::LEFT_HAND_FIRST));
        assert_eq!(joint_index("right_index1"), Some(joint::RIGHT_HAND_FIRST));
        for f in 0..5 {
            assert_eq!(parent(25 + 3 * f), Some(joint::LEFT_WRIST));
            assert_eq!(parent(40 + 3 * f), Some(joint::RIGHT_WRIST));
        }
        for j in 25..N_JOINTS {
            assert_eq!(part_of_joint(j), Part::Hands);
            let wrist = if j < 40 {
                joint::LEFT_WRIST
            } else {
                joint::RIGHT_WRIST
            };
            assert_eq!(body_ancestor(j), wrist);
        }
        assert_eq!(children(joint::NECK).collect::<Vec<_>>(), vec![joint::HEAD]);
    }
}
