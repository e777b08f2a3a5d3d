//! `talkin bench ablations`: the paper's ablations (Tables 1 and 3) on a dataset, each
//! variant trained for the same wall-clock budget with the same recipe and seed, and
//! evaluated on held-out frames:
//!
//! - `full`: the method, one multi-identity model;
//! - `w/o D_hands`, `w/o background`, `w/o jaw in e`: one switch off each;
//! - `single-identity`: one model per subject trained on that subject alone (the same
//!   budget per model, so three times the total compute of `full`), each scored on its
//!   own subject's frames.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::shared::{Scores, avatar_of, thin, train_to_end, write_report};
use crate::speed_vs_error::spread_frames;
use talkin_data::dataset::{Dataset, Split};
use talkin_render::eval::{EvalOptions, evaluate};
use talkin_train::{Ablation, Budget, Identities, TrainOptions};

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct AblationOptions {
    /// Training seconds per model.
    pub budget_s: f64,
    /// Frames per evaluated split, evenly spaced (0: all).
    pub eval_frames: usize,
    pub train: TrainOptions,
    pub lpips_dir: Option<PathBuf>,
}

/// One variant on one split.
#[derive(Clone, Debug, Serialize)]
pub struct AblationRow {
    pub variant: String,
    pub split: String,
    pub frames: usize,
    pub psnr: f64,
    pub ssim: f64,
    pub lpips: Option<f64>,
    pub psnr_face: Option<f64>,
    pub psnr_hands: Option<f64>,
    pub steps: usize,
}

pub use crate::error::BenchError as AblationError;

const SPLITS: [Split; 2] = [Split::TestSame, Split::TestCross];

