//! Camera-like frames made from synthetic ones: what a phone and a matting tool hand over
//! instead of a person rendered over white with an exact mask. The camera has `scale`
//! times the scene's pixels along each axis, and its frames are averaged down to the
//! scene's size, as an import scales a phone's video down (`--max-size`): the flaws are
//! of the phone's pixels, and a frame without them is the scene's frame exactly. Each
//! scene pixel, a `scale` x `scale` block, is put by the exact mask in front of a dark,
//! cluttered room; the camera adds an exposure gain, sensor noise and JPEG; the matting
//! tool's mask is grown or shrunk, holed and soft. Every flaw can be turned off on its
//! own, to measure what each costs; the same seed gives the same bytes.

use std::io::Cursor;

use image::{GrayImage, RgbImage};
use talkin_grids::SplitMix64;

use super::layouts::{Clip, FramePixels};
pub use talkin_data::dataset::dilate;

/// How the frames differ from the synthetic scene's.
#[derive(Clone, Debug)]
pub struct Capture {
    /// Seeds the room, the noise and where the mask's holes fall.
    pub seed: u64,
    /// The camera's pixels per scene pixel along each axis; every flaw below is in the
    /// camera's pixels, which are averaged down to the scene's.
    pub scale: u32,
    /// A dark, cluttered room behind the person (a gradient, striped wall, checked floor,
    /// blobs of furniture, a lamp); without it the scene's white stays.
    pub room: bool,
    /// The camera's exposure against the scene's: a gain on the whole frame (1 = none).
    pub gain: f32,
    /// Sensor noise, its standard deviation in 8-bit levels (0 = none).
    pub noise: f32,
    /// Quality of the JPEG the frames are stored as (`None`: lossless).
    pub jpeg_quality: Option<u8>,
    pub mask: MaskFlaws,
}

/// How the matting tool's mask differs from the exact one.
#[derive(Clone, Debug)]
pub struct MaskFlaws {
    /// Pixels the mask grows by (negative: shrinks by), frame `i` taking entry
    /// `i % len` (empty: none).
    pub grow_px: Vec<i32>,
    /// Radius of a hole punched where the person is at least this deep plus a pixel
    /// (0: none).
    pub hole_px: u32,
    /// A hole in every this many frames, from the first (0: none).
    pub holes_every: usize,
    /// Soft edges: the mask blurred by a Gaussian of this sigma in pixels (0: hard).
    pub soft_px: f32,
}

/// One flaw of [`Capture::phone`], by the name the end-to-end test takes.
pub const FLAWS: [&str; 7] = ["room", "exposure", "noise", "jpeg", "grow", "hole", "soft"];

impl Capture {
    /// A phone video of a person in a living room, cut out by a matting tool, at 4 times
    /// the scene's size: every flaw on. The mask is 2 px off (half a scene pixel), its
    /// holes 4 px in radius, its edge soft over about 3 px; the noise and JPEG are a
    /// phone's at its own size, a quarter as strong once averaged down.
    pub fn phone(seed: u64) -> Capture {
        Capture {
            seed,
            scale: 4,
            room: true,
            gain: 0.9,
            noise: 3.0,
            jpeg_quality: Some(85),
            mask: MaskFlaws {
                grow_px: vec![2, -2],
                hole_px: 4,
                holes_every: 2,
                soft_px: 1.5,
            },
        }
    }

    /// No flaw: the synthetic frames, at [`Capture::phone`]'s scale.
    pub fn none(seed: u64) -> Capture {
        Capture::phone_with(seed, &[])
    }

    /// [`Capture::phone`] with only the flaws named (of [`FLAWS`]).
    pub fn phone_with(seed: u64, flaws: &[&str]) -> Capture {
        for f in flaws {
            assert!(FLAWS.contains(f), "unknown flaw {f:?}: one of {FLAWS:?}");
        }
        let phone = Capture::phone(seed);
        let on = |f: &str| flaws.contains(&f);
        let hole = on("hole");
        Capture {
            seed,
            scale: phone.scale,
            room: on("room"),
            gain: if on("exposure") { phone.gain } else { 1.0 },
            noise: if on("noise") { phone.noise } else { 0.0 },
            jpeg_quality: phone.jpeg_quality.filter(|_| on("jpeg")),
            mask: MaskFlaws {
                grow_px: if on("grow") {
                    phone.mask.grow_px
                } else {
                    Vec::new()
                },
                hole_px: if hole { phone.mask.hole_px } else { 0 },
                holes_every: if hole { phone.mask.holes_every } else { 0 },
                soft_px: if on("soft") { phone.mask.soft_px } else { 0.0 },
            },
        }
    }

