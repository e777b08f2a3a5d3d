//! `talkin bench convergence`: whether a recipe gets better the longer it trains. The
//! same recipe trains one run per budget (each with its own schedule, as a user running
//! `--steps N` gets) and seed; each run is scored on its held-out frames (test_same) and
//! on as many of its training frames, by the anchors' protocol and by how thick the
//! person renders ([`talkin_render::eval::thickness_inside`]). A field that memorises
//! its frames scores well early and falls on held-out frames as budget grows; one that
//! stays a cloud keeps its thickness in centimetres.

mod plot;

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::BenchError;
use crate::shared::{avatar_of, thin, train_to_end, write_report};
use talkin_data::dataset::{Dataset, Split};
use talkin_render::eval::{EvalOptions, EvalReport, evaluate};
use talkin_train::{Budget, TrainOptions};

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct ConvergenceOptions {
    /// Training steps of each run.
    pub budgets: Vec<usize>,
    pub seeds: Vec<u64>,
    /// Training frames scored, evenly spaced (0: all); held-out frames are all scored.
    pub train_frames: usize,
    /// The recipe (the budget and seed are each run's).
    pub train: TrainOptions,
    pub lpips_dir: Option<PathBuf>,
    /// Score by the anchors' protocol too (LPIPS-VGG: about 10 s a 512x512 frame).
    pub anchors: bool,
    /// The colour truth and render are composited over when scored (`talkin eval`'s
    /// `--background`; a capture's is black); `None`: the dataset's own.
    pub score_over: Option<[f32; 3]>,
}

/// One split's scores at one budget.
#[derive(Clone, Debug, Serialize)]
pub struct Mark {
    pub frames: usize,
    pub psnr_person: Option<f64>,
    pub ssim_person: Option<f64>,
    /// x1000, AlexNet.
    pub lpips_person: Option<f64>,
    pub psnr_inside: Option<f64>,
    /// The anchors' protocol: whole frame PSNR, scikit-image SSIM, LPIPS-VGG x1000.
    pub anchors_psnr: Option<f64>,
    pub anchors_ssim: Option<f64>,
    pub anchors_lpips_vgg: Option<f64>,
    pub thickness_median_mm: Option<f64>,
    pub thickness_p90_mm: Option<f64>,
}

impl Mark {
    fn of(r: &EvalReport) -> Mark {
        Mark {
            frames: r.frames_evaluated,
            psnr_person: r.psnr_person,
            ssim_person: r.ssim_person,
            lpips_person: r.lpips_person,
            psnr_inside: r.person_inside.map(|m| m.psnr),
            anchors_psnr: r.anchors.map(|a| a.psnr),
            anchors_ssim: r.anchors.map(|a| a.ssim),
            anchors_lpips_vgg: r.anchors.and_then(|a| a.lpips_vgg),
            thickness_median_mm: r.thickness_inside.map(|t| t.median_mm),
            thickness_p90_mm: r.thickness_inside.map(|t| t.p90_mm),
        }
    }
}

/// One run: a budget and a seed.
#[derive(Clone, Debug, Serialize)]
pub struct Point {
    pub steps: usize,
    pub seed: u64,
    /// Wall seconds of training (the machine's, not comparable across machines).
    pub train_seconds: f64,
    pub held_out: Mark,
    pub training: Mark,
}

/// `convergence.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub points: Vec<Point>,
    pub held_out_split: &'static str,
    pub training_frames_scored: usize,
}

