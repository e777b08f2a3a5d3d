use std::path::PathBuf;

use anyhow::Context;

use super::inspect::{self, InspectArgs};
use super::synth::{self, SynthArgs};

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Working directory for the scene and every result.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let data = args.out.join("data");
    let defaults = talkin_engine::synth::SynthConfig::default();
    println!("== 1/2 generate the synthetic scene -> {}", data.display());
    synth::generate(&SynthArgs {
        out: data.clone(),
        identities: defaults.identities,
        frames: defaults.frames,
        size: defaults.size,
        seed: args.seed,
        motion: None,
    })?;
    let sheet = args.out.join("contact_sheet.png");
    println!("== 2/2 validate it and write a contact sheet");
    inspect::run(InspectArgs {
        dir: data,
        sheet: Some(sheet),
        sheet_frames: 16,
        joints_json: Some(args.out.join("joints.json")),
    })
}
