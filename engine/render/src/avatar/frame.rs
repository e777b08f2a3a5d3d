//! Rendering one frame: every pixel's ray through the frame's sampler, the field in
//! chunks, volume rendering over the background.

use std::ops::Range;
use std::time::Instant;

use burn::prelude::*;
use image::RgbImage;
use rayon::prelude::*;
use talkin_avatar::field_inputs::{frame_conditions, packed_layout};
use talkin_avatar::scene::{FrameSampler, FrameScene};
use talkin_grids::{PackedSamples, Ray, SamplerKind};
use talkin_human::body::FrameParams;
use talkin_human::camera::Camera;
use talkin_nets::{FieldConfig, FieldInput, is_cpu, max_tensor_bytes};

use talkin_avatar::{Avatar, AvatarError};

use super::forwards::plan_forwards;

/// Rays the host samples at once when rendering (chunks run in parallel).
pub const RENDER_CHUNK_RAYS: usize = 8192;
/// Field samples per evaluation at most when rendering on the CPU: a chunk of rays with
/// more is halved until it fits. This bounds the memory of one forward; a whole chunk of
/// dense rays (8192 x 128 samples) held several GB of activations, and two chunks in
/// parallel took about 14 GB. A GPU's own cap comes from its binding limit
/// ([`forward_samples_on`]).
pub const RENDER_CHUNK_SAMPLES: usize = 1 << 17;
/// Rays of a frame in one wave: the host holds one wave's samples at a time (32 chunks;
/// a dense 4096x4096 frame would otherwise hold about 36 GB of them).
pub const RENDER_WAVE_RAYS: usize = 32 * RENDER_CHUNK_RAYS;
/// The most samples one forward takes on a GPU, whatever its binding limit allows: a
/// 540x540 frame of the default scene (3.9M samples) is then eight forwards, which lay
/// out their inputs on eight host threads at once.
pub const DEVICE_FORWARD_SAMPLES_MAX: usize = 1 << 19;
/// Largest image a render accepts (pixels): 4096 x 4096.
pub const MAX_RENDER_PIXELS: u64 = 4096 * 4096;

/// One forward's rendered rays (its values still on the device), or the count of its
/// rays where no ray met the body. The frame reads every piece back at once.
enum Piece {
    /// `[rays, 7 + classes]`: colour over the background, opacity, the depth moments
    /// ([`talkin_nets::field::FieldOutput::depth_moments`]), segmentation logits.
    Rendered(Box<Tensor<2>>),
    /// This many rays without a sample: the background.
    Empty(usize),
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
    /// How thick the matter is along each pixel's ray: the weighted standard deviation
    /// of its samples' depths, metres (0 where nothing was met). `[h * w]`
    pub depth_spread: Vec<f32>,
    /// Argmax of the rendered segmentation logits (0 where the opacity is below 0.5).
    /// `[h * w]`
    pub labels: Vec<u8>,
    /// Field samples evaluated.
    pub samples: usize,
    /// The most samples one field forward saw ([`forward_samples_on`] at most, unless a
    /// single ray has more).
    pub largest_forward: usize,
    /// Wall time of the whole frame.
    pub seconds: f64,
    /// Of it, the host sampling the rays (each wave's chunks in parallel).
    pub sampling_seconds: f64,
    /// Of it, the forwards: on the CPU the field itself; on a GPU laying out each
    /// forward's inputs and queueing its work. What is left is the read back, which on a
    /// GPU waits for the queued work.
    pub forward_seconds: f64,
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
}

/// The most field samples one render forward takes on `device`: on the CPU
/// [`RENDER_CHUNK_SAMPLES`]; on a GPU as many as keep the widest activation within the
/// device's binding limit ([`max_tensor_bytes`]), at least [`RENDER_CHUNK_SAMPLES`] and
/// at most [`DEVICE_FORWARD_SAMPLES_MAX`]. The widest activation is bounded by twice the
/// widest MLP (a skip layer's input is its width and the encoding's) and at least 512
/// floats (inverse skinning's rows for a sample with every body bone a candidate).
pub fn forward_samples_on(device: &Device, config: &FieldConfig) -> usize {
    let Some(limit) = max_tensor_bytes(device) else {
        return RENDER_CHUNK_SAMPLES;
    };
    let widest = [&config.body, &config.face, &config.hands, &config.deform]
        .iter()
        .map(|m| 2 * m.width)
        .max()
        .unwrap_or(0)
        .max(512);
    let fits = limit / (4 * widest as u64);
    (fits as usize).clamp(RENDER_CHUNK_SAMPLES, DEVICE_FORWARD_SAMPLES_MAX)
}