/// Trains and scores every budget and seed; writes `out/convergence.json`,
/// `out/convergence.md`, `out/convergence.png` and the runs with their scored renders
/// under `out/runs/`.
pub fn convergence(
    dataset: &Dataset,
    out: &Path,
    opts: &ConvergenceOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Summary, BenchError> {
    if opts.budgets.is_empty() || opts.budgets.contains(&0) {
        return Err(BenchError::bad(
            "budgets",
            "expected a list of step counts above 0",
        ));
    }
    if opts.seeds.is_empty() {
        return Err(BenchError::bad("seeds", "expected at least one seed"));
    }
    let held_out = dataset.split_indices(Split::TestSame);
    if held_out.is_empty() {
        return Err(BenchError::bad(
            "data",
            "the dataset has no test_same frame to score",
        ));
    }
    let training = thin(&dataset.split_indices(Split::Train), opts.train_frames);
    let mut scored = dataset.clone();
    if let Some(rgb) = opts.score_over {
        scored.show_over(rgb).map_err(|e| {
            BenchError::bad(
                "score_over",
                &format!("the truth cannot be shown over it: {e}"),
            )
        })?;
    }
    let mut points = Vec::new();
    for &seed in &opts.seeds {
        for &steps in &opts.budgets {
            let name = format!("steps{steps}-seed{seed}");
            let run = out.join("runs").join(&name);
            progress(&format!("{name}: training"));
            let train = TrainOptions {
                budget: Budget::Steps(steps),
                seed,
                checkpoint_every_s: f64::INFINITY,
                ..opts.train.clone()
            };
            let start = std::time::Instant::now();
            let trainer = train_to_end(dataset, &run, &train)?;
            let train_seconds = start.elapsed().as_secs_f64();
            let mut avatar = avatar_of(&trainer);
            if let Some(rgb) = opts.score_over {
                avatar.background = rgb;
            }
            let mut score = |split: &str, frames: &[usize]| -> Result<Mark, BenchError> {
                progress(&format!("{name}: scoring {} {split} frames", frames.len()));
                let eval = EvalOptions {
                    renders_dir: Some(run.join(format!("eval_{split}_renders"))),
                    lpips_dir: opts.lpips_dir.clone(),
                    smooth: false,
                    anchors: opts.anchors,
                };
                Ok(Mark::of(&evaluate(&avatar, &scored, frames, &eval)?))
            };
            let point = Point {
                steps,
                seed,
                train_seconds,
                held_out: score("test_same", &held_out)?,
                training: score("train", &training)?,
            };
            progress(&format!("{name}: {}", row(&point)));
            points.push(point);
        }
    }
    let summary = Summary {
        points,
        held_out_split: "test_same",
        training_frames_scored: training.len(),
    };
    let json = serde_json::to_vec_pretty(&summary).expect("the summary serialises");
    write_report(out, "convergence", &json, &table(&summary))?;
    match plot::plot_points(&summary.points) {
        Ok(img) => {
            let file = out.join("convergence.png");
            let mut png = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .expect("encoding a PNG in memory");
            talkin_data::atomic::write_atomic(&file, &png)
                .map_err(|source| BenchError::Io { file, source })?;
        }
        Err(e) => progress(&format!("no plot: {e}")),
    }
    Ok(summary)
}

fn num(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".to_string(), |x| format!("{x:.digits$}"))
}

/// One point as a table row's cells after its steps and seed.
fn row(p: &Point) -> String {
    let m = |m: &Mark| {
        format!(
            "{} | {} | {} | {} / {} / {} | {} / {}",
            num(m.psnr_person, 2),
            num(m.lpips_person, 1),
            num(m.psnr_inside, 2),
            num(m.anchors_psnr, 2),
            num(m.anchors_ssim, 4),
            num(m.anchors_lpips_vgg, 1),
            num(m.thickness_median_mm, 1),
            num(m.thickness_p90_mm, 1),
        )
    };
    format!("{} | {}", m(&p.held_out), m(&p.training))
}

/// The Markdown table: a row per run, held-out then training frames.
pub fn table(s: &Summary) -> String {
    let mut t = String::from(
        "| steps | seed | train s | held-out box dB | box LPIPS* | inside dB | anchors PSNR / SSIM / LPIPS-VGG | thickness median / p90 mm | training box dB | box LPIPS* | inside dB | anchors PSNR / SSIM / LPIPS-VGG | thickness median / p90 mm |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for p in &s.points {
        t.push_str(&format!(
            "| {} | {} | {:.0} | {} |\n",
            p.steps,
            p.seed,
            p.train_seconds,
            row(p)
        ));
    }
    t
}
