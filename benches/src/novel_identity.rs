//! `talkin bench novel-identity`: the paper's novel-identity experiment (section 4.3,
//! "Learning a novel identity") on a dataset. One multi-identity model is trained without
//! one subject; that subject is then learned from the first 1, 3, 10 or 30 seconds of its
//! video ([`Trainer::adapt`]: a new identity code, every parameter fine-tuned at
//! [`talkin_train::Preset::adapt_lr_ratio`] of the training rate), each adaptation with the same budget, and
//! every adapted model is scored on the same held-out frames of that subject: its
//! `test_same` frames after the longest clip (poses no clip shows) and its `test_ood`
//! frames (unseen arm, head and face ranges). Beside each adaptation, the paper's
//! HumanNeRF baseline: a fresh single-identity model trained on the same clip with the
//! same budget, so the table shows what the other subjects' prior buys.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::shared::{Scores, avatar_of, finish, thin, train_to_end, write_report};
use talkin_data::dataset::{Dataset, Split};
use talkin_render::eval::{EvalOptions, evaluate};
use talkin_train::{Budget, Identities, TrainOptions, Trainer};

pub use crate::error::BenchError as NovelIdentityError;

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct NovelIdentityOptions {
    /// The held-out subject; `None`: the dataset's last subject.
    pub subject: Option<String>,
    /// Clip lengths in seconds from the start of the subject's video (the paper: 1, 3,
    /// 10, 30).
    pub clips_s: Vec<f64>,
    /// The multi-identity model's budget (every other subject).
    pub base: Budget,
    /// A trained run to adapt instead of training the base model (it must not have
    /// trained the held-out subject).
    pub base_run: Option<PathBuf>,
    /// The adaptations' learning rate over the recipe's (default [`talkin_train::Preset::adapt_lr_ratio`]).
    pub adapt_lr_ratio: f64,
    /// Each adaptation's budget.
    pub adapt: Budget,
    /// Also train a fresh single-identity model on each clip with the same budget at the
    /// recipe's rate (the paper's HumanNeRF baseline: what the other subjects' prior buys).
    pub scratch: bool,
    /// Frames per evaluated split, evenly spaced (0: all).
    pub eval_frames: usize,
    /// The recipe of both stages (the adaptations at `adapt_lr_ratio` of its rate).
    pub train: TrainOptions,
    pub lpips_dir: Option<PathBuf>,
}

/// One adapted model on one split.
#[derive(Clone, Debug, Serialize)]
pub struct NovelIdentityRow {
    pub subject: String,
    /// `adapted` (the multi-identity model fine-tuned on the clip) or `scratch` (a
    /// single-identity model trained on the clip alone).
    pub model: String,
    /// The clip asked for, and the training frames and seconds of video it held.
    pub clip_s: f64,
    pub clip_frames: usize,
    pub clip_video_s: f64,
    pub split: String,
    pub frames: usize,
    #[serde(flatten)]
    pub scores: Scores,
    /// Steps taken on the clip.
    pub steps: usize,
}

