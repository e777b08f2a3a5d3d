use talkin_data::census::{Articulation, CanonicalSize, LabelSource, PartPixels, SubjectCensus};

use super::*;
use crate::recipe::FingerSkinning;

/// A subject seen like the demo's (hands and face large, everything moving) or, with
/// `still`, like ZJU-MoCap 387's (hands a few hundred pixels, fingers, jaw and expression
/// at rest), at `footprint_mm`.
fn subject(still: bool, footprint_mm: Option<f64>) -> SubjectCensus {
    SubjectCensus {
        name: "s".into(),
        frames: 90,
        views: 1,
        frames_counted: 24,
        pixels: PartPixels {
            frame: 262144.0,
            person: 30000.0,
            body: 20000.0,
            arms: 6000.0,
            head: 3000.0,
            left_hand: if still { 150.0 } else { 600.0 },
            right_hand: if still { 150.0 } else { 600.0 },
            frames_with_hands: 24,
            frames_with_head: 24,
        },
        labels: LabelSource::Derived,
        articulation: if still {
            Articulation {
                body_deg: 30.0,
                ..Articulation::default()
            }
        } else {
            Articulation {
                fingers_deg: 20.0,
                wrists_deg: 15.0,
                jaw_deg: 5.0,
                expression: 0.5,
                body_deg: 20.0,
            }
        },
        footprint_mm,
        canonical: CanonicalSize {
            extent_m: 1.9,
            surface_m2: 1.9,
        },
    }
}

fn census(subjects: Vec<SubjectCensus>) -> Census {
    Census {
        subjects,
        capture: false,
    }
}

fn decision<'a>(opts: &'a TrainOptions, flag: &str) -> &'a Decision {
    let plan = opts.plan.as_ref().unwrap();
    plan.decisions.iter().find(|d| d.flag == flag).unwrap()
}

#[test]
fn a_scene_that_shows_and_moves_everything_keeps_everything() {
    let opts = Plan::apply(
        census(vec![subject(false, Some(3.0))]),
        TrainOptions::default(),
        |_| false,
    );
    let base = TrainOptions::default();
    assert_eq!(opts.ablation, base.ablation);
    assert_eq!(opts.skin_fingers, base.skin_fingers);
    assert_eq!(
        (opts.hash_levels, opts.hash_table_log2),
        (Some(12), Some(17))
    );
    assert_eq!(opts.plan.as_ref().unwrap().decisions.len(), 8);
    assert!(opts.check().is_ok());
}

#[test]
fn still_fingers_and_a_still_face_drop_their_bones_and_inputs() {
    let opts = Plan::apply(
        census(vec![subject(true, Some(6.5))]),
        TrainOptions::default(),
        |_| false,
    );
    assert!(opts.ablation.hands && !opts.ablation.use_d_hands);
    assert_eq!(opts.skin_fingers, FingerSkinning::Wrist);
    assert!(
        opts.ablation.face && !opts.ablation.face_uses_expression && !opts.ablation.face_uses_jaw
    );
    // 387's footprint keeps the preset's grid; a capture four times coarser does not.
    assert_eq!(opts.hash_levels, Some(12));
    assert!(opts.check().is_ok());
    let far = Plan::apply(
        census(vec![subject(true, Some(26.0))]),
        TrainOptions::default(),
        |_| false,
    );
    let (levels, table) = (far.hash_levels.unwrap(), far.hash_table_log2.unwrap());
    assert!(levels < 12 && table < 17, "{levels} {table}");
    assert!(far.check().is_ok());
    let text = opts.plan.as_ref().unwrap().describe();
    assert!(
        text.contains("--skin-fingers wrist") && text.contains("F_hands kept"),
        "{text}"
    );
}

/// A capture's fits misalign its frames by more than a pixel: at 387's footprint the
/// finest cell is 1.5 pixels (8 levels, about 7 mm), where the same frames with exact
/// fits keep the preset's 12 (1.4 mm); the reason says why.
#[test]
fn a_capture_stops_its_grid_at_what_its_fits_can_align() {
    let planned = |capture| {
        Plan::apply(
            Census {
                subjects: vec![subject(true, Some(5.4))],
                capture,
            },
            TrainOptions::default(),
            |_| false,
        )
    };
    let (exact, capture) = (planned(false), planned(true));
    assert_eq!(exact.hash_levels, Some(12));
    assert_eq!(capture.hash_levels, Some(8));
    // 1.9 m2 in 8.1 mm cells: 29k cells a level.
    assert_eq!(capture.hash_table_log2, Some(15));
    assert!(capture.check().is_ok());
    let reason = &decision(&capture, "--hash-levels").reason;
    assert!(
        reason.contains("5.4 mm") && reason.contains("capture") && reason.contains("8.1 mm"),
        "{reason}"
    );
}

