//! The importers' own files made hostile: SMPLer-X's per-person JSON and `.npz`, and
//! HumanNeRF's `metadata.json`, each with bytes flipped, spliced or cut, or one value
//! swapped for an odd one; PeopleSnapshot's split yaml likewise. Reading the source never panics, and what it accepts is finite
//! and within the parameter limits `dataset.json` holds it to (an import that wrote a
//! dataset its own loader refuses would fail only at training).
//!
//! 64 cases per property from a fixed seed; `PROPTEST_CASES=N` runs more (see
//! docs/results.md).

#[path = "../engine/data/tests/support/damaged_bytes.rs"]
mod damaged_bytes;
#[path = "../engine/data/tests/support/json_mutation.rs"]
mod json_mutation;
#[path = "../engine/data/tests/support/proptest_config.rs"]
mod proptest_config;

mod common;

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, OnceLock};

use common::layouts::{Clip, SmplerxFixture, write_humannerf_wild, write_smplerx};
use damaged_bytes::damage;
use json_mutation::{mutate_leaf, odd_value};
use proptest::prelude::*;
use proptest_config::config;
use serde_json::Value;
use talkin::data::dataset::Dataset;
use talkin::data::params_json::PARAM_LIMIT;
use talkin::import::peoplesnapshot::parse_splits_yaml;
use talkin::import::{Format, ImportOptions, Source, read_source};

fn scene() -> &'static Dataset {
    static SCENE: OnceLock<Dataset> = OnceLock::new();
    SCENE.get_or_init(|| common::synthetic_scene("hostile_imports_scene", 1, 48, 1))
}

fn smplerx_fixture() -> &'static SmplerxFixture {
    static FIXTURE: OnceLock<SmplerxFixture> = OnceLock::new();
    FIXTURE.get_or_init(|| write_smplerx(&Clip::subject0(scene()), "hostile_imports_smplerx"))
}

fn humannerf_fixture() -> &'static (PathBuf, PathBuf) {
    static FIXTURE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    FIXTURE.get_or_init(|| write_humannerf_wild(&Clip::subject0(scene()), "hostile_imports_hn"))
}

fn read_smplerx() -> Result<Source, String> {
    let fx = smplerx_fixture();
    let mut opts = ImportOptions::new(Format::SmplerX, &fx.results, "unused");
    opts.images = Some(fx.images.clone());
    opts.masks = Some(fx.masks.clone());
    opts.body_model = Some(fx.model.clone());
    opts.focal = Some(60.0);
    opts.fps = Some(25.0);
    read_source(&opts).map_err(|e| e.to_string())
}

fn read_humannerf() -> Result<Source, String> {
    let (src, model) = humannerf_fixture();
    let mut opts = ImportOptions::new(Format::HumanNerf, src, "unused");
    opts.body_model = Some(model.clone());
    read_source(&opts).map_err(|e| e.to_string())
}

/// What an accepted source must hold: finite numbers, parameters within the limit.
fn assert_sound(source: &Source) {
    assert!(source.rest_joints.iter().all(|j| j.is_finite()));
    for f in &source.frames {
        assert!(f.time.is_finite(), "{}", f.name);
        assert!(f.intrinsics.iter().flatten().all(|v| v.is_finite()));
        assert!(f.extrinsics.iter().flatten().all(|v| v.is_finite()));
        assert!(f.distortion.iter().flatten().all(|v| v.is_finite()));
        let p = &f.params;
        assert!(p.is_finite(), "{}", f.name);
        let within = |x: f64| x.abs() <= PARAM_LIMIT;
        assert!(
            p.local_rotations()
                .iter()
                .all(|r| r.to_array().into_iter().all(within)),
            "{}: a rotation beyond {PARAM_LIMIT}",
            f.name
        );
        assert!(p.expression.iter().copied().all(within), "{}", f.name);
        assert!(p.transl.to_array().into_iter().all(within), "{}", f.name);
    }
}

