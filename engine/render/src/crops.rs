//! Person, face and hand crops from the projected skeleton.
//!
//! Person: the box of the projected corners of the posed body's 3D bounds (every capsule,
//! the head's grown for hair) padded by [`PERSON_PAD_M`], clipped to the image: Neural
//! Body's and Instant-NVR's evaluation region, so a large background cannot hide a foggy
//! person.
//! Face: the bounding square of the projected head, jaw and eye joints and of the head
//! capsule (each end a sphere of the capsule's radius, times [`HEAD_GROWTH`] for hair).
//! Hands: the bounding square of the projected wrist and finger joints and of the hand's
//! capsules (finger tips included), grown by [`HAND_MARGIN`]. Every crop is a square of at
//! least [`MIN_CROP`] px (LPIPS needs it), shrunk to the image's shorter side and shifted
//! inside the image. A part whose box misses the image, or that lies behind the camera,
//! gives no crop and says why.

use glam::DVec3;
use serde::Serialize;
use talkin_grids::Part;

use crate::metrics::Rect;
use talkin_human::body::joint::*;
use talkin_human::body::{FrameParams, Skeleton, limb_capsules};
use talkin_human::camera::Camera;

/// Smallest crop side in pixels (AlexNet LPIPS needs >= 31).
pub const MIN_CROP: u32 = 32;
/// The head capsule is the bare skull; hair and ears stick out of it by about this factor.
pub const HEAD_GROWTH: f64 = 1.3;
/// Hand boxes grow by this fraction of their side (finger thickness, cloth at the cuff).
pub const HAND_MARGIN: f64 = 0.25;

/// The person box pads the body's 3D bounds by this much (metres), as Neural Body does
/// around the SMPL vertices.
pub const PERSON_PAD_M: f64 = 0.05;

/// Which crop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CropKind {
    Person,
    Face,
    LeftHand,
    RightHand,
}

impl CropKind {
    pub const ALL: [CropKind; 4] = [
        CropKind::Person,
        CropKind::Face,
        CropKind::LeftHand,
        CropKind::RightHand,
    ];

    pub const fn name(self) -> &'static str {
        match self {
            CropKind::Person => "person",
            CropKind::Face => "face",
            CropKind::LeftHand => "left_hand",
            CropKind::RightHand => "right_hand",
        }
    }
}

/// Spheres (centre, radius in metres) and joints whose projections a crop must cover.
struct Cover {
    joints: Vec<usize>,
    spheres: Vec<(DVec3, f64)>,
    growth: f64,
}

/// The crops of a frame: for each kind its square, or why there is none.
pub fn frame_crops(
    skeleton: &Skeleton,
    params: &FrameParams,
    camera: &Camera,
) -> Vec<(CropKind, Result<Rect, String>)> {
    let posed = skeleton.pose(params);
    let capsules = limb_capsules(skeleton, &posed);
    let head_spheres = capsules
        .iter()
        .filter(|c| c.part == Part::Head)
        .flat_map(|c| {
            let r = c.radius as f64 * HEAD_GROWTH;
            [(c.a.as_dvec3(), r), (c.b.as_dvec3(), r)]
        })
        .collect();
    let hand = |wrist: usize, first: usize| {
        let in_hand = |bone: usize| bone == wrist || (first..first + 15).contains(&bone);
        Cover {
            joints: std::iter::once(wrist).chain(first..first + 15).collect(),
            spheres: capsules
                .iter()
                .filter(|c| c.part == Part::Hands && in_hand(c.bone as usize))
                .flat_map(|c| {
                    let r = c.radius as f64;
                    [(c.a.as_dvec3(), r), (c.b.as_dvec3(), r)]
                })
                .collect(),
            growth: 1.0 + HAND_MARGIN,
        }
    };
    let covers = [
        (
            CropKind::Face,
            Cover {
                joints: vec![HEAD, JAW, LEFT_EYE, RIGHT_EYE],
                spheres: head_spheres,
                growth: 1.0,
            },
        ),
        (CropKind::LeftHand, hand(LEFT_WRIST, LEFT_HAND_FIRST)),
        (CropKind::RightHand, hand(RIGHT_WRIST, RIGHT_HAND_FIRST)),
    ];
    let person = person_box(
        camera,
        capsules.iter().flat_map(|c| {
            let r = c.radius as f64
                * if c.part == Part::Head {
                    HEAD_GROWTH
                } else {
                    1.0
                };
            [(c.a.as_dvec3(), r), (c.b.as_dvec3(), r)]
        }),
    );
    std::iter::once((CropKind::Person, person))
        .chain(covers.into_iter().map(|(kind, cover)| {
            let points = cover
                .joints
                .iter()
                .map(|&j| (posed.joint(j), 0.0))
                .chain(cover.spheres);
            (kind, square_crop(camera, points, cover.growth))
        }))
        .collect()
}

