//! The subjects a server renders and the camera each gets when a request brings none.
//!
//! A checkpoint stores no camera, so the default is built from the subject's rest skeleton
//! ([`default_camera`], in the render crate so that `talkin render` frames alike).

use talkin_avatar::Avatar;
use talkin_human::camera::{Camera, CameraError};

/// One trained subject as the server offers it.
#[derive(Clone, Debug)]
pub struct ServedSubject {
    pub name: String,
    /// Identity index in the avatar.
    pub index: usize,
    pub default_camera: Camera,
    /// The point the default camera looks at (world space): what a viewer orbits.
    pub orbit_target: glam::DVec3,
}

/// Every trained subject of `avatar`, each with a default camera of `width` x `height`.
pub fn served_subjects(
    avatar: &Avatar,
    width: u32,
    height: u32,
) -> Result<Vec<ServedSubject>, CameraError> {
    avatar
        .subjects
        .iter()
        .enumerate()
        .filter_map(|(index, slot)| slot.model.as_ref().map(|m| (index, m)))
        .map(|(index, model)| {
            let camera = default_camera(&model.skeleton, width, height)?;
            // The ray through the principal point is the optical axis; the camera looks
            // at the point this far along it.
            let k = camera.intrinsics_rows();
            let (centre, forward) = camera.ray_through(glam::DVec2::new(k[0][2], k[1][2]));
            let orbit_target = centre + forward * talkin_render::sequence::DEFAULT_CAMERA_DISTANCE;
            Ok(ServedSubject {
                name: model.name.clone(),
                index,
                default_camera: camera,
                orbit_target,
            })
        })
        .collect()
}

/// The camera a subject gets when a request brings none (shared with `talkin render`).
pub use talkin_render::sequence::default_camera;
