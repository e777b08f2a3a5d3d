//! One subject in its canonical pose as the renderer sees it: the field's density and
//! colour at canonical points, each point with the candidate bones and parts the sampler
//! would give it (the inflated capsules that hold it), culled where the renderer culls
//! (outside every capsule, or in a cell the occupancy grid marks empty).
//!
//! The canonical pose maps every joint to itself, so inverse skinning leaves the points
//! where they are; D_nr sees the canonical body pose, the face a neutral expression and
//! closed jaw, the hands the rest hand, and F_body the mean of the frame codes (a frame
//! the run did not train on). The field has no view direction: its colour is the same
//! from every side.

use burn::prelude::*;
use glam::Vec3;
use rayon::prelude::*;
use talkin_avatar::Avatar;
use talkin_avatar::field_inputs::frame_conditions;
use talkin_avatar::scene::FrameScene;
use talkin_avatar::subject::SubjectModel;
use talkin_grids::Capsule;
use talkin_grids::intersect::signed_distance;
use talkin_human::body::canonical_params;
use talkin_nets::{FieldInput, FrameConditions, read_floats};

use crate::ExportError;

/// Points per field forward (the renderer's CPU cap is twice this).
const FORWARD_POINTS: usize = 1 << 16;

/// The field's density and colour at one canonical point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Radiance {
    /// Density (1/m); 0 where the renderer would never sample.
    pub sigma: f32,
    /// Colour in [0, 1].
    pub rgb: [f32; 3],
}

/// A subject of an avatar, posed canonically.
pub struct CanonicalSubject<'a> {
    avatar: &'a Avatar,
    identity: usize,
    model: &'a SubjectModel,
    conditions: FrameConditions,
    /// The sampler's capsules in the canonical pose (grown by their shells' margins).
    capsules: Vec<Capsule>,
}

impl<'a> CanonicalSubject<'a> {
    /// Subject `name` of `avatar` (an unknown or untrained name is an error listing the
    /// trained ones).
    pub fn new(avatar: &'a Avatar, name: &str) -> Result<Self, ExportError> {
        let (identity, model) = avatar.subject(name)?;
        let params = canonical_params();
        let scene = FrameScene::new(&model.skeleton, &model.canonical, &params);
        let fingers = avatar.config.skinning.skins_fingers();
        let conditions = frame_conditions(identity, &params, &scene, &model.shells, fingers);
        let capsules = model.shells.inflate(&scene.capsules);
        Ok(CanonicalSubject {
            avatar,
            identity,
            model,
            conditions,
            capsules,
        })
    }

    pub fn avatar(&self) -> &Avatar {
        self.avatar
    }

    pub fn model(&self) -> &SubjectModel {
        self.model
    }

    /// The avatar's identity index of the subject.
    pub fn identity(&self) -> usize {
        self.identity
    }

    /// The field's conditions of the canonical frame.
    pub fn conditions(&self) -> &FrameConditions {
        &self.conditions
    }

    /// The box holding every point the renderer may sample: the occupancy grid's.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.model.grid.aabb()
    }

    /// The candidate bones and parts of `p` (those of the grown capsules holding it),
    /// `(0, 0)` outside them all.
    pub fn candidates(&self, p: Vec3) -> (u64, u8) {
        self.capsules
            .iter()
            .filter(|c| signed_distance(p, c) <= 0.0)
            .fold((0, 0), |(bones, parts), c| {
                (bones | 1 << c.bone, parts | c.part.bit())
            })
    }

    /// Whether the renderer samples `p` at all.
    pub fn is_sampled(&self, p: Vec3) -> bool {
        self.model.grid.is_occupied(p) && self.candidates(p).0 != 0
    }

    /// The field at `points` (zero density where the renderer never samples).
    pub fn radiance(&self, points: &[Vec3]) -> Result<Vec<Radiance>, ExportError> {
        let masks: Vec<(u64, u8)> = points
            .par_iter()
            .map(|&p| {
                if self.model.grid.is_occupied(p) {
                    self.candidates(p)
                } else {
                    (0, 0)
                }
            })
            .collect();
        let kept: Vec<usize> = (0..points.len()).filter(|&i| masks[i].0 != 0).collect();
        let values: Vec<Vec<Radiance>> = kept
            .par_chunks(FORWARD_POINTS)
            .map(|chunk| {
                let pts: Vec<[f32; 3]> = chunk.iter().map(|&i| points[i].to_array()).collect();
                let bones: Vec<u64> = chunk.iter().map(|&i| masks[i].0).collect();
                let parts: Vec<u8> = chunk.iter().map(|&i| masks[i].1).collect();
                self.forward(&pts, &bones, &parts)
            })
            .collect::<Result<_, _>>()?;
        let mut out = vec![Radiance::default(); points.len()];
        for (&i, r) in kept.iter().zip(values.into_iter().flatten()) {
            out[i] = r;
        }
        Ok(out)
    }

    /// One forward of the field. Where the hands' second pass has a sample (it
    /// composites in front of the body's), the denser of the two passes is kept.
    fn forward(
        &self,
        points: &[[f32; 3]],
        bone_masks: &[u64],
        part_masks: &[u8],
    ) -> Result<Vec<Radiance>, ExportError> {
        let input = FieldInput {
            points,
            bone_masks,
            part_masks,
            frame: &self.conditions,
            step: self.avatar.field_step,
        };
        let output = self.avatar.field.forward(&input)?;
        let host = |t: Tensor<2>| read_floats(t).map_err(|_| ExportError::NonFinite);
        let sigma = host(output.sigma.unsqueeze_dim(1))?;
        let rgb = host(output.rgb)?;
        let mut out: Vec<Radiance> = sigma
            .iter()
            .zip(rgb.chunks_exact(3))
            .map(|(&sigma, c)| Radiance {
                sigma,
                rgb: [c[0], c[1], c[2]],
            })
            .collect();
        if let Some(hands) = output.hands {
            let sigma = host(hands.sigma.unsqueeze_dim(1))?;
            let rgb = host(hands.rgb)?;
            for (k, &i) in hands.indices.iter().enumerate() {
                if sigma[k] > out[i].sigma {
                    out[i] = Radiance {
                        sigma: sigma[k],
                        rgb: [rgb[3 * k], rgb[3 * k + 1], rgb[3 * k + 2]],
                    };
                }
            }
        }
        if out
            .iter()
            .any(|r| !r.sigma.is_finite() || r.rgb.iter().any(|c| !c.is_finite()))
        {
            return Err(ExportError::NonFinite);
        }
        Ok(out)
    }
}