    /// `clip` as the camera saw it: its frames' pixels by [`Capture::frames`].
    pub fn clip<'a>(&self, clip: &Clip<'a>) -> Clip<'a> {
        clip.with_pixels(self.frames(&clip.pixels))
    }

    /// The camera-like version of `frames` (persons over white with exact coverage masks,
    /// all of one size), of their size: the frame as stored (and its JPEG, when the
    /// camera's pixels are the scene's) and the matting tool's mask.
    pub fn frames(&self, frames: &[FramePixels]) -> Vec<FramePixels> {
        let Some(first) = frames.first() else {
            return Vec::new();
        };
        let (w, h) = first.rgb.dimensions();
        let room = self
            .room
            .then(|| room(w * self.scale, h * self.scale, self.seed));
        frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                assert_eq!(f.rgb.dimensions(), (w, h), "frames of one size");
                self.frame(i, &upscaled(f, self.scale), room.as_ref())
            })
            .collect()
    }

    fn frame(&self, i: usize, f: &FramePixels, room: Option<&Vec<[f32; 3]>>) -> FramePixels {
        let (w, h) = f.rgb.dimensions();
        // One stream for the sensor and one for the matting tool: turning one flaw off
        // leaves the others where they were.
        let frame_seed = self.seed ^ (0x9e37_79b9 * (i as u64 + 1));
        let (mut rng, mut mask_rng) = (SplitMix64::new(frame_seed), SplitMix64::new(!frame_seed));
        let rgb = RgbImage::from_fn(w, h, |x, y| {
            let clean = f.rgb.get_pixel(x, y).0.map(|c| f32::from(c) / 255.0);
            // The scene's pixel is a x person + (1 - a) x white, a its coverage: the room
            // takes the white's place, exactly.
            let a = f32::from(f.mask.get_pixel(x, y).0[0]) / 255.0;
            let seen: [f32; 3] = match room {
                Some(room) => {
                    let r = room[(y * w + x) as usize];
                    std::array::from_fn(|c| clean[c] + (1.0 - a) * (r[c] - 1.0))
                }
                None => clean,
            };
            image::Rgb(seen.map(|c| {
                let v = 255.0 * c * self.gain + self.noise * normal(&mut rng);
                v.round().clamp(0.0, 255.0) as u8
            }))
        });
        let (rgb, jpeg) = match self.jpeg_quality {
            None => (rgb, None),
            Some(q) => {
                let mut bytes = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, q)
                    .encode_image(&rgb)
                    .unwrap();
                let decoded = image::load(Cursor::new(&bytes), image::ImageFormat::Jpeg)
                    .unwrap()
                    .to_rgb8();
                (decoded, Some(bytes))
            }
        };
        let mask = self.mask.apply(i, &f.mask, &mut mask_rng);
        if self.scale == 1 {
            return FramePixels { rgb, jpeg, mask };
        }
        let s = self.scale;
        let (sw, sh) = (w / s, h / s);
        // The mean of each block, rounded: a block of one value keeps it.
        let mean = |sum: u32| ((sum + s * s / 2) / (s * s)) as u8;
        let block = |x: u32, y: u32, v: &dyn Fn(u32, u32) -> u8| {
            let sum: u32 = (0..s * s)
                .map(|k| u32::from(v(x * s + k % s, y * s + k / s)))
                .sum();
            mean(sum)
        };
        FramePixels {
            rgb: RgbImage::from_fn(sw, sh, |x, y| {
                image::Rgb(std::array::from_fn(|c| {
                    block(x, y, &|xx, yy| rgb.get_pixel(xx, yy).0[c])
                }))
            }),
            jpeg: None,
            mask: GrayImage::from_fn(sw, sh, |x, y| {
                image::Luma([block(x, y, &|xx, yy| mask.get_pixel(xx, yy).0[0])])
            }),
        }
    }
}

/// `f` at `scale` times its size, each pixel a `scale` x `scale` block (so averaging the
/// blocks gives `f` back).
fn upscaled(f: &FramePixels, scale: u32) -> FramePixels {
    let (w, h) = f.rgb.dimensions();
    FramePixels {
        rgb: RgbImage::from_fn(w * scale, h * scale, |x, y| {
            *f.rgb.get_pixel(x / scale, y / scale)
        }),
        jpeg: None,
        mask: GrayImage::from_fn(w * scale, h * scale, |x, y| {
            *f.mask.get_pixel(x / scale, y / scale)
        }),
    }
}

