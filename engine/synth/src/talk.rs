//! Talking motion, deterministic from a seed: arm and hand gestures (hands often in front
//! of the chest), finger curls and spreads, a jaw on a syllable-rate envelope with pauses,
//! smooth expressions, torso sway, head nods and turns, eye saccades. 25 fps.

use glam::{DMat3, DVec3};

use talkin_grids::SplitMix64;

use talkin_human::body::skeleton::joint::*;
use talkin_human::body::{FrameParams, N_EXPRESSION, N_HAND_JOINTS, axis_angle_from_rotation};

/// Frames per second of every generated clip.
pub const FPS: f64 = 25.0;

/// The scene's generator for `seed`: the workspace's SplitMix64, its state the seed with
/// the golden-ratio increment XORed in (how every scene was seeded, so that they stay
/// byte-identical).
pub(crate) fn scene_rng(seed: u64) -> SplitMix64 {
    SplitMix64::new(seed ^ 0x9e37_79b9_7f4a_7c15)
}

/// How wide the motion ranges are.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Style {
    /// Gesture tempo factor (1 = about one gesture per second).
    pub tempo: f64,
    /// Out-of-distribution: larger arm raises, more head turn, stronger expressions.
    pub wide: bool,
}

/// A smooth random signal: a few sinusoids.
struct Wave {
    parts: Vec<(f64, f64, f64)>,
}

impl Wave {
    fn new(rng: &mut SplitMix64, amplitude: f64, f_lo: f64, f_hi: f64) -> Self {
        let parts = (0..3)
            .map(|k| {
                let a = amplitude / (1.0 + k as f64);
                (
                    a,
                    rng.uniform(f_lo, f_hi),
                    rng.uniform(0.0, std::f64::consts::TAU),
                )
            })
            .collect();
        Self { parts }
    }
    fn at(&self, t: f64) -> f64 {
        let norm: f64 = self.parts.iter().map(|p| p.0).sum::<f64>().max(1e-12);
        let top = self.parts.first().map_or(0.0, |p| p.0);
        self.parts
            .iter()
            .map(|(a, f, ph)| a * (std::f64::consts::TAU * f * t + ph).sin())
            .sum::<f64>()
            * top
            / norm
    }
}

/// Keyframed values eased with a smoothstep between keys.
struct Keys<const N: usize> {
    times: Vec<f64>,
    values: Vec<[f64; N]>,
}

impl<const N: usize> Keys<N> {
    fn new(
        rng: &mut SplitMix64,
        duration: f64,
        tempo: f64,
        mut sample: impl FnMut(&mut SplitMix64) -> [f64; N],
    ) -> Self {
        let mut times = vec![-0.5];
        let mut values = vec![sample(rng)];
        while *times.last().unwrap() < duration + 1.0 {
            let dt = rng.uniform(0.55, 1.3) / tempo;
            times.push(times.last().unwrap() + dt);
            values.push(sample(rng));
        }
        Self { times, values }
    }
    fn at(&self, t: f64) -> [f64; N] {
        let i = self
            .times
            .partition_point(|&k| k <= t)
            .clamp(1, self.times.len() - 1);
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let u = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
        let w = u * u * (3.0 - 2.0 * u);
        std::array::from_fn(|k| self.values[i - 1][k] * (1.0 - w) + self.values[i][k] * w)
    }
}

fn rx(a: f64) -> DMat3 {
    DMat3::from_rotation_x(a)
}
fn ry(a: f64) -> DMat3 {
    DMat3::from_rotation_y(a)
}
fn rz(a: f64) -> DMat3 {
    DMat3::from_rotation_z(a)
}
fn aa(m: DMat3) -> DVec3 {
    axis_angle_from_rotation(m)
}

