//! Training losses and image metrics: MSE, cross-entropy on rendered segmentation logits,
//! SSIM, and LPIPS (AlexNet or VGG16 backbone, v0.1 linear heads) with SSIM as the
//! fallback perceptual loss when the LPIPS weights are absent.
//!
//! Everything here is backend-generic (the burn [`Device`](burn::tensor::Device) picks the
//! backend) and differentiable with respect to the prediction.
//!
//! Image conventions: [`ssim`] and [`PerceptualLoss`] take `[N, 3, H, W]` images in
//! `[0, 1]`; [`Lpips::forward`] takes them in `[-1, 1]` like the original `lpips` package
//! ([`Lpips::forward_unit`] takes `[0, 1]`).

mod error;
mod lpips;
mod perceptual;
mod pixel;
mod ssim;
mod weights_dir;

pub use error::LossError;
pub use lpips::{Backbone, Lpips};
pub use perceptual::{PerceptualKind, PerceptualLoss};
pub use pixel::{PixelInputs, PixelLoss, PixelWeights, mse, pixel_loss, seg_cross_entropy};
pub use ssim::{SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW, ssim, ssim_loss};
pub use weights_dir::{DEFAULT_LPIPS_DIR, LPIPS_DIR_ENV, lpips_weights_dir};