/// Pixel rays of `camera`, row-major, made on every host thread (a 540x540 frame's took
/// 11 ms on one, a sixth of a 15-fps frame on a GPU).
pub(crate) fn pixel_rays(camera: &Camera) -> Result<Vec<Ray>, talkin_grids::GridError> {
    let width = camera.width as usize;
    (0..width * camera.height as usize)
        .into_par_iter()
        .map(|i| {
            let (o, d) = camera.pixel_ray((i % width) as u32, (i / width) as u32);
            Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY)
        })
        .collect()
}

/// Rendering a frame of an [`Avatar`].
pub trait RenderFrame {
    /// Renders subject `subject` (identity index) in pose `params` through `camera`, with
    /// `sampler` (`None`: the one the avatar was trained with). Deterministic.
    fn render(
        &self,
        subject: usize,
        params: &FrameParams,
        camera: &Camera,
        sampler: Option<SamplerKind>,
    ) -> Result<RenderedFrame, AvatarError> {
        self.render_chunked(subject, params, camera, sampler, self.forward_samples())
    }

    /// [`RenderFrame::render`] with at most `max_chunk_samples` field samples evaluated
    /// at once (at least one ray's). The image does not depend on it.
    fn render_chunked(
        &self,
        subject: usize,
        params: &FrameParams,
        camera: &Camera,
        sampler: Option<SamplerKind>,
        max_chunk_samples: usize,
    ) -> Result<RenderedFrame, AvatarError>;

    /// The most field samples one forward of a render takes on this avatar's device:
    /// [`forward_samples_on`].
    fn forward_samples(&self) -> usize;
}

impl RenderFrame for Avatar {
    fn render_chunked(
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

        // The frame goes in waves of chunks, so the host holds one wave's samples at a
        // time. In a wave the host samples its chunks in parallel (the samples sit at
        // their bins' regular places, no jitter, so the image is the same on any number
        // of threads); on a GPU the forwards are then joined up to the cap (each costs its
        // launches), and on the CPU they run in parallel as they are (the field's
        // inference runs on about one core).
        let join = !is_cpu(&self.field.identity.val().device());
        let (mut total_samples, mut largest_forward) = (0, 0);
        let (mut sampling_seconds, mut forward_seconds) = (0.0, 0.0);
        let mut pieces: Vec<Piece> = Vec::new();
        for (w, wave) in rays.chunks(RENDER_WAVE_RAYS).enumerate() {
            let wave_start = w * RENDER_WAVE_RAYS;
            let sampling = Instant::now();
            let sampled: Vec<(Range<usize>, PackedSamples)> = wave
                .par_chunks(RENDER_CHUNK_RAYS)
                .enumerate()
                .map(|(i, chunk)| {
                    let first = wave_start + i * RENDER_CHUNK_RAYS;
                    frame_sampler
                        .sample(kind, chunk, &model.grid, &model.dilated, None)
                        .map(|samples| (first..first + chunk.len(), samples))
                })
                .collect::<Result<_, _>>()?;
            sampling_seconds += sampling.elapsed().as_secs_f64();
            let forwarding = Instant::now();
            let forwards = plan_forwards(sampled, max_chunk_samples, join);
            for f in &forwards {
                total_samples += f.samples.num_samples();
                largest_forward = largest_forward.max(f.samples.num_samples());
            }
            let wave_pieces: Vec<Piece> = forwards
                .into_par_iter()
                .map(|f| render_forward(self, &conditions, &rays[f.rays], &f.samples))
                .collect::<Result<_, _>>()?;
            pieces.extend(wave_pieces);
            forward_seconds += forwarding.elapsed().as_secs_f64();
        }
        let Colours {
            rgb,
            opacity,
            depth_spread,
            labels,
        } = read_back(self, pieces, rays.len())?;
        Ok(RenderedFrame {
            width: camera.width,
            height: camera.height,
            rgb,
            opacity,
            depth_spread,
            labels,
            samples: total_samples,
            largest_forward,
            seconds: start.elapsed().as_secs_f64(),
            sampling_seconds,
            forward_seconds,
        })
    }

