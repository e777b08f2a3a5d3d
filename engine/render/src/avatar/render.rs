//! Rendering one frame: every pixel's ray through the frame's sampler, the field in
//! chunks, volume rendering over the background.

use std::time::Instant;

use burn::prelude::*;
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use talkin_avatar::field_inputs::{frame_conditions, packed_layout};
use talkin_avatar::scene::{DilatedGrids, FrameSampler, FrameScene};
use talkin_grids::{Ray, SamplerKind};
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;
use talkin_nets::FieldInput;

use super::{Avatar, AvatarError};

/// Rays per field evaluation when rendering.
pub const RENDER_CHUNK_RAYS: usize = 8192;
/// Field samples per evaluation at most when rendering: a chunk of rays with more is
/// halved until it fits. This bounds the memory of one forward; a whole chunk of dense
/// rays (8192 x 128 samples) held several GB of activations, and two chunks in parallel
/// took about 14 GB.
pub const RENDER_CHUNK_SAMPLES: usize = 1 << 17;
/// Largest image a render accepts (pixels): 4096 x 4096.
pub const MAX_RENDER_PIXELS: u64 = 4096 * 4096;

/// One chunk of a frame's rays, rendered: per piece (a chunk halved to fit the sample
/// cap is two pieces), its values still on the device, or the rays' count where no ray
/// met the body. The frame reads every piece back at once.
struct ChunkOut {
    pieces: Vec<Piece>,
    samples: usize,
    /// The most samples one field forward of this chunk saw.
    largest_forward: usize,
}

enum Piece {
    /// `[rays, 4 + classes]`: colour over the background, opacity, segmentation logits.
    Rendered(Box<Tensor<2>>),
    /// This many rays without a sample: the background.
    Empty(usize),
}

impl ChunkOut {
    /// `next`'s rays after these.
    fn append(&mut self, next: ChunkOut) {
        self.pieces.extend(next.pieces);
        self.samples += next.samples;
        self.largest_forward = self.largest_forward.max(next.largest_forward);
    }
}

/// What every chunk of one frame's render shares.
#[derive(Clone, Copy)]
struct ChunkContext<'a> {
    frame_sampler: &'a FrameSampler,
    kind: SamplerKind,
    grid: &'a talkin_grids::OccupancyGrid,
    dilated: &'a DilatedGrids,
    conditions: &'a talkin_nets::FrameConditions,
    /// Field samples per evaluation at most (a single ray may exceed it).
    max_samples: usize,
}

/// A rendered image.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    pub width: u32,
    pub height: u32,
    /// Row-major RGB over the background, in [0, 1]. `[h * w * 3]`
    pub rgb: Vec<f32>,
    /// Accumulated opacity. `[h * w]`
    pub opacity: Vec<f32>,
    /// Argmax of the rendered segmentation logits (0 where the opacity is below 0.5).
    /// `[h * w]`
    pub labels: Vec<u8>,
    /// Field samples evaluated.
    pub samples: usize,
    /// The most samples one field forward saw ([`RENDER_CHUNK_SAMPLES`] at most, unless a
    /// single ray has more).
    pub largest_forward: usize,
    pub seconds: f64,
}

impl RenderedFrame {
    /// The colour as an 8-bit image.
    pub fn to_image(&self) -> RgbImage {
        let bytes = self
            .rgb
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        RgbImage::from_raw(self.width, self.height, bytes).expect("w * h * 3 values")
    }

    /// The opacity as an 8-bit mask.
    pub fn mask_image(&self) -> GrayImage {
        let bytes = self
            .opacity
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        GrayImage::from_raw(self.width, self.height, bytes).expect("w * h values")
    }
}

/// Pixel rays of `camera`, row-major.
pub(crate) fn pixel_rays(camera: &Camera) -> Result<Vec<Ray>, talkin_grids::GridError> {
    let mut rays = Vec::with_capacity((camera.width * camera.height) as usize);
    for y in 0..camera.height {
        for x in 0..camera.width {
            let (o, d) = camera.pixel_ray(x, y);
            rays.push(Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY)?);
        }
    }
    Ok(rays)
}

