//! The novel-identity path on a tiny two-subject scene: a base run trained without one
//! subject, `Trainer::adapt` learning that subject from short clips, and the benchmark
//! that scores every adaptation on the same held-out frames; bad options are named.

mod common;

use talkin::avatar::checkpoint::Checkpoint;
use talkin::benches::novel_identity::{NovelIdentityError, NovelIdentityOptions, novel_identity};
use talkin::data::dataset::Split;
use talkin::grids::SamplerKind;
use talkin::train::Budget;

fn opts(clips_s: Vec<f64>) -> NovelIdentityOptions {
    NovelIdentityOptions {
        subject: None,
        clips_s,
        base: Budget::Steps(4),
        base_run: None,
        adapt_lr_ratio: 1.0 / 50.0,
        adapt: Budget::Steps(3),
        scratch: false,
        eval_frames: 0,
        train: common::small_train_opts(SamplerKind::Accelerated, 4),
        lpips_dir: None,
    }
}

#[test]
fn adapts_from_each_clip_and_scores_the_same_held_out_frames() {
    // Two subjects, 4 training frames each at 25 fps (t = 0, 0.04, 0.08, 0.12) and a
    // test_same frame at 0.16 s.
    let dataset = common::synthetic_scene("novel_identity_scene", 2, 48, 5);
    let out = common::temp_dir("novel_identity_report");
    let rows = novel_identity(&dataset, &out, &opts(vec![0.05, 0.1]), &mut |_| {}).unwrap();

    let novel = &dataset.subjects[1].name;
    // Per clip: test_same (after the longest clip) and test_ood.
    assert_eq!(rows.len(), 4, "{rows:?}");
    for r in &rows {
        assert_eq!(&r.subject, novel);
        assert!(r.scores.psnr.is_finite() && r.scores.psnr > 5.0, "{r:?}");
        assert_eq!(r.steps, 3);
    }
    let clip_frames: Vec<usize> = rows.iter().map(|r| r.clip_frames).collect();
    assert_eq!(clip_frames, [2, 2, 3, 3]);
    assert!(
        (rows[0].clip_video_s - 0.08).abs() < 1e-9,
        "{}",
        rows[0].clip_video_s
    );
    // Every clip is scored on the same frames: the subject's test_same frames after the
    // longest clip, and all of its test_ood frames.
    let own = |split: Split| {
        dataset
            .split_indices(split)
            .into_iter()
            .filter(|&i| dataset.frames[i].subject == 1)
            .count()
    };
    for pair in rows.chunks(2) {
        assert_eq!(pair[0].split, "test_same");
        assert_eq!(pair[0].frames, own(Split::TestSame));
        assert_eq!(pair[1].split, "test_ood");
        assert_eq!(pair[1].frames, own(Split::TestOod));
    }

    // The base run never trained the novel subject; each adapted run did.
    let base = Checkpoint::load(&out.join("runs/base")).unwrap();
    let trained = |c: &Checkpoint, name: &str| {
        c.subjects
            .iter()
            .any(|s| s.name == name && s.model.is_some())
    };
    assert!(!trained(&base, novel));
    assert!(trained(&base, &dataset.subjects[0].name));
    for clip in ["0.05", "0.1"] {
        let adapted = Checkpoint::load(&out.join(format!("runs/adapt-{clip}s"))).unwrap();
        assert!(trained(&adapted, novel), "adapt-{clip}s");
    }
    for file in ["novel_identity.json", "novel_identity.md"] {
        assert!(out.join(file).is_file(), "{file}");
    }
    let table = std::fs::read_to_string(out.join("novel_identity.md")).unwrap();
    assert_eq!(table.lines().count(), 2 + rows.len());

    // An existing base run is adapted as it is, with the rate asked for.
    let again = common::temp_dir("novel_identity_reuse");
    let reused = NovelIdentityOptions {
        base_run: Some(out.join("runs/base")),
        adapt_lr_ratio: 1.0,
        ..opts(vec![0.05])
    };
    let rows = novel_identity(&dataset, &again, &reused, &mut |_| {}).unwrap();
    assert_eq!(rows.len(), 2);
    assert!(!again.join("runs/base").exists());
    let recipe = std::fs::read_to_string(again.join("runs/adapt-0.05s/recipe.json")).unwrap();
    let lr = common::small_train_opts(SamplerKind::Accelerated, 4).initial_lr();
    assert!(recipe.contains(&format!("\"lr\": {lr}")), "{recipe}");
    assert!(recipe.contains("\"clip_seconds\": 0.05"), "{recipe}");
}