/// Arm key: [down, forward, elbow flex, forearm roll, wrist flex, wrist deviation] (rad).
fn arm_key(rng: &mut SplitMix64, wide: bool) -> [f64; 6] {
    let d = f64::to_radians;
    let roll = rng.uniform(d(-40.0), d(30.0));
    let wrist = [
        rng.uniform(d(-30.0), d(30.0)),
        rng.uniform(d(-15.0), d(15.0)),
    ];
    if wide {
        // Raised forward and up, towards or above the head.
        return [
            rng.uniform(d(-35.0), d(35.0)),
            rng.uniform(d(45.0), d(85.0)),
            rng.uniform(d(30.0), d(125.0)),
            roll,
            wrist[0],
            wrist[1],
        ];
    }
    match rng.next_f64() {
        // Hand in front of the chest.
        u if u < 0.4 => [
            rng.uniform(d(42.0), d(60.0)),
            rng.uniform(d(35.0), d(60.0)),
            rng.uniform(d(100.0), d(130.0)),
            roll,
            wrist[0],
            wrist[1],
        ],
        // Resting near the side.
        u if u < 0.55 => [
            rng.uniform(d(70.0), d(78.0)),
            rng.uniform(d(5.0), d(20.0)),
            rng.uniform(d(10.0), d(35.0)),
            roll,
            wrist[0],
            wrist[1],
        ],
        // A gesture out to the side and forward.
        _ => [
            rng.uniform(d(45.0), d(70.0)),
            rng.uniform(d(15.0), d(50.0)),
            rng.uniform(d(40.0), d(100.0)),
            roll,
            wrist[0],
            wrist[1],
        ],
    }
}

/// Hand key: per finger [curl] for index, middle, pinky, ring, thumb, then spread.
fn hand_key(rng: &mut SplitMix64, wide: bool) -> [f64; 6] {
    let hi = if wide { 1.5 } else { 1.1 };
    let shape = rng.next_f64();
    let mut c = [0.0; 6];
    for (k, x) in c.iter_mut().enumerate().take(5) {
        *x = match shape {
            s if s < 0.3 => rng.uniform(0.0, 0.25), // open
            s if s < 0.5 => {
                if k == 0 {
                    rng.uniform(0.0, 0.15)
                } else {
                    rng.uniform(0.7, hi)
                }
            } // point
            s if s < 0.7 => rng.uniform(0.6, hi),   // loose fist
            _ => rng.uniform(0.15, 0.7),            // relaxed
        };
    }
    c[5] = rng.uniform(-0.1, if wide { 0.45 } else { 0.3 });
    c
}

/// Speech on the jaw: phrases separated by pauses, syllables within them.
struct Speech {
    syllable_hz: f64,
    syllable_phase: f64,
    jaw_max: f64,
    /// (start, end) in seconds.
    phrases: Vec<(f64, f64)>,
    /// Loudness of each syllable.
    syllable_gain: Vec<f64>,
}

impl Speech {
    fn new(rng: &mut SplitMix64, duration: f64, wide: bool) -> Self {
        let syllable_hz = rng.uniform(4.0, 5.0);
        let syllable_phase = rng.uniform(0.0, 1.0);
        let jaw_max = if wide { 0.5 } else { 0.3 };
        let mut phrases = Vec::new();
        let mut t = rng.uniform(-0.5, 0.2);
        while t < duration + 1.0 {
            let len = rng.uniform(1.2, 3.0);
            phrases.push((t, t + len));
            t += len + rng.uniform(0.35, 0.8);
        }
        let syllable_gain: Vec<f64> = (0..((duration + 2.0) * 6.0) as usize + 8)
            .map(|_| rng.uniform(0.35, 1.0))
            .collect();
        Self {
            syllable_hz,
            syllable_phase,
            jaw_max,
            phrases,
            syllable_gain,
        }
    }

