//! The dataset loader on arbitrary bytes and on mutated valid documents: it never panics,
//! and whatever it accepts is finite and within the parameter limits.
//!
//! `cargo test -p talkin-data --test loader_properties` runs 64 cases per property;
//! `PROPTEST_CASES=5000 cargo test --release -p talkin-data --test loader_properties`
//! runs many.

use std::path::Path;

#[path = "support/json_mutation.rs"]
mod json_mutation;
#[path = "support/proptest_config.rs"]
mod proptest_config;

use json_mutation::{mutate_leaf, odd_value};
use proptest::prelude::*;
use proptest_config::config;
use serde_json::Value;
use talkin_data::dataset::{Dataset, Frame, Split, Subject};
use talkin_data::params_json::PARAM_LIMIT;
use talkin_human::body::{FrameParams, Skeleton};
use talkin_human::camera::Camera;

/// A small valid dataset.json document.
fn valid_document() -> Value {
    let mut rest = [glam::DVec3::ZERO; 55];
    for (j, r) in rest.iter_mut().enumerate() {
        *r = glam::DVec3::new(0.01 * j as f64, 0.02 * j as f64, 0.0);
    }
    rest[12] = glam::DVec3::new(0.0, 0.55, 0.0);
    let camera = Camera::look_at(
        24,
        32,
        40.0,
        glam::DVec3::new(0.0, 1.0, 3.0),
        glam::DVec3::new(0.0, 1.0, 0.0),
        glam::DVec3::Y,
    )
    .unwrap();
    let mut params = FrameParams::default();
    params.body_pose[3].x = 0.4;
    params.expression[2] = -1.0;
    let frame = |i: usize| Frame {
        subject: 0,
        split: Split::Train,
        time: i as f64 * 0.04,
        image: format!("images/{i}.png").into(),
        mask: format!("masks/{i}.png").into(),
        segmentation: (i == 0).then(|| format!("segmentation/{i}.png").into()),
        depth: None,
        camera,
        params: params.clone(),
    };
    Dataset {
        root: ".".into(),
        background: [1.0, 1.0, 1.0],
        matting: talkin_data::dataset::Matting::Matted,
        masks: Default::default(),
        subjects: vec![Subject {
            name: "ada".into(),
            skeleton: Skeleton { rest_joints: rest },
        }],
        frames: vec![frame(0), frame(1)],
    }
    .to_json()
}

/// Every number in an accepted dataset is finite, every parameter within the limit.
fn assert_sound(d: &Dataset) {
    assert!(d.background.iter().all(|c| (0.0..=1.0).contains(c)));
    for s in &d.subjects {
        assert!(s.skeleton.rest_joints.iter().all(|j| j.is_finite()));
    }
    for f in &d.frames {
        assert!(f.params.is_finite());
        let p = &f.params;
        let within = |x: f64| x.abs() <= PARAM_LIMIT;
        assert!(
            p.local_rotations()
                .iter()
                .all(|r| r.to_array().into_iter().all(within))
        );
        assert!(p.expression.iter().copied().all(within));
        assert!(p.transl.to_array().into_iter().all(within));
        assert!(f.time.is_finite());
        assert!(f.camera.intrinsics.is_finite());
        assert!(f.camera.camera_from_world.is_finite());
    }
}

proptest! {
    #![proptest_config(config(0x10ad_e125))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        let text = String::from_utf8_lossy(&bytes);
        if let Ok(d) = Dataset::from_json_str(&text, Path::new(".")) {
            assert_sound(&d);
        }
    }

    #[test]
    fn mutated_documents_never_panic_or_pass_unsound(
        to in odd_value(),
        picks in prop::collection::vec(any::<usize>(), 8),
    ) {
        let mut doc = valid_document();
        let mut k = 0;
        let mut pick = |n: usize| {
            k += 1;
            picks[k % picks.len()] % n
        };
        mutate_leaf(&mut doc, &mut pick, to);
        if let Ok(d) = Dataset::from_json_str(&doc.to_string(), Path::new(".")) {
            assert_sound(&d);
        }
    }

    /// Any number placed anywhere in a frame's parameters is accepted exactly when it
    /// is within the limit.
    #[test]
    fn parameters_beyond_the_limit_are_refused(
        x in prop_oneof![any::<f64>(), -2e3f64..2e3],
        picks in prop::collection::vec(any::<usize>(), 8),
    ) {
        prop_assume!(x.is_finite());
        let mut doc = valid_document();
        let mut k = 0;
        let mut pick = |n: usize| {
            k += 1;
            picks[k % picks.len()] % n
        };
        let params = &mut doc["frames"][1]["params"];
        let before = params.clone();
        mutate_leaf(params, &mut pick, serde_json::json!(x));
        prop_assume!(*params != before || x == 0.0);
        let loaded = Dataset::from_json_str(&doc.to_string(), Path::new("."));
        prop_assert_eq!(loaded.is_ok(), x.abs() <= PARAM_LIMIT, "{}: {:?}", x, loaded.err());
    }

    #[test]
    fn cut_or_spliced_text_never_panics(cut in 0usize..4096, splice in ".{0,8}") {
        let text = valid_document().to_string();
        let cut = cut.min(text.len());
        let cut = (0..=cut).rev().find(|&c| text.is_char_boundary(c)).unwrap_or(0);
        let damaged = format!("{}{splice}{}", &text[..cut], &text[cut..]);
        if let Ok(d) = Dataset::from_json_str(&damaged, Path::new(".")) {
            assert_sound(&d);
        }
        let _ = Dataset::from_json_str(&text[..cut], Path::new("."));
    }
}

#[test]
fn the_valid_document_is_valid() {
    let d = Dataset::from_json_str(&valid_document().to_string(), Path::new(".")).unwrap();
    assert_sound(&d);
    assert!(d.frames[1].segmentation.is_none());
}
