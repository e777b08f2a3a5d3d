//! Inverse skinning as CubeCL kernels: one unit per sample walks that sample's candidate
//! bones (the set bits of its row of `masks` `[n, 2]`), never the batch.
//!
//! For candidate bone `b` the unit maps the sample `x` (posed) to the bone's canonical
//! point `x_b = T_b [x 1]` (`transforms` `[55, 12]`, the top rows of each joint's
//! `canonical_from_posed`), reads the bone's channel of the volume there (trilinear) and
//! adds the posed-space prior, `-d / tau` with `d` the signed distance from `x` to the
//! bone's nearest posed capsule. The weights are a softmax over the candidates, and
//! `x_canonical = sum_b w_b x_b`.
//!
//! `frame` holds the frame's numbers, [`FRAME_HEAD`] of them and then seven a capsule:
//! the volume's grid (its lower corner, vertices per unit length `(R - 1) / span` along
//! each axis, and `R`), the prior's temperature for limbs and for a sample with a finger
//! among its candidates (0: no prior), and where each bone's capsules start in the list
//! (`N_JOINTS + 1` numbers), then the capsules (`a` xyz, `b` xyz, radius).

use cubecl::prelude::*;

/// SMPL-X joints: the transforms' rows.
pub(crate) const N_JOINTS: usize = 55;
/// Bones a word of `masks` holds: bone `b` is bit `b % 28` of word `b / 28`, so neither
/// word needs an int's sign bit.
pub(crate) const MASK_BITS: usize = 28;
/// The first finger joint: a sample with a candidate from here on is weighed at the
/// finger temperature.
pub(crate) const FIRST_FINGER: usize = 25;
/// Numbers of the grid at the head of `frame`.
const GRID_PARAMS: usize = 7;
/// Where the limbs' and the fingers' temperatures sit in `frame`.
pub(crate) const TAU: usize = GRID_PARAMS;
pub(crate) const FINGER_TAU: usize = GRID_PARAMS + 1;
/// Where the capsules' starts sit in `frame` (`N_JOINTS + 1` of them).
pub(crate) const CAPSULE_STARTS: usize = GRID_PARAMS + 2;
/// Numbers before the capsules.
pub(crate) const FRAME_HEAD: usize = CAPSULE_STARTS + N_JOINTS + 1;
/// Numbers a capsule.
pub(crate) const CAPSULE_PARAMS: usize = 7;
/// The prior's logit of a bone without a capsule (the CPU's `NO_CAPSULE_LOGIT`).
const NO_CAPSULE_LOGIT: f32 = -1.0e4;

#[derive(CubeType)]
struct Grid {
    min_x: f32,
    min_y: f32,
    min_z: f32,
    scale_x: f32,
    scale_y: f32,
    scale_z: f32,
    res: u32,
}

#[cube]
fn grid_of(frame: &Tensor<f32>) -> Grid {
    Grid {
        min_x: frame[0],
        min_y: frame[1],
        min_z: frame[2],
        scale_x: frame[3],
        scale_y: frame[4],
        scale_z: frame[5],
        res: u32::cast_from(frame[6]),
    }
}

#[derive(CubeType)]
struct Point {
    x: f32,
    y: f32,
    z: f32,
}

#[cube]
fn point_of(points: &Tensor<f32>, s: usize) -> Point {
    Point {
        x: points[s * 3],
        y: points[s * 3 + 1],
        z: points[s * 3 + 2],
    }
}

/// Bone `b`'s canonical point of posed `x`: `T_b [x 1]`.
#[cube]
fn canonical_point(transforms: &Tensor<f32>, b: usize, x: &Point) -> Point {
    let m = b * 12;
    Point {
        x: transforms[m] * x.x
            + transforms[m + 1] * x.y
            + transforms[m + 2] * x.z
            + transforms[m + 3],
        y: transforms[m + 4] * x.x
            + transforms[m + 5] * x.y
            + transforms[m + 6] * x.z
            + transforms[m + 7],
        z: transforms[m + 8] * x.x
            + transforms[m + 9] * x.y
            + transforms[m + 10] * x.z
            + transforms[m + 11],
    }
}

