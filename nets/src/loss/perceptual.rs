use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor};

use super::{Backbone, LossError, Lpips, ssim};

/// Which perceptual loss a [`PerceptualLoss`] computes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PerceptualKind {
    /// LPIPS with this backbone.
    Lpips(Backbone),
    /// `1 - SSIM`, the fallback when the LPIPS weights are absent.
    Ssim,
}

/// The perceptual term of the training loss: LPIPS when its weights file exists, otherwise
/// `1 - SSIM` (and [`fallback_reason`](Self::fallback_reason) says why).
#[derive(Debug)]
pub struct PerceptualLoss {
    lpips: Option<Lpips>,
    missing: Option<PathBuf>,
}

impl PerceptualLoss {
    /// LPIPS from `dir/<backbone.file_name()>` if that file exists, else the SSIM fallback.
    /// A file that exists but cannot be loaded is an error, never a silent fallback.
    pub fn from_dir(dir: &Path, backbone: Backbone, device: &Device) -> Result<Self, LossError> {
        Self::from_file(&dir.join(backbone.file_name()), backbone, device)
    }

    /// LPIPS from `path` if it exists, else the SSIM fallback. A file that exists but cannot
    /// be loaded is an error.
    pub fn from_file(path: &Path, backbone: Backbone, device: &Device) -> Result<Self, LossError> {
        if path.exists() {
            Ok(Self::lpips(Lpips::load(path, backbone, device)?))
        } else {
            Ok(PerceptualLoss {
                lpips: None,
                missing: Some(path.to_path_buf()),
            })
        }
    }

    /// Always LPIPS with these weights.
    pub fn lpips(lpips: Lpips) -> Self {
        PerceptualLoss {
            lpips: Some(lpips),
            missing: None,
        }
    }

    /// Always `1 - SSIM`.
    pub fn ssim() -> Self {
        PerceptualLoss {
            lpips: None,
            missing: None,
        }
    }

    /// Which loss this is.
    pub fn kind(&self) -> PerceptualKind {
        match &self.lpips {
            Some(l) => PerceptualKind::Lpips(l.backbone()),
            None => PerceptualKind::Ssim,
        }
    }

    /// When LPIPS was asked for but its file was absent: the message to print, e.g.
    /// `LPIPS weights not found at ~/.cache/talkin/lpips/alex.safetensors, falling back to SSIM`.
    pub fn fallback_reason(&self) -> Option<String> {
        self.missing.as_ref().map(|p| {
            format!(
                "LPIPS weights not found at {}, falling back to SSIM \
                 (run `talkin lpips-weights` to fetch them)",
                p.display()
            )
        })
    }

    /// Per-image loss: LPIPS distance, or `1 - SSIM`. Images in `[0, 1]`.
    ///
    /// # Shapes
    /// - `pred`, `target`: `[N, 3, H, W]`, `H, W >= 32` recommended (SSIM needs >= 11)
    /// - output: `[N]`
    pub fn forward(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        match &self.lpips {
            Some(l) => l.forward_unit(pred, target),
            None => ssim(pred, target).neg() + 1.0,
        }
    }
}
