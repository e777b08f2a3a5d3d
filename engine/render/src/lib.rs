//! render: a trained avatar at work. Owns loading a run's checkpoint for inference,
//! rendering frames and pose sequences (with contact sheets), and evaluation: PSNR,
//! SSIM and LPIPS* on the full frame, the face and the hands.
//!
//! Must not know about training steps, the server or the experiments; it reads
//! checkpoints through `talkin-avatar`'s checkpoint module and never writes one.

pub mod avatar;
pub mod crops;
pub mod eval;
pub mod metrics;
pub mod sequence;
