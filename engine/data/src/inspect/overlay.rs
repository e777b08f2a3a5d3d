//! The overlay check: frames with their fitted body drawn on the image (the posed limb
//! capsules' outlines and the skeleton, in part colours) and the share of projected body
//! joints on the person, so a user sees at once whether fits and cameras line up.

use image::RgbImage;
use talkin_human::body::{N_JOINTS, PARENTS, limb_capsules, skeleton::part_of_joint};

use crate::dataset::{Dataset, DatasetError};
use crate::draw;

use super::summary::Summary;
use super::validate::FRAME_MIN_JOINTS_ON_PERSON;

/// Frames for an overlay sheet of at most `max_frames`: the flagged ones (lowest share of
/// joints on the person first), then frames spread evenly over the rest.
pub fn overlay_frames(summary: &Summary, max_frames: usize) -> Vec<usize> {
    let mut flagged: Vec<_> = summary
        .frames
        .iter()
        .filter(|c| c.joints_on_person_share() < FRAME_MIN_JOINTS_ON_PERSON)
        .collect();
    flagged.sort_by(|a, b| {
        a.joints_on_person_share()
            .total_cmp(&b.joints_on_person_share())
    });
    let mut chosen: Vec<usize> = flagged.iter().map(|c| c.frame).take(max_frames).collect();
    let rest: Vec<usize> = (0..summary.frames.len())
        .filter(|i| !chosen.contains(i))
        .collect();
    let room = max_frames.saturating_sub(chosen.len()).min(rest.len());
    chosen.extend((0..room).map(|k| rest[k * rest.len() / room]));
    chosen
}

/// The overlay sheet of `frames` (see [`overlay_frames`]), tiles in the given order.
pub fn overlay_sheet(
    dataset: &Dataset,
    summary: &Summary,
    frames: &[usize],
) -> Result<RgbImage, DatasetError> {
    let tiles = frames
        .iter()
        .map(|&i| overlay_tile(dataset, summary, i))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(draw::contact_grid(tiles))
}

/// One frame: the image file as it is (not composited: the fit is judged against what
/// the camera saw), each posed capsule's outline and the skeleton in part colours,
/// a caption with the frame index and its share of body joints on the person (red when
/// flagged).
fn overlay_tile(dataset: &Dataset, summary: &Summary, i: usize) -> Result<RgbImage, DatasetError> {
    let frame = &dataset.frames[i];
    let skeleton = &dataset.subjects[frame.subject].skeleton;
    let posed = skeleton.pose(&frame.params);
    let camera = &frame.camera;
    let mut img = dataset.file_rgb(i)?;
    let fx = camera.intrinsics.x_axis.x;
    let pixel = |p: glam::DVec3| camera.project(p).map(|q| ((q.x, q.y), fx / q.z.max(1e-9)));
    for c in limb_capsules(skeleton, &posed) {
        if let (Some((a, ka)), Some((b, kb))) = (pixel(c.a.as_dvec3()), pixel(c.b.as_dvec3())) {
            let r = f64::from(c.radius);
            let colour = draw::LABEL_COLOURS[c.part.label() as usize];
            draw::capsule_outline(&mut img, a, b, (r * ka, r * kb), colour);
        }
    }
    let joints: Vec<Option<(f64, f64)>> = (0..N_JOINTS)
        .map(|j| pixel(posed.joint(j)).map(|(p, _)| p))
        .collect();
    for j in 1..N_JOINTS {
        let p = PARENTS[j] as usize;
        if let (Some(a), Some(b)) = (joints[p], joints[j]) {
            let colour = draw::LABEL_COLOURS[part_of_joint(p).label() as usize];
            draw::line(&mut img, a, b, colour, 1);
        }
    }
    for q in joints.iter().flatten() {
        draw::dot(&mut img, *q, [255, 255, 255], 1);
    }
    let check = &summary.frames[i];
    let share = check.joints_on_person_share();
    let caption = format!("#{i} {:.0}%", 100.0 * share);
    let colour = if share < FRAME_MIN_JOINTS_ON_PERSON {
        [230, 30, 30]
    } else {
        [20, 20, 20]
    };
    let height = (img.height() as f32 / 14.0).clamp(10.0, 28.0);
    draw::label(&mut img, &caption, 3, 2, height, colour);
    Ok(img)
}
