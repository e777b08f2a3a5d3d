//! The head's frame: offsets authored for a 1.0 head around the head joint, scaled by the
//! subject's head factor; the face and the table rows both place their points in it.

use glam::Vec3;

/// Face layout in the head's rest space: offsets from the head joint, scaled by the head
/// factor.
#[derive(Clone, Copy, Debug)]
pub(super) struct HeadFrame {
    pub joint: Vec3,
    pub k: f32,
}

impl HeadFrame {
    pub const CENTRE: Vec3 = Vec3::new(0.0, 0.095, 0.012);
    pub const RADII: Vec3 = Vec3::new(0.077, 0.102, 0.093);
    pub const EYE_Y: f32 = 0.1;
    pub const MOUTH_Y: f32 = 0.045;
    pub const EYE_X: f32 = 0.031;
    pub const EYE_R: f32 = 0.0125;

    pub fn new(joint: glam::DVec3, k: f64) -> Self {
        Self {
            joint: joint.as_vec3(),
            k: k as f32,
        }
    }
    pub fn at(&self, x: f32, y: f32, z: f32) -> glam::DVec3 {
        (self.joint + Vec3::new(x, y, z) * self.k).as_dvec3()
    }
    pub fn p(&self, x: f32, y: f32, z: f32) -> Vec3 {
        self.joint + Vec3::new(x, y, z) * self.k
    }
    /// z (unscaled offset) of the head ellipsoid's front surface at (x, y).
    pub fn front(x: f32, y: f32) -> f32 {
        let d = Vec3::new(x, y - Self::CENTRE.y, 0.0) / Self::RADII;
        Self::CENTRE.z + Self::RADII.z * (1.0 - d.x * d.x - d.y * d.y).max(0.0).sqrt()
    }
    pub fn eye_centre(&self, sign: f32) -> Vec3 {
        let x = sign * Self::EYE_X;
        self.p(
            x,
            Self::EYE_Y,
            Self::front(x, Self::EYE_Y) - Self::EYE_R + 0.0035,
        )
    }
}
