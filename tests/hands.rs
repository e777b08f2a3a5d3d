//! Hard hand poses: a fist, spread fingers, a finger bent past 90 degrees, two hands
//! touching, a hand in front of the face and a hand partly outside the image. Each pose is
//! rendered by the synthetic generator (which knows every surface point's joint) close up
//! around the hand, then sampled and skinned as training would:
//! - every finger pixel's true surface point lies inside the accelerated sampler's
//!   intervals (0 misses), the capsule shells and grid being the subject's, fitted on
//!   frames that never showed these poses;
//! - inverse LBS with finger bones maps it finite, and a fingertip within a few
//!   millimetres of its true canonical point (the rest-pose hand), where moving the
//!   fingers with their wrist leaves centimetres (printed beside it).

mod common;

use glam::{DVec3, Vec3};
use talkin::avatar::field_inputs::frame_conditions;
use talkin::avatar::scene::{FrameSampler, FrameScene};
use talkin::avatar::subject::{SubjectModel, bone_prior};
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::{Ray, SURFACE_SLACK_M, SamplerKind};
use talkin::human::body::skeleton::joint;
use talkin::human::body::{FrameParams, canonical_params};
use talkin::human::camera::Camera;
use talkin::nets::field::POSED_TAU_M;
use talkin::nets::skinning::{FIRST_FINGER_JOINT, SkinningConfig, skinned_joint};
use talkin::synth::tracer::Scene;
use talkin::synth::{body::figure, look, proportions};

/// Image side of the close-ups (pixels) and their focal length: about 30 cm across at
/// the camera's 0.45 m.
const SIDE: u32 = 128;
const FOCAL: f64 = 190.0;
const DISTANCE: f64 = 0.45;

/// A fingertip's mapped canonical point may lie this far (metres) from its true one on
/// average over a pose, at most `TIP_MAX_M` for any one point. What is left is the blend
/// where two phalanges, or two hands, touch (measured: 0.5 mm mean and 7 mm at worst).
const TIP_MEAN_M: f64 = 0.002;
const TIP_MAX_M: f64 = 0.01;

/// One hard case: a pose and where the close-up camera looks.
struct Case {
    name: &'static str,
    params: FrameParams,
    /// Camera target, world.
    target: DVec3,
}

/// Flexes every joint of every finger of both hands by `fingers` radians, the thumbs by
/// half.
fn curl(params: &mut FrameParams, fingers: f64) {
    for (pose, sign) in [
        (&mut params.left_hand_pose, 1.0),
        (&mut params.right_hand_pose, -1.0),
    ] {
        for (k, r) in pose.iter_mut().enumerate() {
            let thumb = k >= 12;
            let bend = if thumb { 0.5 * fingers } else { fingers };
            *r = DVec3::new(0.0, 0.0, -sign * bend);
        }
    }
}

/// Turns the left shoulder and elbow (coordinate descent on their axis-angles) until the
/// left wrist is as near `target` as they can bring it.
fn reach(skeleton: &talkin::human::body::Skeleton, params: &mut FrameParams, target: DVec3) {
    let joints = [
        joint::LEFT_SHOULDER - 1,
        joint::LEFT_ELBOW - 1,
        joint::LEFT_COLLAR - 1,
    ];
    let miss = |p: &FrameParams| (skeleton.pose(p).joint(joint::LEFT_WRIST) - target).length();
    let mut step = 0.4;
    while step > 1e-3 {
        let mut improved = false;
        for &j in &joints {
            for axis in 0..3 {
                for sign in [1.0, -1.0] {
                    let mut trial = params.clone();
                    trial.body_pose[j][axis] += sign * step;
                    if miss(&trial) < miss(params) {
                        *params = trial;
                        improved = true;
                    }
                }
            }
        }
        if !improved {
            step *= 0.5;
        }
    }
}