/// Fingers that move but never show teach nothing: no finger bones, no D_hands.
#[test]
fn moving_fingers_that_never_show_get_no_bones() {
    let mut hidden = subject(false, Some(2.0));
    hidden.pixels.left_hand = 0.5;
    hidden.pixels.right_hand = 0.0;
    let opts = Plan::apply(census(vec![hidden]), TrainOptions::default(), |_| false);
    assert_eq!(opts.skin_fingers, FingerSkinning::Wrist);
    assert!(!opts.ablation.use_d_hands && opts.ablation.hands);
    assert!(opts.ablation.face_uses_expression && opts.ablation.face_uses_jaw);
}

/// A flag the command line named stays as given, and the decision records it.
#[test]
fn a_named_flag_overrides_its_decision_and_is_recorded() {
    let given = TrainOptions {
        skin_fingers: FingerSkinning::Bones,
        hash_levels: Some(10),
        ..TrainOptions::default()
    };
    let opts = Plan::apply(census(vec![subject(true, Some(6.5))]), given, |id| {
        id == "skin_fingers" || id == "hash_levels"
    });
    assert_eq!(opts.skin_fingers, FingerSkinning::Bones);
    let d = decision(&opts, "--skin-fingers");
    assert!(
        d.overridden && d.used == "bones" && d.planned == "wrist",
        "{d:?}"
    );
    assert_eq!(opts.hash_levels, Some(10));
    let d = decision(&opts, "--hash-levels");
    assert!(d.overridden && d.used == "10" && d.planned == "12", "{d:?}");
    assert!(!decision(&opts, "--hand-deform").overridden);
    assert_eq!(decision(&opts, "--hand-deform").used, "off");
}

/// Every flag the plan decides is a real option's clap id (a renamed field would leave
/// the override unseen).
#[test]
fn every_decision_is_a_flag_of_the_command_line() {
    use clap::{CommandFactory, Parser};
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        recipe: TrainOptions,
    }
    let cmd = Cli::command();
    for rule in rules::RULES {
        let arg = cmd
            .get_arguments()
            .find(|a| a.get_id() == rule.setting.id)
            .unwrap_or_else(|| panic!("`{}` is no option's id", rule.setting.id));
        assert_eq!(format!("--{}", arg.get_long().unwrap()), rule.setting.flag);
    }
}

/// Numerically safe: no pixels, no frames, no footprint, one frame, a subject without
/// frames beside one with: a plan of finite, valid options every time.
#[test]
fn degenerate_censuses_give_a_valid_plan() {
    let mut empty = subject(true, None);
    empty.frames = 0;
    empty.frames_counted = 0;
    empty.pixels = PartPixels::default();
    let mut one_frame = subject(false, Some(4.0));
    one_frame.frames = 1;
    one_frame.frames_counted = 1;
    one_frame.articulation = Articulation::default();
    let mut tiny = subject(true, Some(0.0));
    tiny.canonical = CanonicalSize::default();
    let mut huge = subject(true, Some(f64::INFINITY));
    huge.pixels.person = 0.0;
    let mut nan = subject(false, Some(f64::NAN));
    nan.canonical.extent_m = f64::NAN;
    for c in [
        census(vec![]),
        census(vec![empty.clone()]),
        census(vec![one_frame.clone()]),
        census(vec![empty, subject(false, Some(3.0))]),
        census(vec![tiny]),
        census(vec![huge]),
        census(vec![nan]),
        census(vec![subject(true, Some(1e9))]),
    ] {
        let opts = Plan::apply(c.clone(), TrainOptions::default(), |_| false);
        assert!(opts.check().is_ok(), "{c:?}");
        let plan = opts.plan.as_ref().unwrap();
        for d in &plan.decisions {
            assert!(
                !d.reason.contains("NaN") && !d.reason.contains("inf"),
                "{d:?}"
            );
        }
        // Round trip through the run's record (JSON holds no infinity).
        let finite = c
            .subjects
            .iter()
            .all(|s| s.footprint_mm.is_none_or(f64::is_finite));
        if finite {
            let json = crate::recipe::record::to_json(&opts).unwrap();
            let back = crate::recipe::record::from_json(json).unwrap();
            assert_eq!(back.plan, opts.plan);
        }
    }
}
