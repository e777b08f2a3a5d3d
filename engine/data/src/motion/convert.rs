//! Bringing a motion into our conventions for one subject: mean hands added, z-up turned
//! y-up, translation moved to the subject's skeleton, frame rate changed.
//!
//! SMPL-X rotates the root about the **rest pelvis** `J0`, so the posed pelvis is
//! `J0 + trans`. A rigid change of world frame `Q` keeps every posed point where it was
//! only if `R_root' = Q R_root` and `trans' = Q (trans + J0) - J0`; the translation needs
//! the rest pelvis of the body that performs it, so the conversion is applied at render
//! time with the subject's skeleton ([`change_frame`], [`z_up_to_y_up`]).

use glam::{DMat3, DQuat, DVec3};

use super::{Hands, Motion, MotionError, UpAxis};
use crate::smplx_model::SmplxModel;
use talkin_human::body::{
    FrameParams, N_JOINTS, Skeleton, axis_angle_from_rotation, rotation_from_axis_angle,
};

/// z-up to y-up, a -90 degree turn about x: (x, y, z) -> (x, z, -y).
pub const Z_UP_TO_Y_UP: DMat3 = DMat3::from_cols(
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 0.0, -1.0),
    DVec3::new(0.0, 1.0, 0.0),
);

/// `frame` seen in a world turned by `q`: the root rotation pre-multiplied by `q`, the
/// translation `q (trans + from_pelvis) - to_pelvis`. With `from_pelvis == to_pelvis` (the
/// performer's rest pelvis) every posed point `x` becomes `q x`; a different `to_pelvis`
/// also moves the motion onto a body whose rest pelvis is there, keeping the posed pelvis.
pub fn change_frame(
    frame: &FrameParams,
    q: DMat3,
    from_pelvis: DVec3,
    to_pelvis: DVec3,
) -> FrameParams {
    FrameParams {
        global_orient: axis_angle_from_rotation(q * rotation_from_axis_angle(frame.global_orient)),
        transl: q * (frame.transl + from_pelvis) - to_pelvis,
        ..frame.clone()
    }
}

/// An AMASS (z-up) frame in our y-up world, for a body whose rest pelvis is `rest_pelvis`.
pub fn z_up_to_y_up(frame: &FrameParams, rest_pelvis: DVec3) -> FrameParams {
    change_frame(frame, Z_UP_TO_Y_UP, rest_pelvis, rest_pelvis)
}

/// Resamples frames captured at `from_fps` to `to_fps`, over the same duration (the last
/// output frame is at or before the last input frame). Joint rotations are interpolated as
/// rotations (slerp of unit quaternions along the shorter arc), translation and
/// expression linearly.
pub fn resample(frames: &[FrameParams], from_fps: f64, to_fps: f64) -> Vec<FrameParams> {
    if frames.is_empty() || from_fps == to_fps {
        return frames.to_vec();
    }
    let last = (frames.len() - 1) as f64;
    let count = (last * to_fps / from_fps + 1e-9).floor() as usize + 1;
    (0..count)
        .map(|k| {
            let t = (k as f64 * from_fps / to_fps).min(last);
            let i = (t.floor() as usize).min(frames.len() - 1);
            let a = t - i as f64;
            match frames.get(i + 1) {
                Some(next) if a > 0.0 => interpolate(&frames[i], next, a),
                _ => frames[i].clone(),
            }
        })
        .collect()
}

/// The frame a fraction `a` of the way from `p` to `q`.
fn interpolate(p: &FrameParams, q: &FrameParams, a: f64) -> FrameParams {
    let (rp, rq) = (p.local_rotations(), q.local_rotations());
    let r: [DVec3; N_JOINTS] = std::array::from_fn(|j| {
        let from = DQuat::from_scaled_axis(rp[j]);
        let to = DQuat::from_scaled_axis(rq[j]);
        axis_angle_from_rotation(DMat3::from_quat(from.slerp(to, a)))
    });
    let mut out = p.clone();
    out.set_local_rotations(&r);
    out.transl = p.transl.lerp(q.transl, a);
    for (e, (x, y)) in out
        .expression
        .iter_mut()
        .zip(p.expression.iter().zip(&q.expression))
    {
        *e = x + (y - x) * a;
    }
    out
}