impl MaskFlaws {
    /// Frame `i`'s mask as the matting tool gives it, from the exact `mask`.
    fn apply(&self, i: usize, mask: &GrayImage, rng: &mut SplitMix64) -> GrayImage {
        let (w, h) = mask.dimensions();
        let holed = self.hole_px > 0 && self.holes_every > 0 && i.is_multiple_of(self.holes_every);
        let grow = match self.grow_px.len() {
            0 => 0,
            n => self.grow_px[i % n],
        };
        if grow == 0 && !holed && self.soft_px == 0.0 {
            // No flaw on this frame: the exact coverage.
            return mask.clone();
        }
        let mut person: Vec<bool> = mask.iter().map(|&m| m >= 128).collect();
        person = if grow >= 0 {
            dilate(&person, w, h, grow as u32)
        } else {
            let outside: Vec<bool> = person.iter().map(|p| !p).collect();
            dilate(&outside, w, h, grow.unsigned_abs())
                .iter()
                .map(|o| !o)
                .collect()
        };
        if holed {
            // Deep enough: the hole and a pixel around it lie inside the person and the
            // frame.
            let margin = self.hole_px + 1;
            let outside: Vec<bool> = person.iter().map(|p| !p).collect();
            let near_edge = dilate(&outside, w, h, margin);
            let inside_frame = |k: usize| {
                let (x, y) = (k as u32 % w, k as u32 / w);
                x >= margin && y >= margin && x + margin < w && y + margin < h
            };
            let deep: Vec<usize> = (0..person.len())
                .filter(|&k| !near_edge[k] && inside_frame(k))
                .collect();
            if !deep.is_empty() {
                let at = deep[rng.below(deep.len() as u64) as usize];
                let (cx, cy) = ((at % w as usize) as i64, (at / w as usize) as i64);
                let r = i64::from(self.hole_px);
                for y in cy - r..=cy + r {
                    for x in cx - r..=cx + r {
                        if (x - cx).pow(2) + (y - cy).pow(2) <= r * r {
                            person[(y * w as i64 + x) as usize] = false;
                        }
                    }
                }
            }
        }
        let values: Vec<f32> = person
            .iter()
            .map(|&p| if p { 255.0 } else { 0.0 })
            .collect();
        let values = if self.soft_px > 0.0 {
            blur(&values, w, h, self.soft_px)
        } else {
            values
        };
        GrayImage::from_raw(
            w,
            h,
            values
                .iter()
                .map(|v| v.round().clamp(0.0, 255.0) as u8)
                .collect(),
        )
        .unwrap()
    }
}

/// A room behind the person, linear RGB in [0, 1] per pixel (row-major): a dark wall
/// shading into a warm floor, stripes on the wall, a checked floor, blobs of furniture
/// and a lamp's bright spot, all placed by `seed`.
pub fn room(w: u32, h: u32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = SplitMix64::new(seed);
    let (wf, hf) = (w as f32, h as f32);
    let blobs: Vec<([f32; 2], f32, [f32; 3])> = (0..6)
        .map(|_| {
            let centre = [rng.next_f32() * wf, rng.next_f32() * hf];
            let radius = (0.05 + 0.1 * rng.next_f32()) * hf;
            let colour = [
                0.1 + 0.5 * rng.next_f32(),
                0.1 + 0.5 * rng.next_f32(),
                0.1 + 0.5 * rng.next_f32(),
            ];
            (centre, radius, colour)
        })
        .collect();
    let lamp = [
        (0.1 + 0.8 * rng.next_f32()) * wf,
        (0.05 + 0.2 * rng.next_f32()) * hf,
    ];
    let floor = 0.7 * hf;
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let t = py / hf;
            let mut c = [0.10 + 0.20 * t, 0.11 + 0.13 * t, 0.14 + 0.04 * t];
            let pattern = if py < floor {
                // Wallpaper stripes, 8 across the frame.
                0.06 * (std::f32::consts::TAU * 8.0 * px / wf).sin()
            } else {
                // Floor tiles, 10 across the frame's height.
                let tile = (hf / 10.0).max(1.0);
                let odd = ((px / tile).floor() + (py / tile).floor()) as i64 % 2 == 1;
                if odd { 0.08 } else { -0.04 }
            };
            c = c.map(|v| v + pattern);
            for (centre, radius, colour) in &blobs {
                let d2 = (px - centre[0]).powi(2) + (py - centre[1]).powi(2);
                let a = 0.8 * (-d2 / (2.0 * radius * radius)).exp();
                c = std::array::from_fn(|k| c[k] * (1.0 - a) + colour[k] * a);
            }
            let d2 = (px - lamp[0]).powi(2) + (py - lamp[1]).powi(2);
            let glow = (-d2 / (2.0 * (0.06 * hf).powi(2))).exp();
            let lamp_colour = [1.0, 0.97, 0.85];
            c = std::array::from_fn(|k| c[k] * (1.0 - glow) + lamp_colour[k] * glow);
            out.push(c.map(|v| v.clamp(0.0, 1.0)));
        }
    }
    out
}

/// A separable Gaussian blur of sigma `s` px, edges clamped.
fn blur(v: &[f32], w: u32, h: u32, s: f32) -> Vec<f32> {
    let (w, h) = (w as usize, h as usize);
    let r = (3.0 * s).ceil() as i64;
    let kernel: Vec<f32> = (-r..=r)
        .map(|d| (-(d * d) as f32 / (2.0 * s * s)).exp())
        .collect();
    let total: f32 = kernel.iter().sum();
    let pass = |src: &[f32], along_x: bool| -> Vec<f32> {
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (k, d) in (-r..=r).enumerate() {
                    let (sx, sy) = if along_x {
                        ((x as i64 + d).clamp(0, w as i64 - 1) as usize, y)
                    } else {
                        (x, (y as i64 + d).clamp(0, h as i64 - 1) as usize)
                    };
                    acc += kernel[k] * src[sy * w + sx];
                }
                out[y * w + x] = acc / total;
            }
        }
        out
    };
    pass(&pass(v, true), false)
}

/// Standard normal (Box-Muller).
fn normal(rng: &mut SplitMix64) -> f32 {
    let u = 1.0 - rng.next_f32();
    let v = rng.next_f32();
    (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
}
