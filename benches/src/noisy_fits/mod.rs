//! `talkin bench noisy-fits`: what pose refinement recovers from noisy fits. For each
//! noise level, the training fits get known, seeded noise (`noise`; held-out frames
//! keep their clean fits); the same recipe then trains with and without
//! `--refine-poses` for the same budget, and each run is scored on test_same (clean
//! poses), next to the training fits' error against the truth before and after
//! refinement.

mod noise;
mod plot;

use std::path::{Path, PathBuf};

use serde::Serialize;

pub use noise::{joint_position_error, joint_rotation_error, noisy};

use crate::error::BenchError;
use crate::shared::{Scores, avatar_of, train_to_end, write_report};
use crate::speed_vs_error::spread_frames;
use talkin_data::dataset::{Dataset, Split};
use talkin_render::eval::{EvalOptions, evaluate};
use talkin_train::refine::RefineMode;
use talkin_train::{Budget, TrainOptions};

/// What the benchmark is told.
#[derive(Clone, Debug)]
pub struct NoisyFitsOptions {
    /// Noise levels (degrees RMS per joint).
    pub levels_deg: Vec<f64>,
    /// Training seconds per run.
    pub budget_s: f64,
    /// test_same frames scored, evenly spaced (0: all).
    pub eval_frames: usize,
    pub train: TrainOptions,
    pub lpips_dir: Option<PathBuf>,
}

/// One noise level.
#[derive(Clone, Debug, Serialize)]
pub struct Level {
    pub noise_deg: f64,
    pub psnr_without: f64,
    pub psnr_with: f64,
    pub without: Scores,
    pub with: Scores,
    /// Mean posed-joint position error of the training fits against the truth (metres):
    /// the noisy fits, and the refined ones.
    pub joint_error_before_m: f64,
    pub joint_error_after_m: f64,
    /// Mean joint-rotation error (degrees) over the joints the noise turns.
    pub rotation_error_before_deg: f64,
    pub rotation_error_after_deg: f64,
    pub steps_without: usize,
    pub steps_with: usize,
}

/// `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub levels: Vec<Level>,
    pub budget_s: f64,
    pub eval_frames: usize,
    pub training_frames: usize,
}