/// What [`Motion::prepare`] needs to know.
#[derive(Clone, Copy, Debug)]
pub struct Prepare<'a> {
    /// The skeleton the motion is rendered on.
    pub subject: &'a Skeleton,
    /// The SMPL-X model file, if given: mean hands, and the performer's rest pelvis.
    pub model: Option<&'a SmplxModel>,
    /// Output frame rate (`None`: the file's).
    pub fps: Option<f64>,
    /// Keep the file's translation (after the change of frame) instead of starting the
    /// motion at the subject's rest position.
    pub keep_trans: bool,
}

/// A motion ready to render.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub frames: Vec<FrameParams>,
    /// The frame rate of `frames` (`None` if neither the file nor the caller gave one).
    pub fps: Option<f64>,
    /// What was assumed or left as given, for the user to read.
    pub notes: Vec<String>,
}

impl Motion {
    /// The frames in our conventions for `p.subject`: hands relative to the mean get the
    /// model's mean added (without a model they are kept as given, with a note); z-up
    /// turns y-up; the pelvis keeps its place in the world (the performer's rest pelvis
    /// from the model and the file's betas, else the subject's); unless `keep_trans`, the
    /// translation is then shifted so that the first frame's pelvis is at the subject's
    /// rest pelvis; finally the frames are resampled to `p.fps`.
    pub fn prepare(&self, p: &Prepare) -> Result<Prepared, MotionError> {
        let mut notes = Vec::new();
        let to_pelvis = p.subject.rest_joints[0];
        let from_pelvis = match p.model {
            Some(m) => {
                let n = self.betas.len().min(m.n_shape());
                if self.betas[n..].iter().any(|&b| b != 0.0) {
                    notes.push(format!(
                        "the motion's betas beyond the model's {n} shape components are ignored"
                    ));
                }
                m.rest_joints(&self.betas[..n])?[0]
            }
            None => to_pelvis,
        };
        let hands_mean = match (self.hands, p.model) {
            (Hands::RelativeToMean, Some(m)) => Some(m.hands_mean()),
            (Hands::RelativeToMean, None) => {
                notes.push(format!(
                    "{} stores hand poses relative to the SMPL-X mean hand: without --body-model \
                     they are used as given (fingers look flatter than captured)",
                    self.layout
                ));
                None
            }
            (Hands::Absolute, _) => None,
        };
        let q = match self.up {
            UpAxis::Y => DMat3::IDENTITY,
            UpAxis::Z => Z_UP_TO_Y_UP,
        };
        let mut frames: Vec<FrameParams> = self
            .frames
            .iter()
            .map(|f| {
                let mut f = change_frame(f, q, from_pelvis, to_pelvis);
                if let Some((l, r)) = &hands_mean {
                    for j in 0..l.len() {
                        f.left_hand_pose[j] += l[j];
                        f.right_hand_pose[j] += r[j];
                    }
                }
                f
            })
            .collect();
        if !p.keep_trans
            && let Some(start) = frames.first().map(|f| f.transl)
        {
            for f in &mut frames {
                f.transl -= start;
            }
        }
        if let Some(out) = p.fps
            && !(out.is_finite() && out > 0.0)
        {
            return Err(MotionError::Format {
                file: self.file.clone(),
                problem: format!("cannot resample to {out} frames per second"),
            });
        }
        let fps = match (p.fps, self.fps) {
            (Some(out), Some(file)) => {
                frames = resample(&frames, file, out);
                Some(out)
            }
            (Some(_), None) => {
                return Err(MotionError::Format {
                    file: self.file.clone(),
                    problem: "the motion has no frame rate to resample from (no \
                              `mocap_frame_rate`); leave out --fps"
                        .into(),
                });
            }
            (None, file) => file,
        };
        Ok(Prepared { frames, fps, notes })
    }
}