/// Runs every variant; writes `out/ablations.json`, `out/ablations.md` and the runs under
/// `out/runs/`.
pub fn ablations(
    dataset: &Dataset,
    out: &Path,
    opts: &AblationOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<AblationRow>, AblationError> {
    if !(opts.budget_s.is_finite() && opts.budget_s > 0.0) {
        return Err(AblationError::BadOption {
            field: "minutes",
            problem: "must be a positive number".into(),
        });
    }
    let base = TrainOptions {
        budget: Budget::Seconds(opts.budget_s),
        checkpoint_every_s: f64::INFINITY,
        identities: Identities::All,
        ..opts.train.clone()
    };
    let eval_opts = EvalOptions {
        renders_dir: None,
        lpips_dir: opts.lpips_dir.clone(),
        smooth: false,
        anchors: false,
    };
    let mut rows = variant_rows(dataset, out, opts, &base, &eval_opts, progress)?;
    rows.extend(single_identity_rows(
        dataset, out, opts, &base, &eval_opts, progress,
    )?);
    write_outputs(out, &rows)?;
    Ok(rows)
}

/// The full method and each switch off, trained from `base` and scored on every split.
fn variant_rows(
    dataset: &Dataset,
    out: &Path,
    opts: &AblationOptions,
    base: &TrainOptions,
    eval_opts: &EvalOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<AblationRow>, AblationError> {
    let full = Ablation::default();
    let variants = [
        ("full", full),
        (
            "w/o D_hands",
            Ablation {
                use_d_hands: false,
                ..full
            },
        ),
        (
            "w/o background",
            Ablation {
                hand_background: false,
                ..full
            },
        ),
        (
            "w/o jaw in e",
            Ablation {
                face_uses_jaw: false,
                ..full
            },
        ),
    ];
    let mut rows = Vec::new();
    for (name, ablation) in variants {
        progress(&format!("training `{name}` for {:.0} s", opts.budget_s));
        let run = out.join("runs").join(slug(name));
        let trainer = train_to_end(
            dataset,
            &run,
            &TrainOptions {
                ablation,
                ..base.clone()
            },
        )?;
        let avatar = avatar_of(&trainer);
        for split in SPLITS {
            let frames = spread_frames(dataset, split, opts.eval_frames);
            if frames.is_empty() {
                continue;
            }
            progress(&format!(
                "evaluating `{name}` on {} {split} frames",
                frames.len()
            ));
            let report = evaluate(&avatar, dataset, &frames, eval_opts)?;
            rows.push(row(
                name,
                split,
                frames.len(),
                &Scores::of(&report),
                trainer.steps_taken(),
            ));
        }
    }
    Ok(rows)
}

/// One model per subject, each scored on its own subject's frames, merged per split.
fn single_identity_rows(
    dataset: &Dataset,
    out: &Path,
    opts: &AblationOptions,
    base: &TrainOptions,
    eval_opts: &EvalOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<AblationRow>, AblationError> {
    let mut rows = Vec::new();
    let mut per_split: Vec<Vec<(usize, Scores)>> = vec![Vec::new(); SPLITS.len()];
    let mut steps = 0;
    for (s, subject) in dataset.subjects.iter().enumerate() {
        let own = |split| -> Vec<usize> {
            let frames: Vec<usize> = dataset
                .split_indices(split)
                .into_iter()
                .filter(|&i| dataset.frames[i].subject == s)
                .collect();
            thin(
                &frames,
                opts.eval_frames.div_ceil(dataset.subjects.len().max(1)),
            )
        };
        if dataset
            .split_indices(Split::Train)
            .iter()
            .all(|&i| dataset.frames[i].subject != s)
        {
            continue;
        }
        progress(&format!(
            "training single-identity `{}` for {:.0} s",
            subject.name, opts.budget_s
        ));
        let run = out.join("runs").join(format!("single-{}", subject.name));
        let trainer = train_to_end(
            dataset,
            &run,
            &TrainOptions {
                identities: Identities::Named(vec![subject.name.clone()]),
                ..base.clone()
            },
        )?;
        steps += trainer.steps_taken();
        let avatar = avatar_of(&trainer);
        for (k, split) in SPLITS.into_iter().enumerate() {
            let frames = own(split);
            if !frames.is_empty() {
                let report = evaluate(&avatar, dataset, &frames, eval_opts)?;
                per_split[k].push((frames.len(), Scores::of(&report)));
            }
        }
    }
    for (k, split) in SPLITS.into_iter().enumerate() {
        if let Some(merged) = merge(&per_split[k]) {
            let n = per_split[k].iter().map(|r| r.0).sum();
            rows.push(row("single-identity", split, n, &merged, steps));
        }
    }
    Ok(rows)
}

fn row(name: &str, split: Split, frames: usize, r: &Scores, steps: usize) -> AblationRow {
    AblationRow {
        variant: name.into(),
        split: split.name().into(),
        frames,
        psnr: r.psnr,
        ssim: r.ssim,
        lpips: r.lpips,
        psnr_face: r.psnr_face,
        psnr_hands: r.psnr_hands,
        steps,
    }
}

/// Frame-weighted mean of several models' averages.
fn merge(scores: &[(usize, Scores)]) -> Option<Scores> {
    let total: usize = scores.iter().map(|r| r.0).sum();
    if total == 0 {
        return None;
    }
    let mean = |f: &dyn Fn(&Scores) -> f64| {
        scores.iter().map(|(n, r)| *n as f64 * f(r)).sum::<f64>() / total as f64
    };
    let mean_opt = |f: &dyn Fn(&Scores) -> Option<f64>| {
        scores
            .iter()
            .map(|(n, r)| f(r).map(|v| *n as f64 * v))
            .sum::<Option<f64>>()
            .map(|v| v / total as f64)
    };
    Some(Scores {
        psnr: mean(&|r| r.psnr),
        ssim: mean(&|r| r.ssim),
        lpips: mean_opt(&|r| r.lpips),
        psnr_person: mean_opt(&|r| r.psnr_person),
        psnr_face: mean_opt(&|r| r.psnr_face),
        psnr_hands: mean_opt(&|r| r.psnr_hands),
    })
}

fn slug(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect::<String>()
        .replace("--", "-")
}

/// The rows as a Markdown table (the README's).
pub fn format_table(rows: &[AblationRow]) -> String {
    let opt = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
    let mut t = String::from(
        "| variant | split | frames | PSNR | SSIM | LPIPS* | face PSNR | hands PSNR |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        t.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.4} | {} | {} | {} |\n",
            r.variant,
            r.split,
            r.frames,
            r.psnr,
            r.ssim,
            opt(r.lpips, 1),
            opt(r.psnr_face, 2),
            opt(r.psnr_hands, 2)
        ));
    }
    t
}

fn write_outputs(out: &Path, rows: &[AblationRow]) -> Result<(), AblationError> {
    write_report(
        out,
        "ablations",
        &serde_json::to_vec_pretty(rows).expect("plain data serialises"),
        &format_table(rows),
    )
}
