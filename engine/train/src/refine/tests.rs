//! Hard cases of pose refinement: a correction that carries an elbow past pi, a hand
//! pushed inside the torso, a frame whose hands nothing sees, a gradient that is not
//! finite. Nothing turns NaN, and the rebuilt capsules hold the refined body.

use std::path::PathBuf;

use glam::DVec3;
use talkin_avatar::refined::layout::{self, BODY, DIM, HANDS};
use talkin_avatar::scene::{CapsuleShells, FrameScene};
use talkin_data::dataset::{Dataset, Frame, Split, Subject};
use talkin_human::body::{FrameParams, Skeleton, canonical_params, joint};
use talkin_human::camera::Camera;
use talkin_synth::body::default_rest_joints;

use super::{PoseRefiner, RefineMode, RefineOptions};

fn camera() -> Camera {
    Camera::look_at(
        64,
        64,
        80.0,
        DVec3::new(0.0, 0.0, 3.0),
        DVec3::ZERO,
        DVec3::Y,
    )
    .unwrap()
}

/// One subject, `n` training frames 0.04 s apart, all posed as `params`.
fn dataset(n: usize, params: &FrameParams) -> Dataset {
    let skeleton = default_rest_joints(0);
    Dataset {
        root: PathBuf::from("/nonexistent"),
        background: [1.0; 3],
        matting: talkin_data::dataset::Matting::Matted,
        masks: Default::default(),
        subjects: vec![Subject {
            name: "ada".into(),
            skeleton,
        }],
        frames: (0..n)
            .map(|i| Frame {
                subject: 0,
                split: Split::Train,
                time: 0.04 * i as f64,
                image: format!("images/{i}.png").into(),
                mask: format!("masks/{i}.png").into(),
                segmentation: None,
                depth: None,
                camera: camera(),
                params: params.clone(),
            })
            .collect(),
    }
}

fn opts() -> RefineOptions {
    RefineOptions {
        refine_poses: RefineMode::On,
        pose_warmup: 0,
        ..RefineOptions::default()
    }
}

const LEFT_ELBOW_X: usize = BODY.start + 3 * (joint::LEFT_ELBOW - 1);

/// An elbow bent nearly to pi, and the shoulder turned (searched on a grid) so that a
/// 0.6 rad correction of the elbow puts the wrist deepest inside the torso.
fn folded() -> FrameParams {
    let skeleton = default_rest_joints(0);
    let mut best = (f64::INFINITY, canonical_params());
    for a in 0..24 {
        for b in 0..12 {
            let mut p = canonical_params();
            p.body_pose[joint::LEFT_SHOULDER - 1] =
                DVec3::new(0.0, a as f64 * 0.26 - 3.1, b as f64 * 0.26 - 1.5);
            p.body_pose[joint::LEFT_ELBOW - 1] = DVec3::new(0.0, 3.0, 0.0);
            let mut q = p.clone();
            q.body_pose[joint::LEFT_ELBOW - 1].y += 0.6;
            let posed = skeleton.pose(&q);
            let d = (posed.joint(joint::LEFT_WRIST) - posed.joint(joint::SPINE2)).length();
            if d < best.0 {
                best = (d, p);
            }
        }
    }
    best.1
}