/// The from-scratch baseline trains the novel subject alone on the same clip, with the
/// adaptation's budget, and is scored on the same frames.
#[test]
fn scratch_baseline_trains_the_clip_alone() {
    let dataset = common::synthetic_scene("novel_identity_scratch", 2, 48, 5);
    let out = common::temp_dir("novel_identity_scratch_report");
    let o = NovelIdentityOptions {
        scratch: true,
        ..opts(vec![0.05])
    };
    let rows = novel_identity(&dataset, &out, &o, &mut |_| {}).unwrap();
    let models: Vec<&str> = rows.iter().map(|r| r.model.as_str()).collect();
    assert_eq!(models, ["adapted", "adapted", "scratch", "scratch"]);
    for pair in [(&rows[0], &rows[2]), (&rows[1], &rows[3])] {
        assert_eq!(pair.0.split, pair.1.split);
        assert_eq!(pair.0.frames, pair.1.frames);
        assert_eq!(pair.0.clip_frames, pair.1.clip_frames);
        assert_eq!(pair.1.steps, 3);
        assert!(pair.1.scores.psnr.is_finite(), "{:?}", pair.1);
    }
    // Only the novel subject, only its clip (t = 0 and 0.04 s).
    let scratch = Checkpoint::load(&out.join("runs/scratch-0.05s")).unwrap();
    let trained: Vec<&str> = scratch
        .subjects
        .iter()
        .filter(|s| s.model.is_some())
        .map(|s| s.name.as_str())
        .collect();
    assert_eq!(trained, [dataset.subjects[1].name.as_str()]);
    let frames: Vec<usize> = serde_json::from_value(scratch.state["frames"].clone()).unwrap();
    assert_eq!(frames.len(), 2);
    for i in frames {
        assert_eq!(dataset.frames[i].subject, 1);
        assert!(dataset.frames[i].time < 0.05 + 1e-9);
    }
}

#[test]
fn bad_options_name_the_field() {
    let dataset = common::synthetic_scene("novel_identity_bad", 2, 48, 6);
    let out = common::temp_dir("novel_identity_bad_report");
    let field = |o: NovelIdentityOptions| match novel_identity(&dataset, &out, &o, &mut |_| {}) {
        Err(NovelIdentityError::BadOption { field, problem }) => (field, problem),
        other => panic!("expected a bad option, got {other:?}"),
    };
    // A clip as long as the video leaves no test_same frame after it.
    let (f, problem) = field(opts(vec![1.0]));
    assert_eq!(f, "clips");
    assert!(problem.contains("--frames"), "{problem}");
    for clips in [vec![], vec![0.0], vec![f64::NAN]] {
        assert_eq!(field(opts(clips)).0, "clips");
    }
    for ratio in [0.0, f64::NAN] {
        let o = NovelIdentityOptions {
            adapt_lr_ratio: ratio,
            ..opts(vec![0.05])
        };
        assert_eq!(field(o).0, "adapt_lr_ratio");
    }
    let (f, problem) = field(NovelIdentityOptions {
        subject: Some("nobody".into()),
        ..opts(vec![0.05])
    });
    assert_eq!(f, "subject");
    assert!(problem.contains("nobody"), "{problem}");
}
