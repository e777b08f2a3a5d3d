//! Rays in posed (world) space and their convention.

use glam::Vec3;

use crate::GridError;

/// Tolerance on `|direction| - 1` accepted by [`Ray::validate`].
pub const UNIT_TOLERANCE: f32 = 1e-3;

/// A ray in posed (world) space: the points `origin + t * direction` for
/// `t_min <= t <= t_max`.
///
/// Convention: `direction` has unit length, so `t` is a distance in metres along the ray;
/// `t_min` is finite (usually the near plane, may be 0), `t_max` may be `f32::INFINITY`.
/// Every query validates its rays and returns [`GridError`] for NaN/inf origins or
/// directions, non-unit directions and `t_min > t_max`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub direction: Vec3,
    pub t_min: f32,
    pub t_max: f32,
}

impl Ray {
    /// A ray with `direction` normalised (it may have any non-zero finite length).
    pub fn new(origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Result<Ray, GridError> {
        let direction = direction.try_normalize().ok_or(GridError::NonFiniteRay {
            index: 0,
            field: "direction (zero, NaN or inf)",
        })?;
        let ray = Ray {
            origin,
            direction,
            t_min,
            t_max,
        };
        ray.validate(0)?;
        Ok(ray)
    }

    /// The point at distance `t` along the ray, in world space.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.direction
    }

    /// Checks the convention above; `index` only labels the error.
    pub fn validate(&self, index: usize) -> Result<(), GridError> {
        if !self.origin.is_finite() {
            return Err(GridError::NonFiniteRay {
                index,
                field: "origin",
            });
        }
        if !self.direction.is_finite() {
            return Err(GridError::NonFiniteRay {
                index,
                field: "direction",
            });
        }
        let length = self.direction.length();
        if (length - 1.0).abs() > UNIT_TOLERANCE {
            return Err(GridError::DirectionNotUnit { index, length });
        }
        if !self.t_min.is_finite() {
            return Err(GridError::NonFiniteRay {
                index,
                field: "t_min",
            });
        }
        if self.t_max.is_nan() {
            return Err(GridError::NonFiniteRay {
                index,
                field: "t_max",
            });
        }
        if self.t_min > self.t_max {
            return Err(GridError::EmptyRayRange {
                index,
                t_min: self.t_min,
                t_max: self.t_max,
            });
        }
        Ok(())
    }
}

/// Validates every ray of a batch, reporting the first bad one.
pub fn validate_rays(rays: &[Ray]) -> Result<(), GridError> {
    rays.iter().enumerate().try_for_each(|(i, r)| r.validate(i))
}

/// The part `[t0, t1]` of the ray's range inside the box `[min, max]`, or `None`.
/// Slab test in f64 so axis-parallel rays and large coordinates stay exact enough.
pub fn clip_to_box(ray: &Ray, min: Vec3, max: Vec3) -> Option<(f32, f32)> {
    let mut t0 = ray.t_min as f64;
    let mut t1 = ray.t_max as f64;
    for axis in 0..3 {
        let o = ray.origin[axis] as f64;
        let d = ray.direction[axis] as f64;
        let (lo, hi) = (min[axis] as f64, max[axis] as f64);
        if d == 0.0 {
            if o < lo || o > hi {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = ((lo - o) / d, (hi - o) / d);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        t0 = t0.max(a);
        t1 = t1.min(b);
    }
    (t0 <= t1).then_some((t0 as f32, t1 as f32))
}
