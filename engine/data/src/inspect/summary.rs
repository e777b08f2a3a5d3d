//! Decoding every frame and summarising what a dataset holds and whether it is sound.

use rayon::prelude::*;

use crate::dataset::OFF_BY;
use crate::dataset::{
    Composited, Dataset, DatasetError, LABEL_NAMES, Matting, N_LABELS, Split, Surroundings,
};
use talkin_human::body::{N_BODY_JOINTS, N_JOINTS};

/// What one frame's pixels say about its fit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameCheck {
    pub frame: usize,
    /// Person pixels (`mask >= 128`).
    pub person_pixels: u64,
    /// Body joints (0..22) that project inside the image.
    pub joints_in_image: u32,
    /// Of those, the ones on a person pixel.
    pub joints_on_person: u32,
    /// The frame had no segmentation file; its labels were derived.
    pub labels_derived: bool,
    /// Pixels where `mask >= 128` disagrees with `segmentation > 0` (0 when derived).
    pub disagreeing_pixels: u64,
    pub pixels: u64,
    /// How far the image file's pixels outside the mask lie from the declared background.
    #[serde(skip)]
    pub surroundings: Surroundings,
    /// Share of those pixels off the background (`Surroundings::off_share`).
    pub surroundings_off_share: f32,
    /// The file is composited by its mask for training and scoring: the dataset says so
    /// (`"matting": "by_mask"`), or it says matted and the surroundings contradict it.
    pub composited: bool,
}

impl FrameCheck {
    /// Share of the in-image projected body joints that land on the person (1 when none
    /// lands in the image, which [`Summary::problems`] reports on its own).
    pub fn joints_on_person_share(&self) -> f64 {
        if self.joints_in_image == 0 {
            1.0
        } else {
            f64::from(self.joints_on_person) / f64::from(self.joints_in_image)
        }
    }
}

/// What `talkin inspect` prints.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub subjects: Vec<String>,
    /// Frames per split, per subject: `[subject][split]` in `Split::ALL` order.
    pub frames_per_split: Vec<[usize; 4]>,
    pub image_sizes: Vec<(u32, u32)>,
    /// Fraction of all pixels with each segmentation label.
    pub label_fractions: [f64; N_LABELS],
    /// Frames in which each label is absent (e.g. hands never visible).
    pub frames_without_label: [usize; N_LABELS],
    /// Fraction of pixels where `mask >= 128` disagrees with `segmentation > 0`, over the
    /// frames with a segmentation file.
    pub mask_seg_disagreement: f64,
    /// Fraction of in-image projected body joints (0..22) that land on the person mask:
    /// low values mean poses or cameras do not line up with the images.
    pub joints_on_person: f64,
    pub frames_with_depth: usize,
    /// The dataset's declared matting.
    #[serde(serialize_with = "matting_name")]
    pub matting: Matting,
    /// Frames declared matted whose surroundings contradict the background.
    pub contradicting_frames: Vec<usize>,
    /// Per frame, in dataset order.
    pub frames: Vec<FrameCheck>,
}

fn matting_name<S: serde::Serializer>(m: &Matting, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(m.name())
}

