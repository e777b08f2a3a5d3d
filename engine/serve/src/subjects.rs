//! The subjects a server renders and the camera each gets when a request brings none.
//!
//! A checkpoint stores no camera, so the default is built from the subject's rest skeleton
//! ([`default_camera`], in the render crate so that `talkin render` frames alike).

use talkin_human::camera::{Camera, CameraError};
use talkin_render::avatar::Avatar;

/// One trained subject as the server offers it.
#[derive(Clone, Debug)]
pub struct ServedSubject {
    pub name: String,
    /// Identity index in the avatar.
    pub index: usize,
    pub default_camera: Camera,
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
            Ok(ServedSubject {
                name: model.name.clone(),
                index,
                default_camera: default_camera(&model.skeleton, width, height)?,
            })
        })
        .collect()
}

/// The camera a subject gets when a request brings none (shared with `talkin render`).
pub use talkin_render::sequence::default_camera;