fn cases(dataset: &Dataset) -> Vec<Case> {
    let skeleton = &dataset.subjects[0].skeleton;
    let base = canonical_params();
    let wrist = |p: &FrameParams, j: usize| skeleton.pose(p).joint(j);
    let mut out = Vec::new();

    let mut fist = base.clone();
    curl(&mut fist, 1.45);
    out.push(Case {
        name: "fist",
        target: wrist(&fist, joint::LEFT_WRIST),
        params: fist,
    });

    let mut spread = base.clone();
    for (pose, sign) in [
        (&mut spread.left_hand_pose, 1.0),
        (&mut spread.right_hand_pose, -1.0),
    ] {
        for f in 0..4 {
            pose[3 * f] = DVec3::new(0.0, -sign * 0.35 * (f as f64 - 1.5), 0.0);
        }
    }
    out.push(Case {
        name: "spread fingers",
        target: wrist(&spread, joint::LEFT_WRIST),
        params: spread,
    });

    let mut bent = base.clone();
    bent.left_hand_pose[0] = DVec3::new(0.0, 0.0, -1.75); // index knuckle, 100 degrees
    bent.left_hand_pose[1] = DVec3::new(0.0, 0.0, -1.3);
    bent.left_hand_pose[2] = DVec3::new(0.0, 0.0, -0.9);
    out.push(Case {
        name: "finger bent past 90 degrees",
        target: wrist(&bent, joint::LEFT_WRIST),
        params: bent,
    });

    // The left hand brought onto the right one, both half curled: clasped.
    let mut clasped = base.clone();
    curl(&mut clasped, 0.8);
    let right = wrist(&clasped, joint::RIGHT_WRIST);
    reach(skeleton, &mut clasped, right + DVec3::new(0.06, 0.0, 0.03));
    out.push(Case {
        name: "two hands touching",
        target: wrist(&clasped, joint::LEFT_WRIST),
        params: clasped,
    });

    // The left hand 12 cm in front of the face.
    let mut face = base.clone();
    curl(&mut face, 0.4);
    let head = wrist(&face, joint::HEAD);
    reach(skeleton, &mut face, head + DVec3::new(0.0, -0.05, 0.12));
    out.push(Case {
        name: "hand in front of the face",
        target: head,
        params: face,
    });

    // A camera aimed 17 cm past the wrist: the wrist and part of the palm fall outside
    // the image.
    let mut outside = base.clone();
    curl(&mut outside, 0.6);
    out.push(Case {
        name: "hand partly outside the image",
        target: wrist(&outside, joint::LEFT_WRIST) + DVec3::new(0.17, 0.0, 0.0),
        params: outside,
    });
    out
}

/// A case's finger pixels: for each, the ray, the surface point and its owning joint.
struct FingerPixels {
    rays: Vec<Ray>,
    t: Vec<f32>,
    points: Vec<[f32; 3]>,
    joints: Vec<usize>,
    /// Finger pixels the image shows at all (a case must show fingers).
    visible: usize,
}

fn finger_pixels(dataset: &Dataset, case: &Case, camera: &Camera) -> FingerPixels {
    let skeleton = &dataset.subjects[0].skeleton;
    let posed = skeleton.pose(&case.params);
    let fig = figure(skeleton, &proportions(0), &look(0), &case.params);
    let rendered = Scene::new(&fig, &posed, Vec3::ONE).render(camera);
    let forward = camera.forward_in_world();
    let mut out = FingerPixels {
        rays: vec![],
        t: vec![],
        points: vec![],
        joints: vec![],
        visible: 0,
    };
    for y in 0..SIDE {
        for x in 0..SIDE {
            let z = rendered.depth[(y * SIDE + x) as usize];
            if z <= 0.0 {
                continue;
            }
            let (o, d) = camera.pixel_ray(x, y);
            let t = z as f64 / d.dot(forward);
            let p = (o + d * t).as_vec3();
            let j = fig.owning_joint(&posed, p);
            if j < FIRST_FINGER_JOINT {
                continue;
            }
            out.visible += 1;
            out.rays
                .push(Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY).unwrap());
            out.t.push(t as f32);
            out.points.push(p.to_array());
            out.joints.push(j);
        }
    }
    out
}