    fn forward_samples(&self) -> usize {
        forward_samples_on(&self.field.identity.val().device(), &self.config)
    }
}

/// One forward: `avatar`'s field at `samples` of `rays`, rendered over the background.
fn render_forward(
    avatar: &Avatar,
    conditions: &talkin_nets::FrameConditions,
    rays: &[Ray],
    samples: &PackedSamples,
) -> Result<Piece, AvatarError> {
    if samples.num_samples() == 0 {
        return Ok(Piece::Empty(rays.len()));
    }
    let points: Vec<[f32; 3]> = samples
        .midpoints_in_world(rays)
        .into_iter()
        .map(|p| p.to_array())
        .collect();
    let input = FieldInput {
        points: &points,
        bone_masks: &samples.bone_mask,
        part_masks: &samples.part_mask,
        frame: conditions,
        step: avatar.field_step,
    };
    let output = avatar.field.forward(&input)?;
    let layout = packed_layout(samples);
    let rendered = output.render(&layout.view())?;
    let values = Tensor::cat(
        vec![
            rendered.rgb_over(avatar.background),
            rendered.opacity.clone().unsqueeze_dim(1),
            output.depth_moments(&layout.view())?,
            rendered.seg_logits.clone(),
        ],
        1,
    );
    Ok(Piece::Rendered(Box::new(values)))
}

/// What a frame's pieces hold, per pixel.
struct Colours {
    rgb: Vec<f32>,
    opacity: Vec<f32>,
    depth_spread: Vec<f32>,
    labels: Vec<u8>,
}

/// Columns of a rendered piece before its segmentation logits.
const VALUE_COLUMNS: usize = 7;

/// The frame's colour, opacity, depth spread and labels from its pieces (`n` rays in
/// all), read back in one transfer (on a GPU, one wait for the frame's queued work).
fn read_back(avatar: &Avatar, pieces: Vec<Piece>, n: usize) -> Result<Colours, AvatarError> {
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
        None => (Vec::new(), VALUE_COLUMNS),
        Some(first) => {
            let width = first.dims()[1];
            let values = talkin_nets::read_floats(Tensor::cat(rendered, 0)).map_err(|_| wrong())?;
            (values, width)
        }
    };
    if width < VALUE_COLUMNS {
        return Err(wrong());
    }
    let classes = width - VALUE_COLUMNS;
    let mut out = Colours {
        rgb: Vec::with_capacity(3 * n),
        opacity: Vec::with_capacity(n),
        depth_spread: Vec::with_capacity(n),
        labels: Vec::with_capacity(n),
    };
    let mut rows = values.chunks_exact(width);
    for piece in &pieces {
        let count = match piece {
            Piece::Empty(count) => {
                out.rgb.extend((0..*count).flat_map(|_| avatar.background));
                out.opacity.extend(std::iter::repeat_n(0.0, *count));
                out.depth_spread.extend(std::iter::repeat_n(0.0, *count));
                out.labels.extend(std::iter::repeat_n(0u8, *count));
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
            out.rgb.extend_from_slice(&row[..3]);
            out.opacity.push(row[3]);
            out.depth_spread
                .push(talkin_nets::volume::depth_spread([row[4], row[5], row[6]]));
            let logits = &row[VALUE_COLUMNS..];
            // Argmax among the person classes where the ray is mostly opaque.
            out.labels.push(if row[3] < 0.5 || classes == 0 {
                0
            } else {
                (1..classes)
                    .max_by(|&a, &b| logits[a].total_cmp(&logits[b]))
                    .unwrap_or(0) as u8
            });
        }
    }
    if out.rgb.len() != 3 * n || rows.next().is_some() {
        return Err(wrong());
    }
    Ok(out)
}