/// One case at a time per fixture: the properties run in parallel and damage its files.
fn exclusive(fixture: &'static Mutex<()>) -> MutexGuard<'static, ()> {
    fixture
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

static SMPLERX: Mutex<()> = Mutex::new(());
static HUMANNERF: Mutex<()> = Mutex::new(());

/// Puts `bytes` in `file` for as long as it lives, then the original back (a failing
/// case unwinds through it too).
struct Swapped {
    file: PathBuf,
    original: Vec<u8>,
}

impl Swapped {
    fn new(file: &Path, bytes: &[u8]) -> Swapped {
        let original = std::fs::read(file).unwrap();
        std::fs::write(file, bytes).unwrap();
        Swapped {
            file: file.to_path_buf(),
            original,
        }
    }
}

impl Drop for Swapped {
    fn drop(&mut self) {
        std::fs::write(&self.file, &self.original).unwrap();
    }
}

/// The files of `dir` ending in `ext`, sorted.
fn files(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == ext))
        .collect();
    out.sort();
    out
}

/// Bytes flipped, spliced in and cut.
fn damaged(
    mut bytes: Vec<u8>,
    flips: &[(prop::sample::Index, u8)],
    splice: &Option<(prop::sample::Index, Vec<u8>)>,
    cut: Option<prop::sample::Index>,
) -> Vec<u8> {
    for (at, byte) in flips {
        let i = at.index(bytes.len());
        bytes[i] ^= byte;
    }
    if let Some((at, spliced)) = splice {
        let i = at.index(bytes.len() + 1);
        bytes.splice(i..i, spliced.iter().copied());
    }
    if let Some(cut) = cut {
        bytes.truncate(cut.index(bytes.len() + 1));
    }
    bytes
}

/// `file`'s JSON with one leaf swapped for `to`.
fn with_odd_leaf(file: &Path, to: Value, picks: &[usize]) -> Vec<u8> {
    let mut doc: Value = serde_json::from_slice(&std::fs::read(file).unwrap()).unwrap();
    let mut k = 0;
    let mut pick = |n: usize| {
        k += 1;
        picks[k % picks.len()] % n
    };
    mutate_leaf(&mut doc, &mut pick, to);
    doc.to_string().into_bytes()
}

fn flips() -> impl Strategy<Value = Vec<(prop::sample::Index, u8)>> {
    prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..8)
}

fn splice() -> impl Strategy<Value = Option<(prop::sample::Index, Vec<u8>)>> {
    prop::option::of((
        any::<prop::sample::Index>(),
        prop::collection::vec(any::<u8>(), 1..16),
    ))
}

proptest! {
    #![proptest_config(config(0x1a90_57e5))]

    #[test]
    fn damaged_smplerx_files_never_panic(
        which in any::<prop::sample::Index>(),
        flips in flips(),
        splice in splice(),
        cut in prop::option::weighted(0.3, any::<prop::sample::Index>()),
    ) {
        let _one = exclusive(&SMPLERX);
        let fx = smplerx_fixture();
        let mut candidates = files(&fx.results.join("meta"), "json");
        candidates.extend(files(&fx.results.join("smplx"), "npz"));
        let file = which.get(&candidates);
        let bytes = damaged(std::fs::read(file).unwrap(), &flips, &splice, cut);
        let _swap = Swapped::new(file, &bytes);
        if let Ok(source) = read_smplerx() {
            assert_sound(&source);
        }
    }

    #[test]
    fn smplerx_json_with_an_odd_value_never_panics(
        which in any::<prop::sample::Index>(),
        to in odd_value(),
        picks in prop::collection::vec(any::<usize>(), 8),
    ) {
        let _one = exclusive(&SMPLERX);
        let fx = smplerx_fixture();
        let file = which.get(&files(&fx.results.join("meta"), "json")).clone();
        let _swap = Swapped::new(&file, &with_odd_leaf(&file, to, &picks));
        if let Ok(source) = read_smplerx() {
            assert_sound(&source);
        }
    }

    #[test]
    fn damaged_humannerf_metadata_never_panics(
        flips in flips(),
        splice in splice(),
        cut in prop::option::weighted(0.3, any::<prop::sample::Index>()),
    ) {
        let _one = exclusive(&HUMANNERF);
        let file = humannerf_fixture().0.join("metadata.json");
        let bytes = damaged(std::fs::read(&file).unwrap(), &flips, &splice, cut);
        let _swap = Swapped::new(&file, &bytes);
        if let Ok(source) = read_humannerf() {
            assert_sound(&source);
        }
    }

    #[test]
    fn humannerf_metadata_with_an_odd_value_never_panics(
        to in odd_value(),
        picks in prop::collection::vec(any::<usize>(), 8),
    ) {
        let _one = exclusive(&HUMANNERF);
        let file = humannerf_fixture().0.join("metadata.json");
        let _swap = Swapped::new(&file, &with_odd_leaf(&file, to, &picks));
        if let Ok(source) = read_humannerf() {
            assert_sound(&source);
        }
    }
}

