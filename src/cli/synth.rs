use std::path::PathBuf;

use talkin_data::dataset::Dataset;
use talkin_data::motion;
use talkin_synth as synth;

use crate::progress::Progress;

#[derive(clap::Args, Debug, Clone)]
pub struct SynthArgs {
    /// Output directory (created; an existing dataset there is overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of identities (subjects).
    #[arg(long, default_value_t = synth::SynthConfig::default().identities)]
    pub identities: usize,
    /// Training frames per identity.
    #[arg(long, default_value_t = synth::SynthConfig::default().frames)]
    pub frames: usize,
    /// Image height in pixels (width is 3/4 of it).
    #[arg(long, default_value_t = synth::SynthConfig::default().size)]
    pub size: u32,
    /// Seed of every random choice: the same arguments give byte-identical output.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Render ground truth for this motion instead of the built-in one: a JSON list of
    /// `params` objects, or a BEAT2 or AMASS .npz (`poses` N x 165, ...; see
    /// docs/dataset-format.md), its frames as stored.
    #[arg(long)]
    pub motion: Option<PathBuf>,
}

pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let dataset = generate(&args)?;
    println!(
        "wrote {} frames of {} subjects to {}",
        dataset.frames.len(),
        dataset.subjects.len(),
        args.out.display()
    );
    Ok(())
}

/// Generates the dataset `args` describe, showing progress.
pub fn generate(args: &SynthArgs) -> anyhow::Result<Dataset> {
    let motion = args.motion.as_ref().map(motion::load_motion).transpose()?;
    let cfg = synth::SynthConfig {
        identities: args.identities,
        frames: args.frames,
        size: args.size,
        seed: args.seed,
        motion,
    };
    let mut progress: Option<Progress> = None;
    let dataset = synth::generate(&cfg, &args.out, &mut |done, total| {
        progress
            .get_or_insert_with(|| Progress::new("synth", total, "frames"))
            .update(done, "")
    })?;
    Ok(dataset)
}