#[test]
fn hard_hand_poses_are_sampled_and_skinned_to_the_rest_pose_hand() {
    let dataset = common::synthetic_scene("hard_hands", 1, 160, 7);
    let train = dataset.split_indices(Split::Train);
    let model = SubjectModel::fit(&dataset, 0, &train, 64).unwrap();
    let skeleton = &dataset.subjects[0].skeleton;
    let device = burn::prelude::Device::flex();
    let volume = |finger_bones: bool| {
        SkinningConfig::new()
            .with_posed_tau(Some(POSED_TAU_M))
            .with_finger_bones(Some(finger_bones))
            .init(
                [-1.2, -1.3, -0.6],
                [1.2, 1.0, 0.6],
                &bone_prior([skeleton]),
                &device,
            )
            .unwrap()
    };
    let (bones, wrist) = (volume(true), volume(false));
    for case in cases(&dataset) {
        let eye = case.target + DVec3::new(0.0, 0.0, DISTANCE);
        let camera = Camera::look_at(SIDE, SIDE, FOCAL, eye, case.target, DVec3::Y).unwrap();
        let px = finger_pixels(&dataset, &case, &camera);
        assert!(
            px.visible > 100,
            "{}: {} finger pixels",
            case.name,
            px.visible
        );

        // Sampling: the accelerated sampler as training builds it.
        let scene = FrameScene::new(skeleton, &model.canonical, &case.params);
        let grown = model.shells.inflate(&scene.capsules);
        let sampler = FrameSampler::new(scene.clone(), &model.shells, &px.rays, true).unwrap();
        let samples = sampler
            .sample(
                SamplerKind::Accelerated,
                &px.rays,
                &model.grid,
                &model.dilated,
                None,
            )
            .unwrap();
        let misses = (0..px.rays.len())
            .filter(|&r| !samples.holds(r, px.t[r], SURFACE_SLACK_M))
            .count();
        assert!(
            samples
                .t_start
                .iter()
                .chain(&samples.t_end)
                .all(|t| t.is_finite()),
            "{}: non-finite samples",
            case.name
        );

        // Skinning: each surface point with its candidates as the sampler gives them.
        let masks: Vec<u64> = px
            .points
            .iter()
            .map(|p| common::candidate_mask(&grown, Vec3::from_array(*p)))
            .collect();
        let tip_errors = |finger_bones: bool| -> Vec<f64> {
            let volume = if finger_bones { &bones } else { &wrist };
            let conditions = frame_conditions(0, &case.params, &scene, &model.shells, finger_bones);
            let x = common::skin(volume, &px.points, &masks, &conditions);
            assert!(x.iter().all(|v| v.is_finite()), "{}: NaN", case.name);
            (0..px.points.len())
                .filter(|&k| (px.joints[k] - FIRST_FINGER_JOINT) % 3 == 2)
                .map(|k| {
                    let got = x[k];
                    let p = Vec3::from_array(px.points[k]);
                    let want = scene.canonical_from_posed[skinned_joint(px.joints[k], true)]
                        .transform_point3(p);
                    (got - want).length() as f64
                })
                .collect()
        };
        let (with_bones, with_wrist) = (tip_errors(true), tip_errors(false));
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        let quantile = |v: &[f64], q: f64| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            v.get(((v.len() as f64 * q) as usize).min(v.len().saturating_sub(1)))
                .copied()
                .unwrap_or(0.0)
        };
        eprintln!(
            "{}: {} finger pixels, {misses} missed; fingertips ({}): finger bones {:.2} mm \
             mean, {:.2} median, {:.2} 90%, {:.2} max; wrist {:.2} mm mean",
            case.name,
            px.visible,
            with_bones.len(),
            1e3 * mean(&with_bones),
            1e3 * quantile(&with_bones, 0.5),
            1e3 * quantile(&with_bones, 0.9),
            1e3 * max(&with_bones),
            1e3 * mean(&with_wrist),
        );
        assert_eq!(
            misses, 0,
            "{}: finger surface outside the samples",
            case.name
        );
        assert!(
            with_bones.len() > 10,
            "{}: {} fingertip pixels",
            case.name,
            with_bones.len()
        );
        assert!(
            mean(&with_bones) < TIP_MEAN_M && max(&with_bones) < TIP_MAX_M,
            "{}: fingertips {} m mean, {} m max",
            case.name,
            mean(&with_bones),
            max(&with_bones)
        );
    }
}