    /// Jaw opening (rad about x) at time `t`; slightly open at rest.
    fn jaw(&self, t: f64) -> f64 {
        let talking = self.phrases.iter().any(|&(a, b)| t >= a && t <= b);
        let phase = t * self.syllable_hz + self.syllable_phase;
        let syl = (std::f64::consts::PI * phase.fract()).sin().powf(1.5);
        let gain = self.syllable_gain[(phase as usize).min(self.syllable_gain.len() - 1)];
        // Phrases fade in and out over 0.15 s instead of snapping the jaw.
        let edge = self
            .phrases
            .iter()
            .map(|&(a, b)| ((t - a).min(b - t) / 0.15).clamp(0.0, 1.0))
            .fold(0.0, f64::max);
        0.02 + if talking {
            self.jaw_max * syl * gain * edge
        } else {
            0.0
        }
    }
}

/// The random signals of one clip, drawn once from the seed (the order of the draws is
/// part of the output); a frame samples them at its time.
struct Performance {
    arms: [Keys<6>; 2],
    hands: [Keys<6>; 2],
    expressions: Vec<Wave>,
    smile_bias: f64,
    head_turn: Wave,
    head_nod: Wave,
    head_tilt: Wave,
    sway: [Wave; 3],
    eyes: Keys<2>,
    speech: Speech,
}

impl Performance {
    fn new(rng: &mut SplitMix64, duration: f64, style: Style) -> Self {
        let wide = style.wide;
        let arms = [0, 1].map(|_| Keys::new(rng, duration, style.tempo, |r| arm_key(r, wide)));
        let hands =
            [0, 1].map(|_| Keys::new(rng, duration, style.tempo * 1.3, |r| hand_key(r, wide)));
        let expr_gain = if wide { 2.4 } else { 1.0 };
        let expressions: Vec<Wave> = (0..N_EXPRESSION)
            .map(|k| Wave::new(rng, if k == 0 { 0.9 } else { 0.7 } * expr_gain, 0.08, 0.5))
            .collect();
        let smile_bias = rng.uniform(0.0, 0.5);
        let turn_amp = if wide { 0.6 } else { 0.18 };
        let head_turn = Wave::new(rng, turn_amp, 0.05, 0.3);
        let head_nod = Wave::new(rng, if wide { 0.3 } else { 0.09 }, 0.4, 1.6);
        let head_tilt = Wave::new(rng, 0.06, 0.1, 0.5);
        let sway = [0, 1, 2].map(|_| Wave::new(rng, 0.045, 0.08, 0.4));
        let eyes = Keys::new(rng, duration, 2.0, |r| {
            [r.uniform(-0.25, 0.25), r.uniform(-0.12, 0.12)]
        });
        let speech = Speech::new(rng, duration, wide);
        Self {
            arms,
            hands,
            expressions,
            smile_bias,
            head_turn,
            head_nod,
            head_tilt,
            sway,
            eyes,
            speech,
        }
    }

    fn frame(&self, t: f64) -> FrameParams {
        let mut p = self.torso_and_head(t);
        for side in 0..2 {
            self.arm(&mut p, side, t);
        }
        p.jaw_pose = DVec3::new(self.speech.jaw(t), 0.0, 0.0);
        // Expressions, gently smiling on average.
        for (k, w) in self.expressions.iter().enumerate() {
            p.expression[k] = w.at(t) + if k == 0 { self.smile_bias } else { 0.0 };
        }
        let [yaw, pitch] = self.eyes.at(t);
        p.leye_pose = DVec3::new(pitch, yaw, 0.0);
        p.reye_pose = DVec3::new(pitch, yaw, 0.0);
        p
    }