/// Vertex coordinate and fraction along one axis: `u` clamped to `[0, R - 1]`, the cell
/// `min(floor(u), R - 2)`.
#[derive(CubeType)]
struct Axis {
    cell: u32,
    frac: f32,
}

#[cube]
fn axis_of(x: f32, min: f32, scale: f32, res: u32) -> Axis {
    let top = f32::cast_from(res - 1);
    let u = f32::max(f32::min((x - min) * scale, top), 0.0);
    let mut cell = u32::cast_from(u.floor());
    if cell > res - 2 {
        cell = res - 2;
    }
    Axis {
        cell,
        frac: u - f32::cast_from(cell),
    }
}

#[cube]
fn lerp_weight(frac: f32, upper: u32) -> f32 {
    let mut w = 1.0 - frac;
    if upper == 1 {
        w = frac;
    }
    w
}

/// Where a canonical point reads its bone's channel: the cell and the three fractions.
#[derive(CubeType)]
struct Corners {
    x: Axis,
    y: Axis,
    z: Axis,
    bone: u32,
}

#[cube]
fn corners_of(xb: &Point, bone: u32, grid: &Grid) -> Corners {
    Corners {
        x: axis_of(xb.x, grid.min_x, grid.scale_x, grid.res),
        y: axis_of(xb.y, grid.min_y, grid.scale_y, grid.res),
        z: axis_of(xb.z, grid.min_z, grid.scale_z, grid.res),
        bone,
    }
}

/// The volume's index of corner `k` (`(k & 1, k >> 1 & 1, k >> 2)`):
/// `((bone R + z) R + y) R + x`.
#[cube]
fn corner_row(c: &Corners, k: u32, res: u32) -> usize {
    let x = c.x.cell + (k & 1);
    let y = c.y.cell + ((k >> 1) & 1);
    let z = c.z.cell + (k >> 2);
    usize::cast_from(((c.bone * res + z) * res + y) * res + x)
}

#[cube]
fn corner_weight(c: &Corners, k: u32) -> f32 {
    lerp_weight(c.x.frac, k & 1)
        * lerp_weight(c.y.frac, (k >> 1) & 1)
        * lerp_weight(c.z.frac, k >> 2)
}

/// Signed distance from `p` to the capsule whose numbers start at `frame[c]` (negative
/// inside).
#[cube]
fn capsule_distance(frame: &Tensor<f32>, c: usize, p: &Point) -> f32 {
    let abx = frame[c + 3] - frame[c];
    let aby = frame[c + 4] - frame[c + 1];
    let abz = frame[c + 5] - frame[c + 2];
    let apx = p.x - frame[c];
    let apy = p.y - frame[c + 1];
    let apz = p.z - frame[c + 2];
    let len2 = abx * abx + aby * aby + abz * abz;
    let mut t = 0.0f32;
    if len2 > 0.0 {
        t = ((apx * abx + apy * aby + apz * abz) / len2).clamp(0.0, 1.0);
    }
    let dx = apx - t * abx;
    let dy = apy - t * aby;
    let dz = apz - t * abz;
    f32::sqrt(dx * dx + dy * dy + dz * dz) - frame[c + 6]
}

/// The posed prior's logit of bone `b` at posed `x`: the largest `-d / tau` over the
/// bone's capsules ([`NO_CAPSULE_LOGIT`] without one), 0 without a prior (`tau == 0`).
#[cube]
fn posed_logit(frame: &Tensor<f32>, b: usize, x: &Point, tau: f32) -> f32 {
    let mut l = 0.0f32;
    if tau > 0.0 {
        l = NO_CAPSULE_LOGIT;
        let first = usize::cast_from(frame[CAPSULE_STARTS + b]);
        let end = usize::cast_from(frame[CAPSULE_STARTS + b + 1]);
        for c in first..end {
            let d = capsule_distance(frame, FRAME_HEAD + c * CAPSULE_PARAMS, x);
            l = f32::max(l, -d / tau);
        }
    }
    l
}

