//! Inverse LBS against the synthetic generator's ground truth. Every primitive of the
//! mannequin is rigid with one joint, so a training pixel's true surface point has a true
//! canonical point: its owning joint's `canonical_from_posed` applied to it (a finger's
//! through its wrist, the body warp's bone). The skinning prior alone (the learned volume
//! at its start) must send the surface there; a map that blends two bones where limbs
//! meet smears the limb differently in every pose, which no radiance field can fit.

mod common;

use burn::prelude::*;
use glam::Vec3;
use talkin::avatar::field_inputs::frame_conditions;
use talkin::avatar::scene::{CapsuleShells, FrameScene, fit_subject_margins, foreground_rays};
use talkin::avatar::subject::bone_prior;
use talkin::data::dataset::{Dataset, Split};
use talkin::grids::MarginFitOpts;
use talkin::grids::intersect::signed_distance;
use talkin::human::body::canonical_params;
use talkin::human::body::skeleton::body_ancestor;
use talkin::nets::skinning::SkinningConfig;
use talkin::synth::{body::figure, look, proportions};

/// Per joint group (torso and legs, upper arms, forearms, hands, head): pixels and the
/// mean distance (metres) from the mapped to the true canonical point.
struct GroupErrors {
    pixels: [usize; 5],
    sum: [f64; 5],
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
/// fitted `shells`) with a volume built by `config`.
fn mapping_errors(
    dataset: &Dataset,
    shells: &CapsuleShells,
    config: &SkinningConfig,
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
        pixels: [0; 5],
        sum: [0.0; 5],
    };
    for i in dataset.split_indices(Split::Train) {
        let frame = &dataset.frames[i];
        let scene = FrameScene::new(skeleton, &canonical, &frame.params);
        let conditions = frame_conditions(0, &frame.params, &scene, shells);
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
            // Candidates as the sampler gives them: the bones of the grown capsules that
            // hold the point.
            let mask = grown
                .iter()
                .filter(|c| signed_distance(p, c) <= 0.0)
                .fold(0u64, |m, c| m | 1 << c.bone);
            let joint = fig.owning_joint(&scene.posed, p);
            points.push(p.to_array());
            masks.push(mask);
            truth.push((
                group(joint),
                scene.canonical_from_posed[body_ancestor(joint)].transform_point3(p),
            ));
        }
        let warp = volume
            .inverse_lbs(
                &points,
                &masks,
                &conditions.canonical_from_posed,
                &conditions.bone_capsules,
                &device,
            )
            .unwrap();
        let x = warp.x_canonical.try_to_vec_as::<f32>().unwrap();
        for (k, (g, want)) in truth.into_iter().enumerate() {
            let got = Vec3::new(x[3 * k], x[3 * k + 1], x[3 * k + 2]);
            out.pixels[g] += 1;
            out.sum[g] += (got - want).length() as f64;
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
    let posed = mapping_errors(
        &dataset,
        &shells,
        &SkinningConfig::new().with_posed_tau(Some(0.005)),
    );
    let canonical = mapping_errors(&dataset, &shells, &SkinningConfig::new());
    let names = ["torso and legs", "upper arms", "forearms", "hands", "head"];
    for g in 0..5 {
        eprintln!(
            "{}: {} pixels, posed prior {:.2} cm, canonical prior {:.2} cm",
            names[g],
            posed.pixels[g],
            100.0 * posed.mean(g),
            100.0 * canonical.mean(g)
        );
        assert!(
            posed.pixels[g] > 50,
            "{}: {} pixels",
            names[g],
            posed.pixels[g]
        );
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
    // thighs is the same systematic offset in every frame).
    for (g, name) in [(0, "torso and legs"), (4, "head")] {
        let (p, c) = (posed.mean(g), canonical.mean(g));
        assert!(
            p < 1.2 * c + 1e-3,
            "{name}: posed {p} m against canonical {c} m"
        );
    }
}
