//! LPIPS (v0.1 heads; AlexNet for the engine's LPIPS*, VGG16 for the anchors' protocol)
//! of image regions through `nets::loss::Lpips`.

use std::path::Path;

use burn::tensor::{Device, Tensor, TensorData};
use image::RgbImage;
use talkin_nets::loss::{Backbone, LossError, Lpips};

use crate::crops::MIN_CROP;
use crate::metrics::Rect;

/// The backbone evaluation reports (the paper's LPIPS and the `lpips` package default).
pub const BACKBONE: Backbone = Backbone::Alex;

/// LPIPS weights loaded on the device of the renders they score.
pub struct LpipsScorer {
    lpips: Lpips,
    backbone: Backbone,
    device: Device,
}

impl LpipsScorer {
    /// The scorer from `dir/alex.safetensors`: `Ok(Err(note))` when there is no directory or
    /// no weights file (then LPIPS is reported as null with that note); a file that exists
    /// but cannot be loaded is an error.
    pub fn from_dir(
        dir: Option<&Path>,
        device: &Device,
    ) -> Result<Result<LpipsScorer, String>, LossError> {
        LpipsScorer::with_backbone(dir, BACKBONE, device)
    }

    /// [`LpipsScorer::from_dir`] with `backbone`'s weights (`dir/<name>.safetensors`).
    pub fn with_backbone(
        dir: Option<&Path>,
        backbone: Backbone,
        device: &Device,
    ) -> Result<Result<LpipsScorer, String>, LossError> {
        let Some(dir) = dir else {
            return Ok(Err(
                "LPIPS not computed: no LPIPS weights directory was given".into(),
            ));
        };
        let file = dir.join(backbone.file_name());
        if !file.exists() {
            return Ok(Err(format!(
                "LPIPS not computed: weights not found at {} \
                 (run `talkin lpips-weights`)",
                file.display()
            )));
        }
        let lpips = Lpips::load(&file, backbone, device)?;
        Ok(Ok(LpipsScorer {
            lpips,
            backbone,
            device: device.clone(),
        }))
    }

    /// The backbone it scores with.
    pub fn backbone(&self) -> Backbone {
        self.backbone
    }

    /// LPIPS distance of `a` and `b` over `r` (not scaled); `None` for a region smaller
    /// than [`MIN_CROP`] on a side, which AlexNet cannot see (VGG16 sees 16 px).
    pub fn distance(&self, a: &RgbImage, b: &RgbImage, r: Rect) -> Option<f64> {
        if r.width < MIN_CROP || r.height < MIN_CROP {
            return None;
        }
        let tensor = |img: &RgbImage| {
            let (w, h) = (r.width as usize, r.height as usize);
            let mut v = vec![0.0f32; 3 * w * h];
            for y in 0..h {
                for x in 0..w {
                    let p = img.get_pixel(r.x + x as u32, r.y + y as u32).0;
                    for c in 0..3 {
                        v[(c * h + y) * w + x] = p[c] as f32 / 255.0;
                    }
                }
            }
            Tensor::<4>::from_data(TensorData::new(v, [1, 3, h, w]), &self.device)
        };
        let d: f32 = self.lpips.forward_unit(tensor(a), tensor(b)).into_scalar();
        Some(d as f64)
    }
}