/// The sample's prior temperature: the fingers' when a finger is among its candidates.
#[cube]
fn sample_tau<I: Int>(frame: &Tensor<f32>, masks: &Tensor<I>, s: usize) -> f32 {
    let low = u32::cast_from(masks[s * 2]);
    let high = u32::cast_from(masks[s * 2 + 1]);
    let mut tau = frame[TAU];
    if (low >> FIRST_FINGER as u32) != 0 || high != 0 {
        tau = frame[FINGER_TAU];
    }
    tau
}

/// One candidate: its canonical point, where it reads the volume and its logit (the
/// trilinear read of its channel, then the prior: in that order, as on the CPU, where a
/// bone without a capsule adds -1e4, of which an f32 holds only a thousandth).
#[derive(CubeType)]
struct Candidate {
    xb: Point,
    corners: Corners,
    logit: f32,
}

#[cube]
fn candidate(
    volume: &Tensor<f32>,
    transforms: &Tensor<f32>,
    frame: &Tensor<f32>,
    b: usize,
    x: &Point,
    tau: f32,
    grid: &Grid,
) -> Candidate {
    let xb = canonical_point(transforms, b, x);
    let c = corners_of(&xb, u32::cast_from(b), grid);
    let mut l = 0.0f32;
    #[unroll]
    for k in 0..8u32 {
        l += corner_weight(&c, k) * volume[corner_row(&c, k, grid.res)];
    }
    Candidate {
        xb,
        corners: c,
        logit: l + posed_logit(frame, b, x, tau),
    }
}

/// A sample's softmax over its candidates, in one pass: the largest logit, the sum of
/// `exp(l - max)` and the blend's unnormalised sum.
#[derive(CubeType)]
struct Softmax {
    max: f32,
    sum: f32,
    x: f32,
    y: f32,
    z: f32,
}

#[cube]
#[allow(clippy::too_many_arguments)]
fn softmax_of<I: Int>(
    volume: &Tensor<f32>,
    transforms: &Tensor<f32>,
    frame: &Tensor<f32>,
    masks: &Tensor<I>,
    s: usize,
    x: &Point,
    tau: f32,
    grid: &Grid,
) -> Softmax {
    // Below any logit a volume holds; exp(max - l) of it is 0.
    let mut max = f32::new(-3.0e38);
    let mut sum = 0.0f32;
    let mut px = 0.0f32;
    let mut py = 0.0f32;
    let mut pz = 0.0f32;
    #[unroll]
    for word in 0..2usize {
        let mut bits = u32::cast_from(masks[s * 2 + word]);
        while bits != 0 {
            let b = word * MASK_BITS + usize::cast_from(bits.trailing_zeros());
            bits &= bits - 1;
            let c = candidate(volume, transforms, frame, b, x, tau, grid);
            if c.logit > max {
                // Rescale what was summed against the old maximum.
                let r = f32::exp(max - c.logit);
                sum *= r;
                px *= r;
                py *= r;
                pz *= r;
                max = c.logit;
            }
            let e = f32::exp(c.logit - max);
            sum += e;
            px += e * c.xb.x;
            py += e * c.xb.y;
            pz += e * c.xb.z;
        }
    }
    Softmax {
        max,
        sum,
        x: px,
        y: py,
        z: pz,
    }
}

