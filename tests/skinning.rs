//! Inverse LBS against the synthetic generator's ground truth. Every primitive of the
//! mannequin is rigid with one joint, so a training pixel's true surface point has a true
//! canonical point: its owning joint's `canonical_from_posed` applied to it (a finger's
//! through its own joint: the rest-pose hand). The skinning prior alone (the learned
//! volume at its start) must send the surface there; a map that blends two bones where
//! limbs meet smears the limb differently in every pose, which no radiance field can fit,
//! and a map that moves the fingers with their wrist leaves every finger pose in the
//! canonical hand.

mod common;

use burn::prelude::*;
use talkin::avatar::field_inputs::frame_conditions;
use talkin::avatar::scene::{CapsuleShells, FrameScene, fit_subject_margins, foreground_rays};
use talkin::avatar::subject::bone_prior;
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::MarginFitOpts;
use talkin::human::body::canonical_params;
use talkin::human::body::skeleton::body_ancestor;
use talkin::nets::field::POSED_TAU_M;
use talkin::nets::skinning::{FIRST_FINGER_JOINT, SkinningConfig};
use talkin::synth::{body::figure, look, proportions};

/// Per joint group (torso and legs, upper arms, forearms, hands, head, and again on their
/// own the hands' fingertips and the head's jaw and eyes): pixels and the mean distance
/// (metres) from the mapped to the true canonical point.
struct GroupErrors {
    pixels: [usize; 7],
    sum: [f64; 7],
}

const GROUPS: [&str; 7] = [
    "torso and legs",
    "upper arms",
    "forearms",
    "hands",
    "head",
    "fingertips",
    "jaw and eyes",
];

/// Whether SMPL-X joint `joint` carries a fingertip (the third joint of a finger).
fn is_fingertip(joint: usize) -> bool {
    joint >= FIRST_FINGER_JOINT && (joint - FIRST_FINGER_JOINT) % 3 == 2
}

impl GroupErrors {
    fn mean(&self, g: usize) -> f64 {
        self.sum[g] / self.pixels[g].max(1) as f64
    }
}

fn group(joint: usize) -> usize {
    match body_ancestor(joint) {
        16 | 17 => 1,
        18 | 19 => 2,
        20 | 21 => 3,
        12 | 15 => 4,
        _ => 0,
    }
}

/// Maps every training pixel's true surface point of `dataset` (one subject with the
/// fitted `shells`) with a volume built by `config`, against the truth through each
/// point's own joint (`own_joint`) or through its body ancestor (the fingers' wrist, the
/// jaw's and eyes' head).
fn mapping_errors(
    dataset: &Dataset,
    shells: &CapsuleShells,
    config: &SkinningConfig,
    own_joint: bool,
) -> GroupErrors {
    let device = Device::flex();
    let skeleton = &dataset.subjects[0].skeleton;
    let canonical = skeleton.pose(&canonical_params());
    let volume = config
        .init(
            [-1.2, -1.3, -0.6],
            [1.2, 1.0, 0.6],
            &bone_prior([skeleton]),
            &device,
        )
        .unwrap();
    let mut out = GroupErrors {
        pixels: [0; 7],
        sum: [0.0; 7],
    };
    for i in dataset.split_indices(Split::Train) {
        let frame = &dataset.frames[i];
        let scene = FrameScene::new(skeleton, &canonical, &frame.params);
        let conditions = frame_conditions(0, &frame.params, &scene, shells, config.skins_fingers());
        let fig = figure(skeleton, &proportions(0), &look(0), &frame.params);
        let images = dataset.images(i).unwrap();
        let depth = dataset.depth(i).unwrap().expect("synthetic depth");
        let (rays, pixels) = foreground_rays(&frame.camera, &images).unwrap();
        let forward = frame.camera.forward_in_world().as_vec3();
        let grown = shells.inflate(&scene.capsules);
        let (mut points, mut masks, mut truth) = (vec![], vec![], vec![]);
        for (ray, &pixel) in rays.iter().zip(&pixels) {
            let Some(z) = depth[pixel as usize] else {
                continue;
            };
            let p = ray.ray.origin + ray.ray.direction * (z / ray.ray.direction.dot(forward));
            let mask = common::candidate_mask(&grown, p);
            let joint = fig.owning_joint(&scene.posed, p);
            points.push(p.to_array());
            masks.push(mask);
            truth.push((
                joint,
                scene.canonical_from_posed[if own_joint {
                    joint
                } else {
                    body_ancestor(joint)
                }]
                .transform_point3(p),
            ));
        }
        let mapped = common::skin(&volume, &points, &masks, &conditions);
        for ((joint, want), got) in truth.into_iter().zip(mapped) {
            let error = (got - want).length() as f64;
            let jaw_or_eye = (22..FIRST_FINGER_JOINT).contains(&joint).then_some(6);
            let tip = is_fingertip(joint).then_some(5);
            for g in std::iter::once(group(joint)).chain(tip).chain(jaw_or_eye) {
                out.pixels[g] += 1;
                out.sum[g] += error;
            }
        }
    }
    out
}

