//! human: the SMPL-X body without SMPL-X's licensed files. Owns the skeleton topology,
//! per-frame parameters, rotations, forward kinematics, the skinning transforms, the limb
//! capsules, pinhole cameras and the paper's test-time smoothing.
//!
//! Must not know about files or formats (the dataset, JSON, motion files), neural nets or
//! training: every subject brings its own rest-pose joints as plain numbers.

pub mod body;
pub mod camera;
pub mod smooth;