/// `out[s] = sum_b w_b x_b` over sample `s`'s candidates, one unit per sample.
#[cube(launch)]
pub(crate) fn warp_kernel<I: Int>(
    volume: &Tensor<f32>,
    transforms: &Tensor<f32>,
    points: &Tensor<f32>,
    frame: &Tensor<f32>,
    masks: &Tensor<I>,
    out: &mut Tensor<f32>,
    #[define(I)] _dtype: ElemType,
) {
    let s = ABSOLUTE_POS;
    if s >= masks.shape(0) {
        terminate!();
    }
    let grid = grid_of(frame);
    let x = point_of(points, s);
    let tau = sample_tau::<I>(frame, masks, s);
    let sm = softmax_of::<I>(volume, transforms, frame, masks, s, &x, tau, &grid);
    let inv = 1.0 / sm.sum;
    out[s * 3] = sm.x * inv;
    out[s * 3 + 1] = sm.y * inv;
    out[s * 3 + 2] = sm.z * inv;
}

/// The warp's backward, one unit per sample: `d l_b = w_b (g . x_b - g . x)` spread over
/// the candidate's eight volume corners, and with `with_transforms` `d T_b = w_b g [x 1]^T`,
/// both by atomic float adds into zeroed gradients. The transforms' gradient flows
/// through the blended points, not through where the logits are read (as on the CPU).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn warp_backward_kernel<I: Int>(
    volume: &Tensor<f32>,
    transforms: &Tensor<f32>,
    points: &Tensor<f32>,
    frame: &Tensor<f32>,
    masks: &Tensor<I>,
    grad_out: &Tensor<f32>,
    grad_volume: &mut Tensor<Atomic<f32>>,
    grad_transforms: &mut Tensor<Atomic<f32>>,
    #[comptime] with_transforms: bool,
    #[define(I)] _dtype: ElemType,
) {
    let s = ABSOLUTE_POS;
    if s >= masks.shape(0) {
        terminate!();
    }
    let grid = grid_of(frame);
    let x = point_of(points, s);
    let tau = sample_tau::<I>(frame, masks, s);
    let sm = softmax_of::<I>(volume, transforms, frame, masks, s, &x, tau, &grid);
    let inv = 1.0 / sm.sum;
    let gx = grad_out[s * 3];
    let gy = grad_out[s * 3 + 1];
    let gz = grad_out[s * 3 + 2];
    let g_dot_x = (gx * sm.x + gy * sm.y + gz * sm.z) * inv;
    #[unroll]
    for word in 0..2usize {
        let mut bits = u32::cast_from(masks[s * 2 + word]);
        while bits != 0 {
            let b = word * MASK_BITS + usize::cast_from(bits.trailing_zeros());
            bits &= bits - 1;
            let c = candidate(volume, transforms, frame, b, &x, tau, &grid);
            let w = f32::exp(c.logit - sm.max) * inv;
            let g_dot_xb = gx * c.xb.x + gy * c.xb.y + gz * c.xb.z;
            let dl = w * (g_dot_xb - g_dot_x);
            #[unroll]
            for corner in 0..8u32 {
                grad_volume[corner_row(&c.corners, corner, grid.res)]
                    .fetch_add(corner_weight(&c.corners, corner) * dl);
            }
            if with_transforms {
                let m = b * 12;
                let (wx, wy, wz) = (w * gx, w * gy, w * gz);
                grad_transforms[m].fetch_add(wx * x.x);
                grad_transforms[m + 1].fetch_add(wx * x.y);
                grad_transforms[m + 2].fetch_add(wx * x.z);
                grad_transforms[m + 3].fetch_add(wx);
                grad_transforms[m + 4].fetch_add(wy * x.x);
                grad_transforms[m + 5].fetch_add(wy * x.y);
                grad_transforms[m + 6].fetch_add(wy * x.z);
                grad_transforms[m + 7].fetch_add(wy);
                grad_transforms[m + 8].fetch_add(wz * x.x);
                grad_transforms[m + 9].fetch_add(wz * x.y);
                grad_transforms[m + 10].fetch_add(wz * x.z);
                grad_transforms[m + 11].fetch_add(wz);
            }
        }
    }
}
