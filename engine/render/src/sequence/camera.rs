//! The camera a subject gets when nothing brings one (the server's requests, `talkin render
//! --motion`).
//!
//! A checkpoint stores no camera (rendering needs no dataset), so the default is built from
//! the subject's rest skeleton: frontal, 3.2 m away, framing the T-pose (arms spread) from
//! mid-thigh to above the head, like the synthetic scenes' cameras.

use glam::DVec3;

use talkin_human::body::{Skeleton, joint};
use talkin_human::camera::{Camera, CameraError};

/// How far the default camera stands from the point it looks at (metres).
pub const DEFAULT_CAMERA_DISTANCE: f64 = 3.2;

/// A frontal camera framing `skeleton`'s T-pose from mid-thigh up with 10% to spare.
pub fn default_camera(skeleton: &Skeleton, width: u32, height: u32) -> Result<Camera, CameraError> {
    let r = &skeleton.rest_joints;
    let bottom = (r[joint::LEFT_HIP].y + r[joint::LEFT_KNEE].y) * 0.5;
    // The head joint sits at the skull's base; the crown is about a third of the
    // pelvis-to-neck distance above it.
    let top = r[joint::HEAD].y + 0.35 * 0.55 * skeleton.scale();
    let centre = DVec3::new(
        (r[joint::LEFT_WRIST].x + r[joint::RIGHT_WRIST].x) * 0.5,
        (top + bottom) * 0.5,
        r[joint::PELVIS].z,
    );
    // Fingertips stick out past the wrists by about a hand's length.
    let half_width = (r[joint::LEFT_WRIST].x - r[joint::RIGHT_WRIST].x).abs() * 0.5
        + 0.25 * 0.55 * skeleton.scale();
    let half_height = (top - bottom) * 0.5;
    let distance = DEFAULT_CAMERA_DISTANCE;
    let focal = (f64::from(width) * 0.5 * distance / half_width)
        .min(f64::from(height) * 0.5 * distance / half_height)
        / 1.1;
    Camera::look_at(
        width,
        height,
        focal,
        centre + DVec3::new(0.0, 0.0, distance),
        centre,
        DVec3::Y,
    )
}