/// Runs every level; writes `out/summary.json`, `out/noisy_fits.md`, `out/noisy_fits.png`,
/// the noisy datasets under `out/data/` and the runs under `out/runs/`.
pub fn noisy_fits(
    dataset: &Dataset,
    out: &Path,
    opts: &NoisyFitsOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<Summary, BenchError> {
    if !(opts.budget_s.is_finite() && opts.budget_s > 0.0) {
        return Err(BenchError::bad("minutes-each", "must be a positive number"));
    }
    if opts.levels_deg.is_empty()
        || opts
            .levels_deg
            .iter()
            .any(|d| !(d.is_finite() && *d >= 0.0))
    {
        return Err(BenchError::bad(
            "noise-deg",
            "expected a list of degrees >= 0",
        ));
    }
    let train_frames = dataset.split_indices(Split::Train);
    if train_frames.is_empty() {
        return Err(BenchError::bad("data", "the dataset has no training frame"));
    }
    let eval_frames = spread_frames(dataset, Split::TestSame, opts.eval_frames);
    if eval_frames.is_empty() {
        return Err(BenchError::bad(
            "data",
            "the dataset has no test_same frame to score",
        ));
    }
    let eval_opts = EvalOptions {
        renders_dir: None,
        lpips_dir: opts.lpips_dir.clone(),
        smooth: false,
        anchors: false,
    };
    let mut levels = Vec::new();
    for &deg in &opts.levels_deg {
        let name = format!("noise-{deg}deg");
        let data_dir = out.join("data").join(&name);
        let noisy_set = noisy_dataset(dataset, &data_dir, deg)?;
        let mut scores = Vec::new();
        let mut runs = Vec::new();
        for refine in [RefineMode::Off, RefineMode::On] {
            let label = if refine == RefineMode::On {
                "with"
            } else {
                "without"
            };
            progress(&format!(
                "{deg} degrees: training {label} refinement for {:.0} s",
                opts.budget_s
            ));
            let mut train = TrainOptions {
                budget: Budget::Seconds(opts.budget_s),
                checkpoint_every_s: f64::INFINITY,
                ..opts.train.clone()
            };
            train.refine.refine_poses = refine;
            let run = out.join("runs").join(format!("{name}-{label}"));
            let trainer = train_to_end(&noisy_set, &run, &train)?;
            progress(&format!(
                "{deg} degrees: scoring {label} refinement on {} test_same frames",
                eval_frames.len()
            ));
            let avatar = avatar_of(&trainer);
            let report = evaluate(&avatar, &noisy_set, &eval_frames, &eval_opts)?;
            scores.push(Scores::of(&report));
            let refined: Vec<_> = train_frames
                .iter()
                .map(|&i| {
                    trainer.refiner().map_or_else(
                        || noisy_set.frames[i].params.clone(),
                        |r| r.params_of(&noisy_set, i),
                    )
                })
                .collect();
            runs.push((trainer.steps_taken(), refined));
        }
        let error = |fits: &[talkin_human::body::FrameParams]| {
            let n = train_frames.len() as f64;
            let (mut pos, mut rot) = (0.0, 0.0);
            for (&i, fit) in train_frames.iter().zip(fits) {
                let truth = &dataset.frames[i].params;
                let skeleton = &dataset.subjects[dataset.frames[i].subject].skeleton;
                pos += joint_position_error(skeleton, truth, fit);
                rot += joint_rotation_error(truth, fit);
            }
            (pos / n, rot / n)
        };
        let (pos_before, rot_before) = error(&runs[0].1);
        let (pos_after, rot_after) = error(&runs[1].1);
        let (without, with) = (scores[0].clone(), scores[1].clone());
        let level = Level {
            noise_deg: deg,
            psnr_without: without.psnr,
            psnr_with: with.psnr,
            without,
            with,
            joint_error_before_m: pos_before,
            joint_error_after_m: pos_after,
            rotation_error_before_deg: rot_before,
            rotation_error_after_deg: rot_after,
            steps_without: runs[0].0,
            steps_with: runs[1].0,
        };
        progress(&format!(
            "{deg} degrees: PSNR {:.2} -> {:.2} dB; joint error {:.1} -> {:.1} mm",
            level.psnr_without,
            level.psnr_with,
            1e3 * pos_before,
            1e3 * pos_after
        ));
        levels.push(level);
    }
    let summary = Summary {
        levels,
        budget_s: opts.budget_s,
        eval_frames: eval_frames.len(),
        training_frames: train_frames.len(),
    };
    let json = serde_json::to_vec_pretty(&summary).expect("the summary serialises");
    write_report(out, "noisy_fits", &json, &table(&summary))?;
    let summary_file = out.join("summary.json");
    talkin_data::atomic::write_atomic(&summary_file, &json).map_err(|source| BenchError::Io {
        file: summary_file,
        source,
    })?;
    match plot::plot_levels(&summary.levels) {
        Ok(img) => {
            let file = out.join("noisy_fits.png");
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

/// A copy of `dataset` in `dir` whose training fits carry noise of level `deg` (seeded
/// per frame); held-out frames keep their fits. Images are linked, not copied.
fn noisy_dataset(dataset: &Dataset, dir: &Path, deg: f64) -> Result<Dataset, BenchError> {
    let io = |file: &Path| {
        let file = file.to_path_buf();
        move |source| BenchError::Io { file, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let root = dataset.root.canonicalize().map_err(io(&dataset.root))?;
    // Every directory the index names files in, linked.
    let mut dirs: Vec<PathBuf> = dataset
        .frames
        .iter()
        .flat_map(|f| {
            [
                Some(&f.image),
                Some(&f.mask),
                f.segmentation.as_ref(),
                f.depth.as_ref(),
            ]
        })
        .flatten()
        .filter_map(|p| p.components().next().map(|c| PathBuf::from(c.as_os_str())))
        .collect();
    dirs.sort();
    dirs.dedup();
    for d in dirs {
        let link = dir.join(&d);
        if link.symlink_metadata().is_ok() {
            std::fs::remove_file(&link).map_err(io(&link))?;
        }
        std::os::unix::fs::symlink(root.join(&d), &link).map_err(io(&link))?;
    }
    let mut copy = dataset.clone();
    copy.root = dir.to_path_buf();
    for (i, f) in copy.frames.iter_mut().enumerate() {
        if f.split == Split::Train {
            let seed = 0x6E01_5E00 ^ ((deg * 1000.0).round() as u64) << 20 ^ i as u64;
            f.params = noisy(&f.params, deg, seed);
        }
    }
    copy.save_index().map_err(talkin_train::TrainError::from)?;
    Ok(copy)
}

/// The Markdown table.
pub fn table(s: &Summary) -> String {
    let mut t = format!(
        "Training fits with noise, with and without `--refine-poses` ({:.0} s each, {} \
         training frames; test_same PSNR on {} frames with clean poses)\n\n\
         | noise (deg) | PSNR without | PSNR with | gain (dB) | face with/without | hands with/without | joint error before (mm) | after (mm) | rotation error before (deg) | after (deg) |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
        s.budget_s, s.training_frames, s.eval_frames
    );
    let opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.2}"));
    for l in &s.levels {
        t += &format!(
            "| {} | {:.2} | {:.2} | {:+.2} | {} / {} | {} / {} | {:.1} | {:.1} | {:.2} | {:.2} |\n",
            l.noise_deg,
            l.psnr_without,
            l.psnr_with,
            l.psnr_with - l.psnr_without,
            opt(l.with.psnr_face),
            opt(l.without.psnr_face),
            opt(l.with.psnr_hands),
            opt(l.without.psnr_hands),
            1e3 * l.joint_error_before_m,
            1e3 * l.joint_error_after_m,
            l.rotation_error_before_deg,
            l.rotation_error_after_deg,
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use talkin_human::body::canonical_params;
    use talkin_synth::body::default_rest_joints;

    /// The two error measures are zero on the truth and grow with the noise; the same seed
    /// gives the same noise.
    #[test]
    fn errors_grow_with_the_noise() {
        let skeleton = default_rest_joints(0);
        let truth = canonical_params();
        assert_eq!(joint_position_error(&skeleton, &truth, &truth), 0.0);
        assert!(joint_rotation_error(&truth, &truth) < 1e-6);
        let mean = |deg: f64| -> (f64, f64) {
            let (mut p, mut r) = (0.0, 0.0);
            for seed in 0..20 {
                let fit = noisy(&truth, deg, seed);
                p += joint_position_error(&skeleton, &truth, &fit);
                r += joint_rotation_error(&truth, &fit);
            }
            (p / 20.0, r / 20.0)
        };
        let (p3, r3) = mean(3.0);
        let (p6, r6) = mean(6.0);
        assert!(p6 > 1.5 * p3 && r6 > 1.5 * r3, "{p3} {p6} {r3} {r6}");
        // 6 degrees a joint along the chains, plus 2 cm of translation: centimetres.
        assert!(p6 > 0.02 && p6 < 0.15, "{p6}");
    }
}
