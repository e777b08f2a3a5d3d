//! The ground-truth renderer: sphere tracing of the mannequin's SDF, independent of the
//! engine's samplers (no capsule BVH). Primitives are smooth-unioned in order; the
//! material and segmentation label at a hit are those of the nearest primitive.
//!
//! Per pixel: one centre ray decides segmentation and depth; RGB is supersampled 2x2
//! where the centre rays of neighbouring pixels disagree (silhouettes, part borders), and
//! the mask is the pixel's covered fraction: the share of those four rays that hit, the
//! centre ray elsewhere, kept on the centre ray's side of the 128 cut.
//! Per ray, primitives are culled by their bounding spheres; per SDF evaluation, by the
//! distance to their bounding sphere.

use glam::{Affine3A, Vec3};
use rayon::prelude::*;

use super::body::{Figure, Material, albedo, eye_colour};
use talkin_human::body::{N_JOINTS, PosedSkeleton};
use talkin_human::camera::Camera;

/// Tracer stops when the SDF is below this (metres).
const HIT_EPS: f32 = 2.5e-4;
const MAX_STEPS: usize = 160;

/// One frame's rendered buffers (row-major, camera size).
pub struct Rendered {
    pub rgb: Vec<[u8; 3]>,
    /// The pixel's covered fraction x 255: the share of its rays that hit the figure.
    pub coverage: Vec<u8>,
    /// 0 = background, else the segmentation label 1..=4.
    pub label: Vec<u8>,
    /// Camera z of the centre ray's hit in metres, 0 where background.
    pub depth: Vec<f32>,
}

/// A primitive placed in the world for one frame.
struct Placed {
    rest_from_world: Affine3A,
    centre: Vec3,
    radius: f32,
}

/// The traced scene of one frame.
pub struct Scene<'a> {
    fig: &'a Figure,
    placed: Vec<Placed>,
    light: Vec3,
    background: Vec3,
    /// Smooth skinning: the width (metres) over which skin bends at a joint
    /// ([`Scene::with_smooth_skin`]); `None`: every primitive rigid with its joint.
    smooth: Option<f32>,
    joint_rest_from_world: [Affine3A; N_JOINTS],
    rest_joints: [Vec3; N_JOINTS],
}

/// A pixel's centre ray: what it hit, its shaded colour, its camera z.
type CentreRay = (Option<Hit>, [f32; 3], f32);

#[derive(Clone, Copy)]
struct Hit {
    t: f32,
    prim: usize,
}

impl<'a> Scene<'a> {
    pub fn new(fig: &'a Figure, posed: &PosedSkeleton, background: Vec3) -> Self {
        let world_from_rest: [Affine3A; N_JOINTS] = std::array::from_fn(|j| {
            let a = posed.world_from_rest[j];
            Affine3A::from_mat3_translation(a.matrix3.as_mat3(), a.translation.as_vec3())
        });
        let joint_rest_from_world = world_from_rest.map(|w| w.inverse());
        let placed = fig
            .prims
            .iter()
            .map(|p| {
                let (c, r) = p.shape.bounding_sphere();
                let w = world_from_rest[p.joint];
                Placed {
                    rest_from_world: joint_rest_from_world[p.joint],
                    centre: w.transform_point3(c),
                    radius: r + p.blend,
                }
            })
            .collect();
        Self {
            fig,
            placed,
            light: Vec3::new(-0.45, 0.65, 0.62).normalize(),
            background,
            rest_joints: std::array::from_fn(|j| {
                joint_rest_from_world[j].transform_point3(posed.joint(j).as_vec3())
            }),
            joint_rest_from_world,
            smooth: None,
        }
    }

    /// The scene with skin that bends over `width` metres at every joint (the capture-like
    /// scene's flaw; see `Scene::rest_point`); `width <= 0` keeps it rigid.
    pub fn with_smooth_skin(mut self, width: f32) -> Self {
        self.smooth = (width > 0.0).then_some(width);
        self
    }

