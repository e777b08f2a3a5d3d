//! Contact sheet: frames with a segmentation tint and the projected skeleton drawn on.

use image::RgbImage;

use crate::census::spread;
use crate::dataset::{Dataset, DatasetError, Split};
use crate::draw;
use talkin_human::body::{N_JOINTS, PARENTS, skeleton::part_of_joint};

/// Colour of the strip above a tile, per split.
const SPLIT_COLOURS: [[u8; 3]; 4] = [[90, 90, 90], [40, 110, 220], [220, 120, 30], [200, 40, 40]];

/// A contact sheet of up to `max_frames` frames spread evenly over the dataset (every
/// split represented): each tile is the image with a 35% segmentation tint, bones drawn in
/// their part's colour, joints as white dots, and a strip on top coloured by split
/// (grey train, blue test_same, orange test_cross, red test_ood). Returns the sheet and
/// the frame index of each tile.
pub fn contact_sheet(
    dataset: &Dataset,
    max_frames: usize,
) -> Result<(RgbImage, Vec<usize>), DatasetError> {
    let chosen = pick_frames(dataset, max_frames.max(1));
    let tiles = chosen
        .iter()
        .map(|&i| tile(dataset, i))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((draw::contact_grid(tiles), chosen))
}

fn pick_frames(dataset: &Dataset, max_frames: usize) -> Vec<usize> {
    let mut chosen = Vec::new();
    let splits: Vec<Vec<usize>> = Split::ALL
        .iter()
        .map(|s| dataset.split_indices(*s))
        .filter(|v| !v.is_empty())
        .collect();
    let per_split = (max_frames / splits.len().max(1)).max(1);
    for frames in &splits {
        chosen.extend(spread(frames, per_split));
    }
    chosen.truncate(max_frames);
    chosen.sort_unstable();
    chosen
}

fn tile(dataset: &Dataset, index: usize) -> Result<RgbImage, DatasetError> {
    let images = dataset.images(index)?;
    let frame = &dataset.frames[index];
    let mut img = images.rgb;
    for (x, y, seg) in images.segmentation.enumerate_pixels() {
        let label = seg.0[0] as usize;
        if label > 0 {
            draw::blend(
                &mut img,
                x as i64,
                y as i64,
                draw::LABEL_COLOURS[label],
                0.35,
            );
        }
    }
    let posed = dataset.subjects[frame.subject].skeleton.pose(&frame.params);
    let px: Vec<Option<(f64, f64)>> = (0..N_JOINTS)
        .map(|j| frame.camera.project(posed.joint(j)).map(|p| (p.x, p.y)))
        .collect();
    let width = if img.width() >= 256 { 2 } else { 1 };
    for j in 1..N_JOINTS {
        let p = PARENTS[j] as usize;
        if let (Some(a), Some(b)) = (px[p], px[j]) {
            draw::line(
                &mut img,
                a,
                b,
                draw::LABEL_COLOURS[part_of_joint(p).label() as usize],
                width,
            );
        }
    }
    for q in px.iter().flatten() {
        draw::dot(&mut img, *q, [255, 255, 255], 0);
    }
    let split = Split::ALL
        .iter()
        .position(|s| *s == frame.split)
        .expect("split in ALL");
    for y in 0..3.min(img.height()) {
        for x in 0..img.width() {
            img.put_pixel(x, y, image::Rgb(SPLIT_COLOURS[split]));
        }
    }
    Ok(img)
}