#[test]
fn the_posed_prior_maps_the_synthetic_surface_to_its_true_canonical_point() {
    let dataset = common::synthetic_scene("skinning_truth", 1, 160, 7);
    let shells = fit_subject_margins(&dataset, 0, &MarginFitOpts::default())
        .unwrap()
        .shells;
    // Both with finger bones, against each point's own joint but the jaw's and eyes'
    // (which both move with the head): the priors alone compared.
    let fingers = SkinningConfig::new().with_finger_bones(Some(true));
    let posed = mapping_errors(
        &dataset,
        &shells,
        &fingers.clone().with_posed_tau(Some(POSED_TAU_M)),
        true,
    );
    let canonical = mapping_errors(&dataset, &shells, &fingers, true);
    for (g, name) in GROUPS.iter().enumerate().take(6) {
        eprintln!(
            "{name}: {} pixels, posed prior {:.2} cm, canonical prior {:.2} cm",
            posed.pixels[g],
            100.0 * posed.mean(g),
            100.0 * canonical.mean(g)
        );
        assert!(posed.pixels[g] > 50, "{name}: {} pixels", posed.pixels[g]);
    }
    // Arms: millimetres with the posed prior, centimetres with the canonical one.
    for (g, name, bound) in [(1, "upper arms", 0.01), (2, "forearms", 0.008)] {
        let (p, c) = (posed.mean(g), canonical.mean(g));
        assert!(p < bound, "{name}: {p} m");
        assert!(p < 0.5 * c, "{name}: posed {p} m against canonical {c} m");
    }
    // Hands: two of these frames have them clasped, where the two wrists' cores are
    // equally near and the blend is between them, so centimetres remain; still well under
    // half the canonical prior's error.
    let (p, c) = (posed.mean(3), canonical.mean(3));
    assert!(p < 0.5 * c, "hands: posed {p} m against canonical {c} m");
    // The torso and head: no worse than the canonical prior (the skirt's blend with the
    // thighs is the same systematic offset in every frame; the head's error is its jaw
    // and eyes, which both map with the head).
    for (g, name) in [(0, "torso and legs"), (4, "head")] {
        let (p, c) = (posed.mean(g), canonical.mean(g));
        assert!(
            p < 1.2 * c + 1e-3,
            "{name}: posed {p} m against canonical {c} m"
        );
    }
}

/// Finger bones against the wrist, both with the posed prior, against the true rest-pose
/// hand: skinning each finger about its own knuckles must at least halve the fingertips'
/// error (the wrist's map leaves every curl and spread in the canonical hand), and move
/// no other part. The jaw and eyes, which both maps move with the head, are printed
/// against their own joints: what skinning them could gain.
#[test]
fn finger_bones_map_the_fingers_to_the_rest_pose_hand() {
    let dataset = common::synthetic_scene("skinning_fingers", 1, 160, 7);
    let shells = fit_subject_margins(&dataset, 0, &MarginFitOpts::default())
        .unwrap()
        .shells;
    let config = SkinningConfig::new().with_posed_tau(Some(POSED_TAU_M));
    let wrist = mapping_errors(&dataset, &shells, &config, true);
    let bones = mapping_errors(
        &dataset,
        &shells,
        &config.with_finger_bones(Some(true)),
        true,
    );
    for (g, name) in GROUPS.iter().enumerate() {
        eprintln!(
            "{name}: {} pixels, finger bones {:.2} cm, wrist {:.2} cm",
            bones.pixels[g],
            100.0 * bones.mean(g),
            100.0 * wrist.mean(g)
        );
    }
    assert!(
        bones.pixels[5] > 50,
        "fingertips: {} pixels",
        bones.pixels[5]
    );
    let (b, w) = (bones.mean(5), wrist.mean(5));
    assert!(
        b < 0.5 * w,
        "fingertips: finger bones {b} m against wrist {w} m"
    );
    let (b, w) = (bones.mean(3), wrist.mean(3));
    assert!(b < w, "hands: finger bones {b} m against wrist {w} m");
    // A forearm point the other hand touches (clasped hands) may now follow a finger of
    // that hand instead of its wrist; nothing else changes.
    for g in 0..3 {
        let (b, w) = (bones.mean(g), wrist.mean(g));
        assert!(
            b <= 1.1 * w + 1e-3,
            "{}: finger bones {b} m against wrist {w} m",
            GROUPS[g]
        );
    }
}
