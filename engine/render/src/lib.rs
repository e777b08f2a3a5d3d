//! render: a trained avatar ([`talkin_avatar::Avatar`]) at work. Owns rendering frames
//! and pose sequences (with contact sheets), and evaluation: PSNR, SSIM and LPIPS* on the
//! full frame, the face and the hands.
//!
//! Must not know about training steps, the server or the experiments; it loads avatars
//! through `talkin-avatar` and never writes a checkpoint.

pub mod avatar;
pub mod crops;
pub mod eval;
pub mod metrics;
pub mod sequence;