/// Trains the base model, adapts it once per clip (and trains the from-scratch baseline
/// on it), scores each model; writes
/// `out/novel_identity.json`, `out/novel_identity.md` and the runs under `out/runs/`.
pub fn novel_identity(
    dataset: &Dataset,
    out: &Path,
    opts: &NovelIdentityOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<NovelIdentityRow>, NovelIdentityError> {
    let Plan {
        name,
        others,
        t0,
        eval_sets,
    } = plan(dataset, opts)?;
    let base_run = match &opts.base_run {
        Some(run) => run.clone(),
        None => {
            progress(&format!(
                "training the multi-identity model on {} (without `{name}`)",
                others.join(", ")
            ));
            let run = out.join("runs").join("base");
            train_to_end(
                dataset,
                &run,
                &TrainOptions {
                    budget: opts.base,
                    checkpoint_every_s: f64::INFINITY,
                    identities: Identities::Named(others),
                    ..opts.train.clone()
                },
            )?;
            run
        }
    };
    let adapt_opts = TrainOptions {
        budget: opts.adapt,
        checkpoint_every_s: f64::INFINITY,
        lr: Some(opts.train.initial_lr() * opts.adapt_lr_ratio),
        ..opts.train.clone()
    };
    let eval_opts = EvalOptions {
        renders_dir: None,
        lpips_dir: opts.lpips_dir.clone(),
        smooth: false,
        anchors: false,
    };
    // The baseline: the subject alone, from a fresh field, on the same clip and budget,
    // at the recipe's own rate.
    let scratch_opts = TrainOptions {
        budget: opts.adapt,
        checkpoint_every_s: f64::INFINITY,
        identities: Identities::Named(vec![name.clone()]),
        ..opts.train.clone()
    };
    let mut rows = Vec::new();
    for &clip in &opts.clips_s {
        let models: &[&str] = if opts.scratch {
            &["adapted", "scratch"]
        } else {
            &["adapted"]
        };
        for &model in models {
            let (trainer, doing) = if model == "adapted" {
                let run = out.join("runs").join(format!("adapt-{clip}s"));
                let clip_opts = TrainOptions {
                    clip_seconds: Some(clip),
                    ..adapt_opts.clone()
                };
                let trainer = Trainer::adapt(dataset, &base_run, &name, &run, &clip_opts)?;
                (trainer, "adapting the multi-identity model to")
            } else {
                let run = out.join("runs").join(format!("scratch-{clip}s"));
                let clip_opts = TrainOptions {
                    clip_seconds: Some(clip),
                    ..scratch_opts.clone()
                };
                (
                    Trainer::new(dataset, &run, &clip_opts)?,
                    "training from scratch on",
                )
            };
            // What the clip held, as the trainer cut it.
            let clip_frames = trainer.training_frames().len();
            let clip_video_s = trainer
                .training_frames()
                .iter()
                .map(|&i| dataset.frames[i].time - t0 + 1.0 / talkin_synth::FPS)
                .fold(0.0, f64::max);
            progress(&format!(
                "{doing} `{name}` from {clip} s of video ({clip_frames} training frames)"
            ));
            let trainer = finish(trainer)?;
            let avatar = avatar_of(&trainer);
            for (split, frames) in &eval_sets {
                let report = evaluate(&avatar, dataset, frames, &eval_opts)?;
                rows.push(NovelIdentityRow {
                    subject: name.clone(),
                    model: model.into(),
                    clip_s: clip,
                    clip_frames,
                    clip_video_s,
                    split: split.name().into(),
                    frames: frames.len(),
                    scores: Scores::of(&report),
                    steps: trainer.steps_taken(),
                });
            }
        }
    }
    write_report(
        out,
        "novel_identity",
        &serde_json::to_vec_pretty(&rows).expect("plain data serialises"),
        &format_table(&rows),
    )?;
    Ok(rows)
}

/// Who is held out, who the base model learns from, and the held-out frames every
/// model is scored on.
struct Plan {
    name: String,
    others: Vec<String>,
    /// The held-out subject's first training frame's time.
    t0: f64,
    eval_sets: Vec<(Split, Vec<usize>)>,
}

/// Checks the options against the dataset and plans the experiment.
fn plan(dataset: &Dataset, opts: &NovelIdentityOptions) -> Result<Plan, NovelIdentityError> {
    let bad = |field, problem: String| NovelIdentityError::BadOption { field, problem };
    if !(opts.adapt_lr_ratio.is_finite() && opts.adapt_lr_ratio > 0.0) {
        return Err(bad(
            "adapt_lr_ratio",
            format!("expected a positive number, found {}", opts.adapt_lr_ratio),
        ));
    }
    if opts.clips_s.is_empty() || !opts.clips_s.iter().all(|c| c.is_finite() && *c > 0.0) {
        return Err(bad("clips", "expected one or more positive seconds".into()));
    }
    let s = match &opts.subject {
        None => dataset.subjects.len().checked_sub(1),
        Some(name) => dataset.subject_index(name),
    }
    .ok_or_else(|| {
        bad(
            "subject",
            format!(
                "`{}` is not a subject of {} (it has {})",
                opts.subject.as_deref().unwrap_or("(last)"),
                dataset.root.display(),
                names(dataset)
            ),
        )
    })?;
    let name = dataset.subjects[s].name.clone();
    let others: Vec<String> = dataset
        .subjects
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != s && !dataset.subject_frames(i, Split::Train).is_empty())
        .map(|(_, x)| x.name.clone())
        .collect();
    if others.is_empty() {
        return Err(bad(
            "subject",
            format!("no other subject of {} has training frames", names(dataset)),
        ));
    }
    let video = dataset.subject_frames(s, Split::Train);
    let Some(&first) = video.first() else {
        return Err(bad("subject", format!("`{name}` has no training frames")));
    };
    let t0 = dataset.frames[first].time;
    let longest = opts.clips_s.iter().copied().fold(0.0, f64::max);
    // The same held-out frames for every clip: none inside the longest one.
    let eval_sets: Vec<(Split, Vec<usize>)> = [Split::TestSame, Split::TestOod]
        .into_iter()
        .map(|split| {
            let after: Vec<usize> = dataset
                .subject_frames(s, split)
                .into_iter()
                .filter(|&i| split != Split::TestSame || dataset.frames[i].time - t0 >= longest)
                .collect();
            (split, thin(&after, opts.eval_frames))
        })
        .filter(|(_, f)| !f.is_empty())
        .collect();
    if !eval_sets.iter().any(|(split, _)| *split == Split::TestSame) {
        let last = dataset.frames[*video.last().unwrap_or(&first)].time - t0;
        return Err(bad(
            "clips",
            format!(
                "`{name}` has {last:.2} s of video and no test_same frame after the \
                 longest clip ({longest} s); generate a longer video (e.g. `talkin synth \
                 --frames 800`: 40 s a subject) or ask for shorter clips"
            ),
        ));
    }
    Ok(Plan {
        name,
        others,
        t0,
        eval_sets,
    })
}

fn names(dataset: &Dataset) -> String {
    let all: Vec<&str> = dataset.subjects.iter().map(|x| x.name.as_str()).collect();
    all.join(", ")
}

/// The rows as a Markdown table (the README's).
pub fn format_table(rows: &[NovelIdentityRow]) -> String {
    let opt = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
    let mut t = String::from(
        "| subject | model | clip (s) | clip frames | split | frames | PSNR | SSIM | LPIPS* | face PSNR | hands PSNR | steps |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        t.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.4} | {} | {} | {} | {} |\n",
            r.subject,
            r.model,
            r.clip_s,
            r.clip_frames,
            r.split,
            r.frames,
            r.scores.psnr,
            r.scores.ssim,
            opt(r.scores.lpips, 1),
            opt(r.scores.psnr_face, 2),
            opt(r.scores.psnr_hands, 2),
            r.steps
        ));
    }
    t
}