/// Decodes every frame (in parallel) and summarises; the first broken file is the error.
pub fn summarize(
    dataset: &Dataset,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Summary, DatasetError> {
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut label_counts = vec![[0u64; N_LABELS]; dataset.frames.len()];
    let checks: Vec<FrameCheck> = (0..dataset.frames.len())
        .into_par_iter()
        .zip(label_counts.par_iter_mut())
        .map(|(i, labels)| {
            let check = check_frame(dataset, i, labels)?;
            progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
            Ok(check)
        })
        .collect::<Result<_, DatasetError>>()?;

    let mut frames_per_split = vec![[0usize; 4]; dataset.subjects.len()];
    for f in &dataset.frames {
        let s = Split::ALL
            .iter()
            .position(|s| *s == f.split)
            .expect("every split is in ALL");
        frames_per_split[f.subject][s] += 1;
    }
    let mut image_sizes: Vec<(u32, u32)> = dataset
        .frames
        .iter()
        .map(|f| (f.camera.width, f.camera.height))
        .collect();
    image_sizes.sort_unstable();
    image_sizes.dedup();
    let total_pixels: u64 = checks.iter().map(|f| f.pixels).sum();
    let mut label_fractions = [0.0; N_LABELS];
    let mut frames_without_label = [0; N_LABELS];
    for labels in &label_counts {
        for l in 0..N_LABELS {
            label_fractions[l] += labels[l] as f64 / total_pixels.max(1) as f64;
            frames_without_label[l] += usize::from(labels[l] == 0);
        }
    }
    let in_image: u32 = checks.iter().map(|f| f.joints_in_image).sum();
    let on_person: u32 = checks.iter().map(|f| f.joints_on_person).sum();
    let labelled = checks.iter().filter(|c| !c.labels_derived);
    let labelled_pixels: u64 = labelled.clone().map(|c| c.pixels).sum();
    let disagreeing: u64 = labelled.map(|c| c.disagreeing_pixels).sum();
    Ok(Summary {
        subjects: dataset.subjects.iter().map(|s| s.name.clone()).collect(),
        frames_per_split,
        image_sizes,
        label_fractions,
        frames_without_label,
        mask_seg_disagreement: disagreeing as f64 / labelled_pixels.max(1) as f64,
        joints_on_person: if in_image == 0 {
            0.0
        } else {
            on_person as f64 / in_image as f64
        },
        frames_with_depth: dataset.frames.iter().filter(|f| f.depth.is_some()).count(),
        matting: dataset.matting,
        contradicting_frames: checks
            .iter()
            .filter(|c| dataset.matting != Matting::ByMask && c.surroundings.contradicts())
            .map(|c| c.frame)
            .collect(),
        frames: checks,
    })
}

/// Decodes frame `i` (and its depth), counts its labels into `labels` and checks its fit.
fn check_frame(
    dataset: &Dataset,
    i: usize,
    labels: &mut [u64; N_LABELS],
) -> Result<FrameCheck, DatasetError> {
    let images = dataset.images(i)?;
    dataset.depth(i)?;
    let mut disagreeing_pixels = 0;
    let mut person_pixels = 0;
    for (seg, mask) in images.segmentation.pixels().zip(images.mask.pixels()) {
        labels[seg.0[0] as usize] += 1;
        disagreeing_pixels += u64::from((seg.0[0] > 0) != (mask.0[0] >= 128));
        person_pixels += u64::from(mask.0[0] >= 128);
    }
    let frame = &dataset.frames[i];
    let posed = dataset.subjects[frame.subject].skeleton.pose(&frame.params);
    let (mut joints_in_image, mut joints_on_person) = (0, 0);
    for j in 0..N_BODY_JOINTS.min(N_JOINTS) {
        let Some(p) = frame.camera.project(posed.joint(j)) else {
            continue;
        };
        let (x, y) = (p.x.floor(), p.y.floor());
        if x < 0.0 || y < 0.0 || x >= frame.camera.width as f64 || y >= frame.camera.height as f64 {
            continue;
        }
        joints_in_image += 1;
        joints_on_person += u32::from(images.mask.get_pixel(x as u32, y as u32).0[0] >= 128);
    }
    Ok(FrameCheck {
        frame: i,
        person_pixels,
        joints_in_image,
        joints_on_person,
        labels_derived: images.labels_derived,
        disagreeing_pixels: if images.labels_derived {
            0
        } else {
            disagreeing_pixels
        },
        pixels: images.mask.len() as u64,
        surroundings: images.surroundings,
        surroundings_off_share: images.surroundings.off_share,
        composited: images.composited != Composited::No,
    })
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "subjects: {}", self.subjects.len())?;
        writeln!(
            f,
            "  {:<16} {:>6} {:>10} {:>11} {:>9}",
            "name", "train", "test_same", "test_cross", "test_ood"
        )?;
        for (name, n) in self.subjects.iter().zip(&self.frames_per_split) {
            writeln!(
                f,
                "  {name:<16} {:>6} {:>10} {:>11} {:>9}",
                n[0], n[1], n[2], n[3]
            )?;
        }
        let sizes: Vec<String> = self
            .image_sizes
            .iter()
            .map(|(w, h)| format!("{w}x{h}"))
            .collect();
        writeln!(f, "image sizes: {}", sizes.join(", "))?;
        write!(f, "pixels by label:")?;
        for l in 0..N_LABELS {
            write!(
                f,
                " {} {:.2}%",
                LABEL_NAMES[l],
                100.0 * self.label_fractions[l]
            )?;
        }
        writeln!(f)?;
        write!(f, "frames missing a label:")?;
        for l in 1..N_LABELS {
            write!(f, " {} {}", LABEL_NAMES[l], self.frames_without_label[l])?;
        }
        writeln!(f)?;
        writeln!(
            f,
            "mask vs segmentation disagreement: {:.3}% of pixels",
            100.0 * self.mask_seg_disagreement
        )?;
        writeln!(
            f,
            "projected body joints on the person mask: {:.1}%",
            100.0 * self.joints_on_person
        )?;
        let derived: Vec<usize> = self
            .frames
            .iter()
            .filter(|c| c.labels_derived)
            .map(|c| c.frame)
            .collect();
        if !derived.is_empty() {
            writeln!(
                f,
                "frames whose part labels were derived from the mask and the posed \
                 capsules (no segmentation file): {}",
                frame_list(&derived)
            )?;
        }
        writeln!(
            f,
            "frames with ground-truth depth: {}",
            self.frames_with_depth
        )?;
        let mut off: Vec<f32> = self
            .frames
            .iter()
            .map(|c| c.surroundings_off_share)
            .collect();
        off.sort_by(f32::total_cmp);
        let median = off.get(off.len() / 2).copied().unwrap_or(0.0);
        let max = off.last().copied().unwrap_or(0.0);
        write!(
            f,
            "image files outside the mask, off the background by more than {:.0}/255: \
             median {:.1}%, worst {:.1}% of pixels; ",
            OFF_BY * 255.0,
            100.0 * median,
            100.0 * max
        )?;
        match self.matting {
            Matting::ByMask => write!(
                f,
                "matting \"by_mask\": every frame is composited over the background by its mask"
            ),
            Matting::Matted | Matting::Reshown { .. } if self.contradicting_frames.is_empty() => {
                write!(
                    f,
                    "matting \"matted\": the images show the person over the background"
                )
            }
            Matting::Matted | Matting::Reshown { .. } => write!(
                f,
                "matting \"matted\", but {} frames are not over the background: {}",
                self.contradicting_frames.len(),
                frame_list(&self.contradicting_frames)
            ),
        }
    }
}

/// Frame indices as ranges: `0-3, 7, 9-12`.
pub(crate) fn frame_list(frames: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut k = 0;
    while k < frames.len() {
        let start = frames[k];
        let mut end = start;
        while k + 1 < frames.len() && frames[k + 1] == end + 1 {
            k += 1;
            end = frames[k];
        }
        parts.push(if start == end {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
        k += 1;
    }
    parts.join(", ")
}