#[test]
fn a_correction_past_pi_with_a_hand_in_the_torso_stays_finite_and_inside_its_capsules() {
    let skeleton: Skeleton = default_rest_joints(0);
    let canonical = skeleton.pose(&canonical_params());
    let fit = folded();
    let mut delta = vec![0.0f32; DIM];
    delta[LEFT_ELBOW_X + 1] = 0.6; // 3.6 rad: past pi
    let refined = layout::corrected(&fit, &delta);
    assert!(refined.body_pose[joint::LEFT_ELBOW - 1].length() > std::f64::consts::PI);
    let scene = FrameScene::new(&skeleton, &canonical, &refined);
    assert!(
        scene
            .capsules
            .iter()
            .all(|c| c.a.is_finite() && c.b.is_finite() && c.radius.is_finite())
    );
    assert!(scene.canonical_from_posed.iter().all(|m| m.is_finite()));
    // The hand is inside the torso: the wrist lies in a bare torso capsule.
    let posed = skeleton.pose(&refined);
    let wrist = posed.joint(joint::LEFT_WRIST).as_vec3();
    let torso = [joint::PELVIS, joint::SPINE1, joint::SPINE2, joint::SPINE3];
    let contains = |c: &talkin_grids::Capsule, p: glam::Vec3, slack: f32| {
        let ab = c.b - c.a;
        let t = ((p - c.a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        (c.a + t * ab - p).length() <= c.radius + slack
    };
    assert!(
        scene
            .capsules
            .iter()
            .any(|c| torso.contains(&(c.bone as usize)) && contains(c, wrist, 0.0)),
        "the wrist at {wrist} is not inside the torso"
    );
    // Every refined joint of the hand lies in a grown capsule: the sampler's intervals
    // are those capsules', rebuilt from the refined pose.
    let n = scene.capsules.len();
    let shells = CapsuleShells {
        margin: vec![0.02; n],
        core: scene.capsules.iter().map(|c| 0.5 * c.radius).collect(),
        core_shrink: vec![0.0; n],
        from_depth: false,
    };
    let grown = shells.inflate(&scene.capsules);
    let hand =
        std::iter::once(joint::LEFT_WRIST).chain(joint::LEFT_HAND_FIRST..joint::RIGHT_HAND_FIRST);
    for j in hand {
        let p = posed.joint(j).as_vec3();
        let inside = grown.iter().any(|c| contains(c, p, 1e-4));
        assert!(inside, "joint {j} at {p} is outside every grown capsule");
    }
    // And the chain rule's gradient there is finite.
    let grads = talkin_nets::field::leaves::zero_grads(63);
    let mut g = grads.clone();
    g.canonical_from_posed[joint::LEFT_ELBOW][3] = 1.0;
    let d = super::chain::correction_gradient(&skeleton, &canonical, &fit, &delta, &g);
    assert!(d.iter().all(|v| v.is_finite()));
    assert!(d.iter().any(|v| *v != 0.0));
}

#[test]
fn hands_nothing_sees_only_follow_the_prior_and_their_neighbours() {
    let fit = folded();
    let data = dataset(3, &fit);
    let mut r = PoseRefiner::new(&data, &[0, 1, 2], opts());
    // A gradient on the body only (no hand sample was drawn): the hands stay put.
    let mut g = [0.0f64; DIM];
    g[LEFT_ELBOW_X] = 0.3;
    for _ in 0..5 {
        r.update(1, Some(&g));
    }
    let d = r.delta_of(1).unwrap();
    assert!(d.iter().all(|v| v.is_finite()));
    assert!(HANDS.clone().all(|k| d[k] == 0.0));
    assert!(
        d[LEFT_ELBOW_X] < 0.0,
        "moved down its gradient: {}",
        d[LEFT_ELBOW_X]
    );
    // Adam moves it by at most the learning rate a visit, and the fits do not jitter, so
    // the pull toward them holds it within a few: its neighbours did not move.
    assert!(d[LEFT_ELBOW_X].abs() <= 5.0 * r.opts.pose_lr as f32 + 1e-6);
    assert!(r.delta_of(0).unwrap().iter().all(|&v| v == 0.0));
}

#[test]
fn a_gradient_that_is_not_finite_changes_nothing() {
    let data = dataset(2, &canonical_params());
    let mut r = PoseRefiner::new(&data, &[0, 1], opts());
    let before = r.state.clone();
    let mut g = [0.0f64; DIM];
    g[3] = f64::NAN;
    r.update(0, Some(&g));
    g[3] = f64::INFINITY;
    r.update(1, Some(&g));
    assert_eq!(r.state, before);
    // A frame that is not a training frame is ignored.
    r.update(7, Some(&[1.0; DIM]));
    assert_eq!(r.state, before);
}

#[test]
fn the_smoothness_pull_brings_jitter_toward_the_neighbours_and_leaves_smooth_motion() {
    // Jitter: every other frame off by 0.2 rad (rougher than a random walk).
    let mut data = dataset(5, &canonical_params());
    for i in [1, 3] {
        data.frames[i].params.body_pose[3].x += 0.2;
    }
    let smoothing = RefineOptions {
        pose_smooth: 0.5,
        pose_prior: 0.0,
        ..opts()
    };
    let mut r = PoseRefiner::new(&data, &[0, 1, 2, 3, 4], smoothing.clone());
    for _ in 0..10 {
        r.update(1, None);
    }
    let k = BODY.start + 9;
    let p = r.params_of(&data, 1).body_pose[3].x - canonical_params().body_pose[3].x;
    assert!(p.abs() < 0.01, "{p} left of the 0.2 jitter");
    assert!(r.delta_of(1).unwrap()[k] < -0.19);

    // Smooth motion (a steady turn): nothing pulls it, however often a frame is visited.
    let mut data = dataset(5, &canonical_params());
    for i in 0..5 {
        data.frames[i].params.body_pose[3].x += 0.05 * i as f64;
    }
    let mut r = PoseRefiner::new(&data, &[0, 1, 2, 3, 4], smoothing);
    for _ in 0..10 {
        r.update(2, None);
    }
    assert!(r.delta_of(2).unwrap().iter().all(|&v| v == 0.0));
}

#[test]
fn jittery_fits_learn_at_the_jitter_rate_and_smooth_ones_at_the_base_rate() {
    // Adam's first step moves a coordinate by exactly its rate; with no prior and no
    // smoothness pull, what moved is the rate the group was given.
    let free = RefineOptions {
        pose_lr: 1e-3,
        pose_lr_jitter: 5e-3,
        pose_prior: 0.0,
        pose_smooth: 0.0,
        ..opts()
    };
    let k = BODY.start + 9;
    let mut g = [0.0f64; DIM];
    g[k] = 0.3;

    let mut jittery = dataset(5, &canonical_params());
    for i in [1, 3] {
        jittery.frames[i].params.body_pose[3].x += 0.2;
    }
    let mut r = PoseRefiner::new(&jittery, &[0, 1, 2, 3, 4], free.clone());
    r.update(2, Some(&g));
    let moved = r.delta_of(2).unwrap()[k] as f64;
    assert!((moved + 5e-3).abs() < 1e-6, "jittery body moved {moved}");

    // A steady turn: trusted, so the pull toward the fit (0.25 a visit) follows Adam.
    let mut smooth = dataset(5, &canonical_params());
    for i in 0..5 {
        smooth.frames[i].params.body_pose[3].x += 0.05 * i as f64;
    }
    let mut r = PoseRefiner::new(&smooth, &[0, 1, 2, 3, 4], free);
    r.update(2, Some(&g));
    let moved = r.delta_of(2).unwrap()[k] as f64;
    assert!(
        (moved + 1e-3 * 0.75).abs() < 1e-6,
        "smooth body moved {moved}"
    );
}

#[test]
fn frames_seconds_apart_are_not_neighbours() {
    // Jitter-like differences between frames 2 s apart: a body's motion, not a fitter's
    // noise. Nothing pulls them together, however often they are visited.
    let mut data = dataset(5, &canonical_params());
    for (i, f) in data.frames.iter_mut().enumerate() {
        f.time = 2.0 * i as f64;
        if i % 2 == 1 {
            f.params.body_pose[3].x += 0.2;
        }
    }
    let smoothing = RefineOptions {
        pose_smooth: 0.5,
        pose_prior: 0.0,
        ..opts()
    };
    let mut r = PoseRefiner::new(&data, &[0, 1, 2, 3, 4], smoothing);
    for _ in 0..10 {
        r.update(1, None);
    }
    assert!(r.delta_of(1).unwrap().iter().all(|&v| v == 0.0));
}