/// The box of the projected corners of the 3D bounds of `spheres` padded by
/// [`PERSON_PAD_M`], clipped to the image, at least [`MIN_CROP`] px a side where the image
/// allows.
fn person_box(
    camera: &Camera,
    spheres: impl Iterator<Item = (DVec3, f64)>,
) -> Result<Rect, String> {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for (c, r) in spheres {
        lo = lo.min(c - r);
        hi = hi.max(c + r);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Err("no finite body bounds".into());
    }
    let (lo, hi) = (lo - PERSON_PAD_M, hi + PERSON_PAD_M);
    let (mut a, mut b) = (
        glam::DVec2::splat(f64::INFINITY),
        glam::DVec2::splat(f64::NEG_INFINITY),
    );
    for k in 0..8 {
        let corner = DVec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let Some(p) = camera.project(corner) else {
            return Err("the body's bounds reach behind the camera".into());
        };
        a = a.min(p.truncate());
        b = b.max(p.truncate());
    }
    let (w, h) = (camera.width as f64, camera.height as f64);
    if b.x <= 0.0 || b.y <= 0.0 || a.x >= w || a.y >= h {
        return Err(format!(
            "outside the image (projected box x {:.0}..{:.0}, y {:.0}..{:.0} in {}x{})",
            a.x, b.x, a.y, b.y, camera.width, camera.height
        ));
    }
    // Grow a thin box to MIN_CROP about its centre, then clip to the image.
    let grow = |lo: f64, hi: f64, limit: f64| {
        let side = (hi - lo).max(MIN_CROP as f64).min(limit);
        let c = ((lo + hi) * 0.5).clamp(side / 2.0, limit - side / 2.0);
        let (l, h) = (
            (c - side / 2.0).floor().max(0.0),
            (c + side / 2.0).ceil().min(limit),
        );
        (l as u32, (h - l) as u32)
    };
    let (x, width) = grow(a.x.max(0.0), b.x.min(w), w);
    let (y, height) = grow(a.y.max(0.0), b.y.min(h), h);
    Ok(Rect {
        x,
        y,
        width,
        height,
    })
}

/// The square covering the projections of `spheres` (centre, radius in metres), grown by
/// `growth`, at least [`MIN_CROP`] px, inside the image.
fn square_crop(
    camera: &Camera,
    spheres: impl Iterator<Item = (DVec3, f64)>,
    growth: f64,
) -> Result<Rect, String> {
    let focal = camera.intrinsics.x_axis.x.max(camera.intrinsics.y_axis.y);
    let (mut lo, mut hi) = (
        glam::DVec2::splat(f64::INFINITY),
        glam::DVec2::splat(f64::NEG_INFINITY),
    );
    for (centre, radius) in spheres {
        let Some(p) = camera.project(centre) else {
            return Err("behind the camera".into());
        };
        let r = focal * radius / p.z;
        lo = lo.min(p.truncate() - r);
        hi = hi.max(p.truncate() + r);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Err("no finite projection".into());
    }
    let (w, h) = (camera.width as f64, camera.height as f64);
    if hi.x <= 0.0 || hi.y <= 0.0 || lo.x >= w || lo.y >= h {
        return Err(format!(
            "outside the image (projected box x {:.0}..{:.0}, y {:.0}..{:.0} in {}x{})",
            lo.x, hi.x, lo.y, hi.y, camera.width, camera.height
        ));
    }
    let size = hi - lo;
    let side = (size.x.max(size.y) * growth)
        .ceil()
        .max(MIN_CROP as f64)
        .min(w.min(h));
    let centre = (lo + hi) * 0.5;
    let place = |c: f64, limit: f64| (c - side / 2.0).round().clamp(0.0, limit - side) as u32;
    let side_px = side as u32;
    Ok(Rect {
        x: place(centre.x, w),
        y: place(centre.y, h),
        width: side_px,
        height: side_px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A T-pose-ish skeleton: every joint a small step up and out from its parent.
    fn skeleton() -> Skeleton {
        Skeleton::stick_figure()
    }

    #[test]
    fn crops_are_inside_squares_covering_their_joints() {
        let s = skeleton();
        let cam = Camera::look_at(
            120,
            160,
            200.0,
            DVec3::new(0.0, 1.2, 3.0),
            DVec3::new(0.0, 1.2, 0.0),
            DVec3::Y,
        )
        .unwrap();
        let p = FrameParams::default();
        let posed = s.pose(&p);
        for (kind, crop) in frame_crops(&s, &p, &cam) {
            let r = crop.unwrap();
            assert!(r.is_inside(cam.width, cam.height), "{kind:?} {r:?}");
            assert!(r.width >= MIN_CROP && r.height >= MIN_CROP);
            if kind == CropKind::Person {
                // The whole body: every joint, with room around it.
                for j in 0..talkin_human::body::N_JOINTS {
                    let q = cam.project(posed.joint(j)).unwrap();
                    assert!(r.contains(q.x, q.y), "{j} {r:?} misses {q:?}");
                }
                continue;
            }
            assert_eq!(r.width, r.height);
            let j = match kind {
                CropKind::Person => unreachable!(),
                CropKind::Face => HEAD,
                CropKind::LeftHand => LEFT_WRIST,
                CropKind::RightHand => RIGHT_WRIST,
            };
            let q = cam.project(posed.joint(j)).unwrap();
            assert!(r.contains(q.x, q.y), "{kind:?} {r:?} misses {q:?}");
        }
    }

    #[test]
    fn crops_off_screen_or_behind_are_skipped_with_a_reason() {
        let s = skeleton();
        // Looking far to the side: nothing of the person is in view.
        let away = Camera::look_at(
            64,
            64,
            80.0,
            DVec3::new(0.0, 1.2, 3.0),
            DVec3::new(30.0, 1.2, 3.0),
            DVec3::Y,
        )
        .unwrap();
        for (_, crop) in frame_crops(&s, &FrameParams::default(), &away) {
            let why = crop.unwrap_err();
            assert!(why.contains("outside") || why.contains("behind"), "{why}");
        }
        // A small image: the crop shrinks to the image, still inside.
        let tiny = Camera::look_at(
            24,
            40,
            20.0,
            DVec3::new(0.0, 1.2, 3.0),
            DVec3::new(0.0, 1.2, 0.0),
            DVec3::Y,
        )
        .unwrap();
        for (_, crop) in frame_crops(&s, &FrameParams::default(), &tiny) {
            let r = crop.unwrap();
            assert!(r.is_inside(24, 40) && r.width == 24, "{r:?}");
        }
    }
}