    /// The rest point of world point `p` under smooth skinning: the owner joint's rest
    /// image (the joint of the nearest primitive, evaluated rigidly), blended with its
    /// parent's and children's images near the joint they share: a neighbour weighs
    /// `exp(-r^2 / 2 sigma^2)` against the owner's 1, `r` the owner image's distance from
    /// the shared joint in rest space, so skin bends smoothly over a few centimetres at
    /// every joint and moves rigidly elsewhere.
    fn rest_point(&self, p: Vec3, cands: &[usize], sigma: f32) -> (Vec3, u64) {
        use talkin_human::body::PARENTS;
        let mut owner = (f32::INFINITY, usize::MAX);
        for &i in cands {
            let prim = &self.fig.prims[i];
            let d = prim
                .shape
                .distance(self.placed[i].rest_from_world.transform_point3(p));
            if d < owner.0 {
                owner = (d, prim.joint);
            }
        }
        let o = owner.1;
        if o == usize::MAX {
            return (p, 0);
        }
        let mut set = 1u64 << o;
        let q = |j: usize| self.joint_rest_from_world[j].transform_point3(p);
        let qo = q(o);
        let inv = 1.0 / (2.0 * sigma * sigma);
        let (mut acc, mut sum) = (qo, 1.0f32);
        for n in 0..N_JOINTS {
            let shared = if PARENTS[o] >= 0 && PARENTS[o] as usize == n {
                o
            } else if PARENTS[n] >= 0 && PARENTS[n] as usize == o {
                n
            } else {
                continue;
            };
            let w = (-(qo - self.rest_joints[shared]).length_squared() * inv).exp();
            set |= 1 << n;
            if w > 1e-4 {
                acc += q(n) * w;
                sum += w;
            }
        }
        (acc / sum, set)
    }

    /// Scene SDF at `p` over the candidate primitives; returns (distance, nearest prim).
    #[inline]
    fn sdf(&self, p: Vec3, cands: &[usize]) -> (f32, usize) {
        // With smooth skin, the shared rest point and the joints it blends.
        let smooth = self.smooth.map(|sigma| self.rest_point(p, cands, sigma));
        let mut d = f32::INFINITY;
        let mut nearest = (f32::INFINITY, usize::MAX);
        for &i in cands {
            let pl = &self.placed[i];
            let prim = &self.fig.prims[i];
            let di = match smooth {
                Some((r, set)) if set >> prim.joint & 1 == 1 => prim.shape.distance(r),
                Some(_) => prim.shape.distance(pl.rest_from_world.transform_point3(p)),
                None => {
                    let bound = (p - pl.centre).length() - pl.radius;
                    if bound >= d + prim.blend && bound >= nearest.0 {
                        continue;
                    }
                    prim.shape.distance(pl.rest_from_world.transform_point3(p))
                }
            };
            if di < nearest.0 {
                nearest = (di, i);
            }
            d = if d.is_finite() {
                super::sdf::smin(d, di, prim.blend)
            } else {
                di
            };
        }
        (d, nearest.1)
    }

    /// Primitives whose bounding sphere the ray meets, and the ray's [t_in, t_out] over them.
    fn cull(&self, o: Vec3, dir: Vec3, cands: &mut Vec<usize>) -> Option<(f32, f32)> {
        cands.clear();
        let (mut t0, mut t1) = (f32::INFINITY, f32::NEG_INFINITY);
        for (i, pl) in self.placed.iter().enumerate() {
            let oc = o - pl.centre;
            let b = oc.dot(dir);
            let disc = b * b - (oc.length_squared() - pl.radius * pl.radius);
            if disc <= 0.0 {
                continue;
            }
            let s = disc.sqrt();
            if -b + s <= 0.0 {
                continue;
            }
            cands.push(i);
            t0 = t0.min(-b - s);
            t1 = t1.max(-b + s);
        }
        (!cands.is_empty()).then_some((t0.max(0.0), t1))
    }

    fn trace(&self, o: Vec3, dir: Vec3, cands: &mut Vec<usize>) -> Option<Hit> {
        let (mut t, t_end) = self.cull(o, dir, cands)?;
        for _ in 0..MAX_STEPS * if self.smooth.is_some() { 3 } else { 1 } {
            let (d, prim) = self.sdf(o + dir * t, cands);
            if d < HIT_EPS {
                return Some(Hit { t, prim });
            }
            t += d * if self.smooth.is_some() { 0.5 } else { 0.9 };
            if t > t_end {
                return None;
            }
        }
        None
    }

