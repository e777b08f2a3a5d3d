//! Dense against accelerated sampling on a freshly generated small synthetic scene, in
//! one run: samples per foreground ray, rays per second and surface misses, the same
//! report as `talkin bench sampling` (which runs on the full default scene).
//!
//! `cargo bench --bench sampling` (env `FRAMES` per identity, default 12; `SIZE`,
//! default 128).

use talkin_benches::sampling::{bench_sampling, format_report};
use talkin_data::dataset::Dataset;
use talkin_synth::{SynthConfig, generate};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join("talkin-bench-sampling");
    let cfg = SynthConfig {
        identities: 1,
        frames: env("FRAMES", 12),
        size: env("SIZE", 128) as u32,
        seed: 0,
        motion: None,
        capture: None,
        framing: None,
    };
    // Scene generation is set-up, outside every timed part.
    generate(&cfg, &dir, &mut |_, _| {})?;
    let dataset = Dataset::load(&dir)?;
    let report = bench_sampling(&dataset, None, &mut |_, _| {})?;
    println!("{}", format_report(&report));
    Ok(())
}