impl Avatar {
    /// Renders subject `subject` (identity index) in pose `params` through `camera`, with
    /// `sampler` (`None`: the one the avatar was trained with). Deterministic.
    pub fn render(
        &self,
        subject: usize,
        params: &FrameParams,
        camera: &Camera,
        sampler: Option<SamplerKind>,
    ) -> Result<RenderedFrame, AvatarError> {
        self.render_chunked(subject, params, camera, sampler, RENDER_CHUNK_SAMPLES)
    }

    /// [`Avatar::render`] with at most `max_chunk_samples` field samples evaluated at
    /// once (at least one ray's). The image does not depend on it.
    pub fn render_chunked(
        &self,
        subject: usize,
        params: &FrameParams,
        camera: &Camera,
        sampler: Option<SamplerKind>,
        max_chunk_samples: usize,
    ) -> Result<RenderedFrame, AvatarError> {
        let start = Instant::now();
        let model = self.subject_at(subject)?;
        if !params.is_finite() {
            return Err(AvatarError::BadInput {
                what: "params".into(),
                problem: "every pose, expression and translation value must be finite".into(),
            });
        }
        let pixels = u64::from(camera.width) * u64::from(camera.height);
        if pixels > MAX_RENDER_PIXELS {
            return Err(AvatarError::BadInput {
                what: "camera".into(),
                problem: format!(
                    "{}x{} is {pixels} pixels, more than the {MAX_RENDER_PIXELS} a render accepts",
                    camera.width, camera.height
                ),
            });
        }
        let kind = sampler.unwrap_or(self.sampler);
        let scene = FrameScene::new(&model.skeleton, &model.canonical, params);
        let fingers = self.config.skinning.skins_fingers();
        let conditions = frame_conditions(subject, params, &scene, &model.shells, fingers);
        let rays = pixel_rays(camera)?;
        let frame_sampler = FrameSampler::new(scene, &model.shells, &rays, fingers)?;

        // Chunks render in parallel (the field's inference runs on about one core); the
        // samples sit at their bins' regular places (no jitter), so the image is the same
        // on any number of threads.
        let chunks: Vec<ChunkOut> = rays
            .par_chunks(RENDER_CHUNK_RAYS)
            .map(|chunk| {
                let ctx = ChunkContext {
                    frame_sampler: &frame_sampler,
                    kind,
                    grid: &model.grid,
                    dilated: &model.dilated,
                    conditions: &conditions,
                    max_samples: max_chunk_samples,
                };
                self.render_chunk(&ctx, chunk)
            })
            .collect::<Result<_, _>>()?;
        let (mut total_samples, mut largest_forward) = (0, 0);
        let mut pieces = Vec::new();
        for c in chunks {
            largest_forward = largest_forward.max(c.largest_forward);
            total_samples += c.samples;
            pieces.extend(c.pieces);
        }
        let (rgb, opacity, labels) = self.read_back(pieces, rays.len())?;
        Ok(RenderedFrame {
            width: camera.width,
            height: camera.height,
            rgb,
            opacity,
            labels,
            samples: total_samples,
            largest_forward,
            seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// One chunk of a frame's rays, halved while it has more than `ctx.max_samples`
    /// samples.
    fn render_chunk(&self, ctx: &ChunkContext, chunk: &[Ray]) -> Result<ChunkOut, AvatarError> {
        let ChunkContext {
            frame_sampler,
            kind,
            grid,
            dilated,
            conditions,
            max_samples,
        } = *ctx;
        let samples = frame_sampler.sample(kind, chunk, grid, dilated, None)?;
        if samples.num_samples() > max_samples && chunk.len() > 1 {
            let (first, second) = chunk.split_at(chunk.len() / 2);
            let mut out = self.render_chunk(ctx, first)?;
            out.append(self.render_chunk(ctx, second)?);
            return Ok(out);
        }
        if samples.num_samples() == 0 {
            return Ok(ChunkOut {
                pieces: vec![Piece::Empty(chunk.len())],
                samples: 0,
                largest_forward: 0,
            });
        }
        let points: Vec<[f32; 3]> = samples
            .midpoints_in_world(chunk)
            .into_iter()
            .map(|p| p.to_array())
            .collect();
        let input = FieldInput {
            points: &points,
            bone_masks: &samples.bone_mask,
            part_masks: &samples.part_mask,
            frame: conditions,
            step: self.field_step,
        };
        let output = self.field.forward(&input)?;
        let layout = packed_layout(&samples);
        let rendered = output.render(&layout.view())?;
        let values = Tensor::cat(
            vec![
                rendered.rgb_over(self.background),
                rendered.opacity.clone().unsqueeze_dim(1),
                rendered.seg_logits.clone(),
            ],
            1,
        );
        Ok(ChunkOut {
            pieces: vec![Piece::Rendered(Box::new(values))],
            samples: samples.num_samples(),
            largest_forward: samples.num_samples(),
        })
    }

    /// The frame's colour, opacity and labels from its pieces (`n` rays in all), read back
    /// in one transfer (on a GPU, one wait for the frame's queued work).
    #[allow(clippy::type_complexity)]
    fn read_back(
        &self,
        pieces: Vec<Piece>,
        n: usize,
    ) -> Result<(Vec<f32>, Vec<f32>, Vec<u8>), AvatarError> {
        let wrong = || AvatarError::BadInput {
            what: "render".into(),
            problem: "the field returned the wrong number of values".into(),
        };
        let rendered: Vec<Tensor<2>> = pieces
            .iter()
            .filter_map(|p| match p {
                Piece::Rendered(t) => Some(t.as_ref().clone()),
                Piece::Empty(_) => None,
            })
            .collect();
        let (values, width) = match rendered.first() {
            None => (Vec::new(), 0),
            Some(first) => {
                let width = first.dims()[1];
                let values = Tensor::cat(rendered, 0)
                    .try_to_vec_as::<f32>()
                    .map_err(|_| wrong())?;
                (values, width)
            }
        };
        let classes = width.saturating_sub(4);
        let mut rgb = Vec::with_capacity(3 * n);
        let mut opacity = Vec::with_capacity(n);
        let mut labels = Vec::with_capacity(n);
        let mut rows = values.chunks_exact(width.max(1));
        for piece in &pieces {
            let count = match piece {
                Piece::Empty(count) => {
                    rgb.extend((0..*count).flat_map(|_| self.background));
                    opacity.extend(std::iter::repeat_n(0.0, *count));
                    labels.extend(std::iter::repeat_n(0u8, *count));
                    continue;
                }
                Piece::Rendered(t) => t.dims()[0],
            };
            for _ in 0..count {
                let row = rows.next().ok_or_else(wrong)?;
                if row.iter().take(4).any(|v| !v.is_finite()) {
                    return Err(AvatarError::BadInput {
                        what: "render".into(),
                        problem: "the field produced a non-finite colour or opacity \
                                  (a diverged checkpoint?)"
                            .into(),
                    });
                }
                rgb.extend_from_slice(&row[..3]);
                opacity.push(row[3]);
                let logits = &row[4..];
                // Argmax among the person classes where the ray is mostly opaque.
                labels.push(if row[3] < 0.5 || classes == 0 {
                    0
                } else {
                    (1..classes)
                        .max_by(|&a, &b| logits[a].total_cmp(&logits[b]))
                        .unwrap_or(0) as u8
                });
            }
        }
        if rgb.len() != 3 * n || rows.next().is_some() {
            return Err(wrong());
        }
        Ok((rgb, opacity, labels))
    }
}
