//! The SMPL-X body model without SMPL-X's licensed files: skeleton topology, per-frame
//! parameters, rotations, forward kinematics, skinning transforms and limb capsules.
//! Every subject brings its own rest-pose joints.

pub mod capsules;
pub mod fk;
pub mod params;
pub mod rotation;
pub mod skeleton;

pub use capsules::limb_capsules;
pub use fk::{PosedSkeleton, Skeleton, canonical_from_posed, canonical_params};
pub use params::{FrameParams, N_EXPRESSION};
pub use rotation::{axis_angle_from_rotation, rotation_from_axis_angle};
pub use skeleton::{JOINT_NAMES, N_BODY_JOINTS, N_HAND_JOINTS, N_JOINTS, PARENTS, joint};
