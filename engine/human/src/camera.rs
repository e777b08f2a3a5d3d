//! Pinhole cameras in the OpenCV convention: x right, y down, z forward; intrinsics K
//! (3x3) and extrinsics `camera_from_world` (4x4, world to camera). Pixel (x, y) covers
//! [x, x+1) x [y, y+1); its centre is (x + 0.5, y + 0.5).

use glam::{DAffine3, DMat3, DVec2, DVec3};

/// Largest image side accepted (pixels).
pub const MAX_SIDE: u32 = 16_384;

/// Why a camera was rejected. `field` is `width`, `height`, `intrinsics` or `extrinsics`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("camera {field}: {problem}")]
pub struct CameraError {
    pub field: &'static str,
    pub problem: String,
}

fn bad(field: &'static str, problem: impl Into<String>) -> CameraError {
    CameraError {
        field,
        problem: problem.into(),
    }
}

/// A validated pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    /// K: `[fx, s, cx; 0, fy, cy; 0, 0, 1]`.
    pub intrinsics: DMat3,
    pub camera_from_world: DAffine3,
    world_from_camera: DAffine3,
    intrinsics_inv: DMat3,
}

impl Camera {
    /// Validates and builds a camera from row-major K and 4x4 extrinsics (world to camera).
    /// Rejects zero or huge sizes, non-finite numbers, K whose last row is not [0 0 1] or
    /// whose focal lengths are not positive (singular or mirrored), and extrinsics whose
    /// last row is not [0 0 0 1] or whose rotation is not a proper rotation.
    pub fn new(
        width: u32,
        height: u32,
        k: [[f64; 3]; 3],
        extrinsics: [[f64; 4]; 4],
    ) -> Result<Camera, CameraError> {
        for (field, side) in [("width", width), ("height", height)] {
            if side == 0 || side > MAX_SIDE {
                return Err(bad(field, format!("{side} is not in 1..={MAX_SIDE}")));
            }
        }
        if k.iter().flatten().any(|x| !x.is_finite()) {
            return Err(bad("intrinsics", "contains a non-finite number"));
        }
        if k[2] != [0.0, 0.0, 1.0] || k[1][0] != 0.0 {
            return Err(bad(
                "intrinsics",
                format!("must be upper triangular with last row [0, 0, 1], got {k:?}"),
            ));
        }
        let (fx, fy) = (k[0][0], k[1][1]);
        if fx <= 1e-6 || fy <= 1e-6 {
            return Err(bad(
                "intrinsics",
                format!("focal lengths must be positive (singular K), got fx={fx}, fy={fy}"),
            ));
        }
        if extrinsics.iter().flatten().any(|x| !x.is_finite()) {
            return Err(bad("extrinsics", "contains a non-finite number"));
        }
        if extrinsics[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(bad(
                "extrinsics",
                format!("last row must be [0, 0, 0, 1], got {:?}", extrinsics[3]),
            ));
        }
        let col = |c: usize| DVec3::new(extrinsics[0][c], extrinsics[1][c], extrinsics[2][c]);
        let rotation = DMat3::from_cols(col(0), col(1), col(2));
        let orthonormal_error = (rotation.transpose() * rotation - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        if orthonormal_error > 1e-4 || rotation.determinant() < 0.0 {
            return Err(bad(
                "extrinsics",
                format!(
                    "top-left 3x3 must be a rotation (orthonormal, det +1); error {orthonormal_error:.2e}, det {:.4}",
                    rotation.determinant()
                ),
            ));
        }
        let intrinsics = DMat3::from_cols(
            DVec3::new(k[0][0], k[1][0], k[2][0]),
            DVec3::new(k[0][1], k[1][1], k[2][1]),
            DVec3::new(k[0][2], k[1][2], k[2][2]),
        );
        let camera_from_world = DAffine3::from_mat3_translation(rotation, col(3));
        Ok(Camera {
            width,
            height,
            intrinsics,
            camera_from_world,
            world_from_camera: camera_from_world.inverse(),
            intrinsics_inv: intrinsics.inverse(),
        })
    }

    /// A camera at `eye` looking at `target` with world `up` (y up in SMPL-X) projected to
    /// image "up" (-y in OpenCV).
    pub fn look_at(
        width: u32,
        height: u32,
        focal_px: f64,
        eye: DVec3,
        target: DVec3,
        up: DVec3,
    ) -> Result<Camera, CameraError> {
        let forward = (target - eye)
            .try_normalize()
            .ok_or_else(|| bad("extrinsics", "eye == target"))?;
        let right = forward
            .cross(up)
            .try_normalize()
            .ok_or_else(|| bad("extrinsics", "up is parallel to the view direction"))?;
        let down = forward.cross(right);
        // Rows of the rotation are the camera axes in world coordinates.
        let r = [right, down, forward];
        let t = [-right.dot(eye), -down.dot(eye), -forward.dot(eye)];
        let mut e = [[0.0; 4]; 4];
        for i in 0..3 {
            e[i] = [r[i].x, r[i].y, r[i].z, t[i]];
        }
        e[3] = [0.0, 0.0, 0.0, 1.0];
        let k = [
            [focal_px, 0.0, width as f64 / 2.0],
            [0.0, focal_px, height as f64 / 2.0],
            [0.0, 0.0, 1.0],
        ];
        Camera::new(width, height, k, e)
    }

    /// Row-major K, as the dataset stores it.
    pub fn intrinsics_rows(&self) -> [[f64; 3]; 3] {
        let m = self.intrinsics;
        [0, 1, 2].map(|r| m.row(r).to_array())
    }

    /// Row-major 4x4 world-to-camera matrix, as the dataset stores it.
    pub fn extrinsics_rows(&self) -> [[f64; 4]; 4] {
        let m = glam::DMat4::from(self.camera_from_world);
        [0, 1, 2, 3].map(|r| m.row(r).to_array())
    }

    /// Camera centre in world space.
    pub fn center_in_world(&self) -> DVec3 {
        self.world_from_camera.translation
    }

    /// World-space ray through continuous pixel coordinates (`x + 0.5` is pixel x's centre):
    /// origin at the camera centre, unit direction.
    pub fn ray_through(&self, pixel: DVec2) -> (DVec3, DVec3) {
        let dir_in_camera = self.intrinsics_inv * DVec3::new(pixel.x, pixel.y, 1.0);
        let dir_in_world = self.world_from_camera.transform_vector3(dir_in_camera);
        // K is invertible with positive focal lengths, so the direction is never zero.
        (self.center_in_world(), dir_in_world.normalize())
    }

    /// Ray through the centre of pixel (x, y).
    pub fn pixel_ray(&self, x: u32, y: u32) -> (DVec3, DVec3) {
        self.ray_through(DVec2::new(x as f64 + 0.5, y as f64 + 0.5))
    }

    /// Projects a world point to (pixel x, pixel y, depth along the optical axis). `None`
    /// for points at or behind the camera plane (depth <= 1e-9) or non-finite input.
    pub fn project(&self, p_world: DVec3) -> Option<DVec3> {
        let p_camera = self.camera_from_world.transform_point3(p_world);
        if !p_camera.is_finite() || p_camera.z <= 1e-9 {
            return None;
        }
        let uvw = self.intrinsics * p_camera;
        Some(DVec3::new(uvw.x / uvw.z, uvw.y / uvw.z, p_camera.z))
    }

    /// The optical axis (camera +z) in world space, unit length.
    pub fn forward_in_world(&self) -> DVec3 {
        self.world_from_camera.transform_vector3(DVec3::Z)
    }

    /// Depth along the optical axis of a point.
    pub fn depth_of(&self, p_world: DVec3) -> f64 {
        self.camera_from_world.transform_point3(p_world).z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frontal() -> Camera {
        Camera::look_at(
            256,
            320,
            400.0,
            DVec3::new(0.1, 0.3, 3.0),
            DVec3::new(0.0, 0.2, 0.0),
            DVec3::Y,
        )
        .unwrap()
    }

    #[test]
    fn ray_project_round_trip() {
        let cam = frontal();
        for (x, y) in [(0u32, 0u32), (255, 319), (128, 160), (17, 301)] {
            let (o, d) = cam.pixel_ray(x, y);
            assert!((d.length() - 1.0).abs() < 1e-12);
            for t in [0.5, 2.0, 10.0] {
                let uvz = cam.project(o + d * t).unwrap();
                assert!((uvz.x - (x as f64 + 0.5)).abs() < 1e-9);
                assert!((uvz.y - (y as f64 + 0.5)).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn opencv_axes_and_matrix_round_trip() {
        let cam = frontal();
        // The camera looks down -z of the world with y up: world +y is image up (smaller y).
        let above = cam.project(DVec3::new(0.0, 1.0, 0.0)).unwrap();
        let below = cam.project(DVec3::new(0.0, -1.0, 0.0)).unwrap();
        assert!(above.y < below.y);
        // The subject faces +z and +x is the subject's left, which the camera sees on the
        // image's right.
        let left = cam.project(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        assert!(left.x > cam.intrinsics.z_axis.x);
        let again = Camera::new(
            cam.width,
            cam.height,
            cam.intrinsics_rows(),
            cam.extrinsics_rows(),
        )
        .unwrap();
        assert!((again.center_in_world() - cam.center_in_world()).length() < 1e-12);
        assert!(cam.project(cam.center_in_world()).is_none());
        assert!(
            cam.project(DVec3::new(0.0, 0.0, 10.0)).is_none(),
            "behind the camera"
        );
    }

    #[test]
    fn degenerate_cameras_are_rejected() {
        let good = frontal();
        let (k, e) = (good.intrinsics_rows(), good.extrinsics_rows());
        let mut singular = k;
        singular[1][1] = 0.0;
        assert_eq!(
            Camera::new(256, 320, singular, e).unwrap_err().field,
            "intrinsics"
        );
        let mut nan = k;
        nan[0][2] = f64::NAN;
        assert_eq!(
            Camera::new(256, 320, nan, e).unwrap_err().field,
            "intrinsics"
        );
        let mut scaled = e;
        for row in scaled.iter_mut().take(3) {
            row[0] *= 2.0;
        }
        assert_eq!(
            Camera::new(256, 320, k, scaled).unwrap_err().field,
            "extrinsics"
        );
        let mut mirrored = e;
        for row in mirrored.iter_mut().take(3) {
            row[0] = -row[0];
        }
        assert_eq!(
            Camera::new(256, 320, k, mirrored).unwrap_err().field,
            "extrinsics"
        );
        assert_eq!(Camera::new(0, 320, k, e).unwrap_err().field, "width");
        assert!(Camera::look_at(8, 8, 10.0, DVec3::ZERO, DVec3::ZERO, DVec3::Y).is_err());
        assert!(Camera::look_at(8, 8, 10.0, DVec3::ZERO, DVec3::Y, DVec3::Y).is_err());
    }
}
