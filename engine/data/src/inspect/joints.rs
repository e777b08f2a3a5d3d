//! Posed 3D joints of every frame and their 2D projections.

use serde::Serialize;

use crate::dataset::Dataset;
use talkin_human::body::N_JOINTS;

/// One frame's posed joints (world, metres) and pixel projections (`None` behind the
/// camera).
#[derive(Clone, Debug, Serialize)]
pub struct FrameJoints {
    pub frame: usize,
    pub subject: String,
    pub split: String,
    pub joints_3d: Vec<[f64; 3]>,
    pub joints_2d: Vec<Option<[f64; 2]>>,
}

/// Posed joints and projections of frame `index`.
pub fn frame_joints(dataset: &Dataset, index: usize) -> FrameJoints {
    let frame = &dataset.frames[index];
    let subject = &dataset.subjects[frame.subject];
    let posed = subject.skeleton.pose(&frame.params);
    let joints = posed.joints();
    FrameJoints {
        frame: index,
        subject: subject.name.clone(),
        split: frame.split.name().to_string(),
        joints_3d: joints.iter().map(|j| j.to_array()).collect(),
        joints_2d: (0..N_JOINTS)
            .map(|j| frame.camera.project(joints[j]).map(|p| [p.x, p.y]))
            .collect(),
    }
}
