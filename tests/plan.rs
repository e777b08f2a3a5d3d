//! The census and the plan through the command line: `inspect` and `train` print them,
//! `recipe.json` records both, a flag named on the command line overrides its decision
//! and is recorded as overridden, a resumed run keeps the plan it started with, and the
//! hard cases (a subject with no training frames, a single frame, hands that never show)
//! plan and train.

mod common;

use std::path::Path;

use common::cli::{p, stderr, talkin};
use serde_json::Value;

/// Runs `talkin` with `words` (each split at spaces but for absolute paths), expecting
/// success; its standard output.
fn ok(words: &[&str]) -> String {
    let argv: Vec<&str> = words
        .iter()
        .flat_map(|w| {
            if w.starts_with('/') {
                vec![*w]
            } else {
                w.split_whitespace().collect()
            }
        })
        .collect();
    let out = talkin(&argv);
    assert!(out.status.success(), "{argv:?}: {}", stderr(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `talkin train --data DATA --out RUN` of a few tiny steps, with `extra`.
fn train(data: &Path, run: &Path, extra: &str) -> String {
    let tiny = "--batch 64 --patches 0 --occ-every 2 --grid-resolution 16";
    ok(&["train --data", p(data), "--out", p(run), tiny, extra])
}

fn recipe(run: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(run.join("recipe.json")).unwrap()).unwrap()
}

fn decision<'a>(recipe: &'a Value, flag: &str) -> &'a Value {
    recipe["options"]["plan"]["decisions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["flag"] == flag)
        .unwrap_or_else(|| panic!("no decision for {flag}"))
}

#[test]
fn the_plan_is_printed_recorded_overridden_and_kept_on_resume() {
    let root = common::temp_dir("plan_cli");
    let data = root.join("data");
    // Head and shoulders: the hands never show (their fingers move).
    ok(&[
        "synth --out",
        p(&data),
        "--identities 2 --frames 4 --size 64 --framing head",
    ]);
    let inspected = ok(&["inspect", p(&data)]);
    assert!(
        inspected.contains("census of the training frames"),
        "{inspected}"
    );
    assert!(inspected.contains("--skin-fingers wrist"), "{inspected}");

    // One subject trained, the other without frames in the census.
    let run = root.join("run");
    let printed = train(&data, &run, "--steps 3 --identities ada");
    assert!(
        printed.contains("plan:") && printed.contains("--hand-deform off"),
        "{printed}"
    );
    let r = recipe(&run);
    let subjects = r["options"]["plan"]["census"]["subjects"]
        .as_array()
        .unwrap();
    assert_eq!(subjects.len(), 2);
    assert!(subjects.iter().any(|s| s["frames"] == 0));
    let fingers = decision(&r, "--skin-fingers");
    assert_eq!(
        (fingers["used"].as_str(), fingers["overridden"].as_bool()),
        (Some("wrist"), Some(false))
    );
    assert_eq!(r["field"]["skinning"]["finger_bones"], false);
    assert_eq!(r["field"]["use_d_hands"], false);
    assert_eq!(r["field"]["has_face"], true);

    // Resumed: the same plan, said again.
    let resumed = ok(&[
        "train --data",
        p(&data),
        "--out",
        p(&run),
        "--resume --steps 5",
    ]);
    assert!(resumed.contains("resuming with the plan"), "{resumed}");
    assert_eq!(recipe(&run)["options"]["plan"], r["options"]["plan"]);

    // A flag overrides its decision and the recipe says so.
    let forced = root.join("forced");
    train(&data, &forced, "--steps 2 --skin-fingers bones");
    let r = recipe(&forced);
    let fingers = decision(&r, "--skin-fingers");
    assert_eq!(fingers["used"], "bones");
    assert_eq!(fingers["planned"], "wrist");
    assert_eq!(fingers["overridden"], true);
    assert_eq!(r["field"]["skinning"]["finger_bones"], true);

    // --plan off: the options as given, no plan recorded.
    let plain = root.join("plain");
    train(&data, &plain, "--steps 2 --plan off");
    let r = recipe(&plain);
    assert!(r["options"]["plan"].is_null());
    assert_eq!(r["field"]["skinning"]["finger_bones"], true);
}

#[test]
fn a_single_frame_plans_and_trains() {
    let root = common::temp_dir("plan_one_frame");
    let data = root.join("data");
    ok(&[
        "synth --out",
        p(&data),
        "--identities 1 --frames 1 --size 48",
    ]);
    let run = root.join("run");
    let printed = train(&data, &run, "--steps 2");
    assert!(printed.contains("plan:"), "{printed}");
    // One frame moves nothing: every input that reads motion is off, and the plan is
    // finite (JSON writes a NaN as null).
    let r = recipe(&run);
    let text = serde_json::to_string(&r["options"]["plan"]).unwrap();
    assert!(!text.contains("NaN") && !text.contains("null"), "{text}");
    assert_eq!(decision(&r, "--face-expression")["used"], "off");
}

/// A dataset of camera frames composited by their masks (what `import` writes) is a
/// capture: the census records it, and the grid's reason says its fits bound the finest
/// cell; the same frames declared matted do not.
#[test]
fn a_capture_is_recorded_and_its_grid_says_why() {
    let root = common::temp_dir("plan_capture");
    let matted = root.join("matted");
    ok(&[
        "synth --out",
        p(&matted),
        "--identities 1 --frames 2 --size 48",
    ]);
    let captured = root.join("by_mask");
    common::copy_as_capture(&matted, &captured);
    for (data, capture) in [(&matted, false), (&captured, true)] {
        let run = root.join(format!("run_{capture}"));
        train(data, &run, "--steps 1");
        let r = recipe(&run);
        assert_eq!(r["options"]["plan"]["census"]["capture"], capture);
        let reason = decision(&r, "--hash-levels")["reason"]
            .as_str()
            .unwrap()
            .to_string();
        assert_eq!(reason.contains("capture"), capture, "{reason}");
    }
}