#[test]
fn the_fixtures_read() {
    let _one = (exclusive(&SMPLERX), exclusive(&HUMANNERF));
    assert_sound(&read_smplerx().unwrap());
    assert_sound(&read_humannerf().unwrap());
}

/// Found by `smplerx_json_with_an_odd_value_never_panics`: a focal length of 1.3e282 px
/// in a person's meta JSON re-solved the translation to ~1e279 m, which the import wrote
/// into a dataset that its own loader then refused.
#[test]
fn regression_an_absurd_focal_length_is_refused_naming_the_frame() {
    let _one = exclusive(&SMPLERX);
    let file = smplerx_fixture().results.join("meta").join("00002_0.json");
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    doc["focal"] = serde_json::json!([1.2935475821954525e282, 1.2935475821954525e282]);
    let _swap = Swapped::new(&file, doc.to_string().as_bytes());
    let e = read_smplerx().unwrap_err();
    assert!(
        e.contains("000002.params.transl") && e.contains("within"),
        "{e}"
    );
}

/// Found by `humannerf_metadata_with_an_odd_value_never_panics`: a beta of 1e300 in
/// `metadata.json` gave rest joints and a translation of ~1e298, accepted the same way.
#[test]
fn regression_an_absurd_beta_is_refused() {
    let _one = exclusive(&HUMANNERF);
    let file = humannerf_fixture().0.join("metadata.json");
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    doc["000000"]["betas"][9] = serde_json::json!(1e300);
    let _swap = Swapped::new(&file, doc.to_string().as_bytes());
    let e = read_humannerf().unwrap_err();
    assert!(e.contains("params") && e.contains("within"), "{e}");
}

// ---------------------------------------------------------------------------------------
// PeopleSnapshot's split yaml

const SPLITS_YAML: &str = "\
dataset:
  opt:
    train:
      start: 0
      end: 40
      skip: 4
    val:
      start: 41
      end: 41
    test:
      start: 42
      end: 60
      skip: 2  # every other frame
";

fn assert_ranges_sound(text: &str) {
    if let Ok(ranges) = parse_splits_yaml(text, Path::new("subject.yaml")) {
        for r in ranges {
            assert!(r.start <= r.end && r.skip >= 1, "{r:?}");
        }
    }
}

proptest! {
    #![proptest_config(config(0x4f57_11e5))]

    #[test]
    fn split_yaml_of_arbitrary_text_never_panics(text in "(?s).{0,256}") {
        assert_ranges_sound(&text);
    }

    #[test]
    fn damaged_split_yaml_never_panics(damage in damage()) {
        let bytes = damage.apply(SPLITS_YAML.as_bytes().to_vec());
        assert_ranges_sound(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn split_yaml_with_any_number_never_panics(
        at in 0usize..7,
        value in prop_oneof![
            Just("18446744073709551615".to_string()),
            Just("18446744073709551616".to_string()),
            Just("-1".to_string()),
            Just("${x}".to_string()),
            any::<u64>().prop_map(|v| v.to_string()),
        ],
    ) {
        let mut k = 0;
        let text: String = SPLITS_YAML
            .lines()
            .map(|l| match l.split_once(": ") {
                Some((key, _)) if { k += 1; k - 1 == at } => format!("{key}: {value}\n"),
                _ => format!("{l}\n"),
            })
            .collect();
        assert_ranges_sound(&text);
    }
}

#[test]
fn the_split_yaml_fixture_parses() {
    let [train, val, test] = parse_splits_yaml(SPLITS_YAML, Path::new("s.yaml")).unwrap();
    assert_eq!((train.start, train.end, train.skip), (0, 40, 4));
    assert_eq!((val.start, val.end, val.skip), (41, 41, 1));
    assert_eq!((test.start, test.end, test.skip), (42, 60, 2));
}
