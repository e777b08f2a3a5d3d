//! PLACEHOLDER while the evaluation module is written on its own branch: full-frame PSNR
//! only. Replaced on merge.

use std::path::PathBuf;

use crate::avatar::{Avatar, AvatarError};
use crate::dataset::{Dataset, DatasetError};

pub struct EvalOptions {
    pub renders_dir: Option<PathBuf>,
    pub lpips_dir: Option<PathBuf>,
    pub smooth: bool,
}

#[derive(Clone, Debug)]
pub struct EvalReport {
    pub psnr: f64,
    pub ssim: f64,
    pub lpips: Option<f64>,
    pub psnr_face: Option<f64>,
    pub psnr_hands: Option<f64>,
    pub lpips_note: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Avatar(#[from] AvatarError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

pub fn evaluate(
    avatar: &Avatar,
    dataset: &Dataset,
    frames: &[usize],
    _opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let mut total = 0.0;
    for &i in frames {
        let f = &dataset.frames[i];
        let (s, _) = avatar.subject(&dataset.subjects[f.subject].name)?;
        let r = avatar.render(s, &f.params, &f.camera, None)?;
        let gt = dataset.images(i)?.rgb;
        let mut se = 0.0f64;
        for (a, b) in r.rgb.iter().zip(gt.as_raw()) {
            let d = f64::from(*a) - f64::from(*b) / 255.0;
            se += d * d;
        }
        let mse = se / r.rgb.len() as f64;
        total += -10.0 * mse.max(1e-12).log10();
    }
    Ok(EvalReport {
        psnr: total / frames.len().max(1) as f64,
        ssim: f64::NAN,
        lpips: None,
        psnr_face: None,
        psnr_hands: None,
        lpips_note: None,
    })
}