    /// Torso sway with a slight body turn; head nods, turns and tilts.
    fn torso_and_head(&self, t: f64) -> FrameParams {
        let sway = &self.sway;
        let mut p = FrameParams {
            global_orient: DVec3::new(0.0, sway[0].at(t) * 1.5, 0.0),
            ..Default::default()
        };
        p.body_pose[SPINE1 - 1] = DVec3::new(sway[1].at(t) * 0.5, 0.0, sway[2].at(t));
        p.body_pose[SPINE2 - 1] = DVec3::new(
            sway[1].at(t) * 0.5,
            sway[0].at(t) * 0.5,
            sway[2].at(t) * 0.5,
        );
        p.body_pose[SPINE3 - 1] = DVec3::new(0.0, sway[0].at(t) * 0.5, 0.0);
        p.body_pose[NECK - 1] = DVec3::new(
            0.05 + self.head_nod.at(t) * 0.5,
            self.head_turn.at(t) * 0.4,
            self.head_tilt.at(t) * 0.5,
        );
        p.body_pose[HEAD - 1] = DVec3::new(
            self.head_nod.at(t) * 0.5,
            self.head_turn.at(t) * 0.6,
            self.head_tilt.at(t) * 0.5,
        );
        p
    }

    /// One side's shoulder, elbow, wrist and collar, then its hand.
    fn arm(&self, p: &mut FrameParams, side: usize, t: f64) {
        let sign = if side == 0 { 1.0 } else { -1.0 };
        let [down, fwd, flex, roll, wflex, wdev] = self.arms[side].at(t);
        let shoulder = ry(-sign * fwd) * rz(-sign * down);
        p.body_pose[LEFT_SHOULDER + side - 1] = aa(shoulder);
        p.body_pose[LEFT_ELBOW + side - 1] = aa(ry(-sign * flex) * rx(roll));
        p.body_pose[LEFT_WRIST + side - 1] = aa(rz(-sign * wflex) * ry(sign * wdev));
        // Collar follows large raises a little.
        p.body_pose[LEFT_COLLAR + side - 1] =
            DVec3::new(0.0, 0.0, sign * (0.6 - down).max(0.0) * 0.15);
        let pose = if side == 0 {
            &mut p.left_hand_pose
        } else {
            &mut p.right_hand_pose
        };
        hand_pose(pose, sign, self.hands[side].at(t));
    }
}

/// Finger curls and spread (`hand_key` order) as the 15 local rotations of a hand on
/// side `sign`.
fn hand_pose(pose: &mut [DVec3; N_HAND_JOINTS], sign: f64, curls: [f64; 6]) {
    for f in 0..4 {
        // Flexion axis: finger direction x palm normal (-y) = -z (left), +z (right).
        let spread = curls[5] * (f as f64 - 1.2) * 0.25;
        for k in 0..3 {
            let bend = curls[f] * [0.9, 1.1, 0.8][k];
            let r = rz(-sign * bend)
                * if k == 0 {
                    ry(-sign * spread)
                } else {
                    DMat3::IDENTITY
                };
            pose[3 * f + k] = aa(r);
        }
    }
    // Thumb: folds across the palm about an axis along the palm's width.
    let dir = DVec3::new(0.72 * sign, -0.2, 0.66).normalize();
    let axis = dir.cross(DVec3::NEG_Y).normalize();
    for k in 0..3 {
        pose[12 + k] = axis * curls[4] * [0.5, 0.6, 0.7][k];
    }
}

/// A talking clip of `n` frames at [`FPS`].
pub fn talking_clip(seed: u64, n: usize, style: Style) -> Vec<FrameParams> {
    let mut rng = scene_rng(seed);
    let duration = n as f64 / FPS;
    let performance = Performance::new(&mut rng, duration, style);
    (0..n).map(|i| performance.frame(i as f64 / FPS)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clips_are_deterministic_and_finite() {
        let style = Style {
            tempo: 1.0,
            wide: false,
        };
        let a = talking_clip(7, 30, style);
        let b = talking_clip(7, 30, style);
        assert_eq!(a, b);
        assert!(a.iter().all(|p| p.is_finite()));
        assert_ne!(a, talking_clip(8, 30, style));
        // The jaw moves.
        let jaw: Vec<f64> = a.iter().map(|p| p.jaw_pose.x).collect();
        let (lo, hi) = jaw
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(hi - lo > 0.05, "{lo} {hi}");
    }
}