    /// Shaded colour of a hit.
    fn shade(&self, o: Vec3, dir: Vec3, hit: Hit, cands: &[usize]) -> Vec3 {
        let p = o + dir * hit.t;
        let e = 4e-4;
        let k = [
            Vec3::new(1.0, -1.0, -1.0),
            Vec3::new(-1.0, -1.0, 1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(1.0, 1.0, 1.0),
        ];
        let n = k.iter().fold(Vec3::ZERO, |acc, kk| {
            acc + *kk * self.sdf(p + *kk * e, cands).0
        });
        let n = n.try_normalize().unwrap_or(-dir);
        let prim = &self.fig.prims[hit.prim];
        let smooth = self.smooth.map(|sigma| self.rest_point(p, cands, sigma));
        let p_rest = match smooth {
            Some((r, set)) if set >> prim.joint & 1 == 1 => r,
            _ => self.placed[hit.prim].rest_from_world.transform_point3(p),
        };
        let base = match prim.material {
            Material::Eye => {
                let c = match prim.shape {
                    super::sdf::Shape::Ellipsoid { c, .. } => c,
                    _ => p_rest,
                };
                eye_colour(&self.fig.look, p_rest, c)
            }
            m => albedo(self.fig, m, p_rest),
        };
        let lambert = n.dot(self.light).max(0.0);
        let rim = (1.0 - n.dot(-dir).abs().min(1.0)).powi(3);
        (base * (0.38 + 0.62 * lambert) + Vec3::splat(0.18 * rim)).clamp(Vec3::ZERO, Vec3::ONE)
    }

    /// Renders the frame through `camera`.
    pub fn render(&self, camera: &Camera) -> Rendered {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let ray = |x: f64, y: f64| {
            let (o, d) = camera.ray_through(glam::DVec2::new(x, y));
            (o.as_vec3(), d.as_vec3())
        };
        // Centre rays: hit, label, depth, colour.
        let rows: Vec<Vec<CentreRay>> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut cands = Vec::with_capacity(64);
                (0..w)
                    .map(|x| {
                        let (o, d) = ray(x as f64 + 0.5, y as f64 + 0.5);
                        match self.trace(o, d, &mut cands) {
                            Some(hit) => {
                                let c = self.shade(o, d, hit, &cands);
                                let z = camera.depth_of((o + d * hit.t).as_dvec3()) as f32;
                                (Some(hit), c.to_array(), z)
                            }
                            None => (None, self.background.to_array(), 0.0),
                        }
                    })
                    .collect()
            })
            .collect();
        let key = |x: usize, y: usize| rows[y][x].0.map(|h| h.prim);
        // Supersample RGB where neighbouring centre rays differ.
        let rgb_rows: Vec<Vec<([u8; 3], u8)>> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut cands = Vec::with_capacity(64);
                (0..w)
                    .map(|x| {
                        let me = key(x, y);
                        let edge = (x > 0 && key(x - 1, y) != me)
                            || (x + 1 < w && key(x + 1, y) != me)
                            || (y > 0 && key(x, y - 1) != me)
                            || (y + 1 < h && key(x, y + 1) != me);
                        let (c, hits) = if edge {
                            let (mut sum, mut hits) = (Vec3::ZERO, 0u32);
                            for (dx, dy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]
                            {
                                let (o, d) = ray(x as f64 + dx, y as f64 + dy);
                                sum += match self.trace(o, d, &mut cands) {
                                    Some(hit) => {
                                        hits += 1;
                                        self.shade(o, d, hit, &cands)
                                    }
                                    None => self.background,
                                };
                            }
                            (sum * 0.25, hits)
                        } else {
                            (Vec3::from(rows[y][x].1), 4 * u32::from(me.is_some()))
                        };
                        let rgb = c
                            .to_array()
                            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8);
                        // A quarter of 255 per ray, rounded; on the 128 cut where the
                        // centre ray is (the person for rays, labels and depth is the
                        // centre ray's, so mask, segmentation and depth agree).
                        let coverage = ((hits * 255 + 2) / 4) as u8;
                        let coverage = if me.is_some() {
                            coverage.max(128)
                        } else {
                            coverage.min(127)
                        };
                        (rgb, coverage)
                    })
                    .collect()
            })
            .collect();
        let mut out = Rendered {
            rgb: Vec::with_capacity(w * h),
            coverage: Vec::with_capacity(w * h),
            label: Vec::with_capacity(w * h),
            depth: Vec::with_capacity(w * h),
        };
        for y in 0..h {
            out.rgb.extend(rgb_rows[y].iter().map(|p| p.0));
            out.coverage.extend(rgb_rows[y].iter().map(|p| p.1));
            for (hit, _, z) in &rows[y] {
                out.label
                    .push(hit.map_or(0, |hit| self.fig.prims[hit.prim].label));
                out.depth.push(*z);
            }
        }
        out
    }
}
