//! Training the TalkinNeRF field on a dataset (single process, every identity).
//!
//! One step: pick a training frame (seeded), draw a batch of pixel rays (80% inside the
//! person's bounding box), sample them (the accelerated capsule BVH + occupancy-grid
//! sampler, or the dense 128-per-ray baseline), evaluate the field, render, composite over
//! the dataset's background, loss `w_mse * MSE + 0.05 * CE(seg)` (+ `1 * perceptual` on a
//! 32x32 patch when asked for, with `w_mse = 0.2` as in the paper; else `w_mse = 1`),
//! backward, Adam (lr 5e-4, decayed by 0.1 over the run). Every `occ_every` steps each
//! subject's occupancy grid is updated with the field's density. At the end an atomic
//! checkpoint is written.

mod checkpoint;
mod rng;

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use glam::Vec3;
pub use talkin_grids::SamplerKind;
use talkin_grids::{GridError, MarginFitOpts, OccUpdateOpts, OccupancyGrid, PackedSamples, Ray};
use talkin_nets::loss::{LossError, PerceptualLoss, mse, seg_cross_entropy};
use talkin_nets::render::OwnedRaySamples;
use talkin_nets::skinning::BoneSegment;
use talkin_nets::{FieldConfig, FieldInput, FrameConditions, NetsError, TalkinField};

pub use checkpoint::{
    CONFIG_FILE, CheckpointPaths, CheckpointState, MODEL_FILE, STATE_FILE, load_config, load_state,
    save_checkpoint, write_atomic,
};
pub use rng::SplitMix64;

use crate::body::skeleton::body_ancestor;
use crate::body::{PosedSkeleton, canonical_params, limb_capsules};
use crate::dataset::{Dataset, DatasetError, FrameImages, Split};
use crate::sampling::{
    CanonicalGrid, CapsuleShells, FrameSampler, FrameScene, fit_subject_margins,
};
/// Weight of the segmentation cross-entropy.
pub const SEG_WEIGHT: f32 = 0.05;
/// Side of the perceptual-loss patch (pixels).
pub const PATCH: u32 = 32;
/// The log file inside the output directory.
pub const LOG_FILE: &str = "train_log.csv";
/// The checkpoint directory inside the output directory.
pub const CHECKPOINT_DIR: &str = "checkpoint";

/// Everything a run is told.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    /// `fast` or `paper`.
    pub preset: String,
    pub sampler: SamplerKind,
    /// Optimizer steps.
    pub steps: usize,
    /// Seed of the initialisation, frame and ray choice and sample jitter.
    pub seed: u64,
    /// Random pixel rays per step (besides the perceptual patch).
    pub batch_rays: usize,
    /// Initial Adam learning rate; decays exponentially to 0.1x over `steps`.
    pub lr: f64,
    /// Fraction of random rays drawn inside the person's bounding box.
    pub bbox_fraction: f32,
    /// Update the occupancy grids every this many steps (0: never). Accelerated only.
    pub occ_every: u32,
    /// Occupancy-grid cells along the longest axis.
    pub grid_resolution: u32,
    /// Directory of the LPIPS weights: `Some` adds a 32x32 patch per step with the
    /// perceptual loss (LPIPS if `alex.safetensors` is there, else 1 - SSIM) at weight 1
    /// and MSE at 0.2; `None`: MSE at weight 1, no patch.
    pub perceptual: Option<PathBuf>,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            preset: "fast".into(),
            sampler: SamplerKind::Accelerated,
            steps: 1000,
            seed: 0,
            batch_rays: 1024,
            lr: 5e-4,
            bbox_fraction: 0.8,
            occ_every: 64,
            grid_resolution: 128,
            perceptual: None,
        }
    }
}

/// One row of the training log.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepLog {
    /// 1-based: the step just taken.
    pub step: usize,
    pub loss: f32,
    pub mse: f32,
    /// Of the composited colour against the ground truth, over the batch.
    pub psnr: f32,
    pub rays: usize,
    pub samples: usize,
    pub rays_per_s: f64,
    pub samples_per_s: f64,
    pub lr: f64,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    pub logs: Vec<StepLog>,
    pub checkpoint: CheckpointPaths,
    pub log_file: PathBuf,
    pub seconds: f64,
    /// `Some` when a perceptual loss was asked for: why it is SSIM rather than LPIPS.
    pub perceptual_note: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {problem}", file.display())]
    Record { file: PathBuf, problem: String },
    #[error("option `{field}`: {problem}")]
    BadOption {
        field: &'static str,
        problem: String,
    },
    #[error("{}: no frame of split `train`", file.display())]
    NoTrainFrames { file: PathBuf },
    #[error("{}: frames[{frame}]: sampling: {source}", file.display())]
    Grid {
        file: PathBuf,
        frame: usize,
        #[source]
        source: GridError,
    },
    #[error("{}: subject {subject}: occupancy grid: {source}", file.display())]
    Occupancy {
        file: PathBuf,
        subject: usize,
        #[source]
        source: GridError,
    },
    #[error("field: {source}")]
    Field {
        #[source]
        source: NetsError,
    },
    #[error("perceptual loss: {source}")]
    Perceptual {
        #[source]
        source: LossError,
    },
    #[error("step {step}: the loss is not finite ({loss})")]
    NonFinite { step: usize, loss: f32 },
}

/// Per training frame: decoded images and everything the sampler needs that does not
/// change between steps.
struct FrameCache {
    images: FrameImages,
    /// Person bounding box in pixels, inclusive (`None`: empty mask).
    bbox: Option<[u32; 4]>,
    conditions: FrameConditions,
    sampler: FrameSampler,
}

/// One step's batch of rays and their targets.
struct Batch {
    rays: Vec<Ray>,
    rgb: Vec<f32>,
    labels: Vec<i32>,
    /// The first `PATCH * PATCH` rays form a row-major patch.
    has_patch: bool,
}

/// Trains on `dataset`, writing `out/train_log.csv` (one row per step) and
/// `out/checkpoint/`. `progress` sees every step's log and the total.
pub fn train(
    dataset: &Dataset,
    out: &Path,
    opts: &TrainOptions,
    progress: &mut dyn FnMut(&StepLog, usize),
) -> Result<TrainReport, TrainError> {
    let start = Instant::now();
    check_options(opts)?;
    let index_file = dataset.root.join(crate::dataset::INDEX_FILE);
    let train_frames = dataset.split_indices(Split::Train);
    if train_frames.is_empty() {
        return Err(TrainError::NoTrainFrames { file: index_file });
    }
    let n_subjects = dataset.subjects.len();
    let mut config =
        FieldConfig::preset(&opts.preset, n_subjects).ok_or_else(|| TrainError::BadOption {
            field: "preset",
            problem: format!("unknown preset `{}` (fast or paper)", opts.preset),
        })?;

    // Per subject: canonical pose, shells and the initial canonical occupancy grid.
    let mut canonicals: Vec<PosedSkeleton> = Vec::with_capacity(n_subjects);
    let mut shells: Vec<Option<CapsuleShells>> = Vec::with_capacity(n_subjects);
    let mut grids: Vec<Option<OccupancyGrid>> = Vec::with_capacity(n_subjects);
    let mut prior: Vec<BoneSegment> = Vec::new();
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for s in 0..n_subjects {
        let skeleton = &dataset.subjects[s].skeleton;
        let canonical = skeleton.pose(&canonical_params());
        for c in limb_capsules(skeleton, &canonical) {
            prior.push(BoneSegment {
                bone: body_ancestor(c.bone as usize),
                a: c.a.to_array(),
                b: c.b.to_array(),
            });
        }
        let frames: Vec<usize> = train_frames
            .iter()
            .copied()
            .filter(|&i| dataset.frames[i].subject == s)
            .collect();
        if frames.is_empty() {
            // A subject seen only in test splits: nothing to fit or train on.
            canonicals.push(canonical);
            shells.push(None);
            grids.push(None);
            continue;
        }
        let m = fit_subject_margins(dataset, s, &MarginFitOpts::default())?;
        let grid = CanonicalGrid::initial(
            skeleton,
            frames.iter().map(|&i| &dataset.frames[i].params),
            &m.shells,
            opts.grid_resolution,
        )
        .map_err(|source| TrainError::Occupancy {
            file: index_file.clone(),
            subject: s,
            source,
        })?;
        let (g_lo, g_hi) = grid.aabb();
        lo = lo.min(g_lo);
        hi = hi.max(g_hi);
        canonicals.push(canonical);
        shells.push(Some(m.shells));
        grids.push(Some(grid));
    }
    // The field's canonical box: the grids' union (every sample the grid keeps maps
    // inside it), a little padded.
    if lo.is_finite() && hi.is_finite() {
        let pad = Vec3::splat(0.05);
        config.aabb_min = (lo - pad).to_array();
        config.aabb_max = (hi + pad).to_array();
    }

    let device = Device::flex().autodiff();
    device.seed(opts.seed);
    let mut field = config
        .init(&prior, &device)
        .map_err(|source| TrainError::Field { source })?;
    let mut optim = AdamConfig::new().init();
    let perceptual = match &opts.perceptual {
        Some(dir) => Some(
            PerceptualLoss::from_dir(dir, talkin_nets::loss::Backbone::Alex, &device)
                .map_err(|source| TrainError::Perceptual { source })?,
        ),
        None => None,
    };
    let perceptual_note = perceptual.as_ref().and_then(|p| p.fallback_reason());
    let mse_weight = if perceptual.is_some() { 0.2 } else { 1.0 };
    // The face net's expression condition: psi, and the jaw when the config says so.
    let face_dim = talkin_nets::field::EXPRESSION_DIM
        + if config.face_uses_jaw {
            talkin_nets::field::JAW_DIM
        } else {
            0
        };

    std::fs::create_dir_all(out).map_err(|source| TrainError::Io {
        file: out.to_path_buf(),
        source,
    })?;
    let log_file = out.join(LOG_FILE);
    let mut log = std::io::BufWriter::new(std::fs::File::create(&log_file).map_err(|source| {
        TrainError::Io {
            file: log_file.clone(),
            source,
        }
    })?);
    let log_io = |source| TrainError::Io {
        file: log_file.clone(),
        source,
    };
    writeln!(
        log,
        "step,loss,mse,psnr,rays,samples,rays_per_s,samples_per_s,lr"
    )
    .map_err(log_io)?;

    let mut rng = SplitMix64::new(opts.seed ^ 0x7A1C_11E5_EED5_0001);
    let mut cache: HashMap<usize, FrameCache> = HashMap::new();
    let mut logs = Vec::with_capacity(opts.steps);
    // No full-grid warm-up: every update evaluates the occupied cells and a random
    // quarter. Evaluating all ~10^6 cells of a 128-cell grid with three nets took ~6 s per
    // subject on 2 cores (measured on the demo scene), 75x a training step.
    let occ_opts = OccUpdateOpts {
        n: opts.occ_every,
        seed: opts.seed,
        warmup_steps: 0,
        ..OccUpdateOpts::default()
    };
    for step in 0..opts.steps {
        let t0 = Instant::now();
        let i = train_frames[rng.below(train_frames.len() as u64) as usize];
        let subject = dataset.frames[i].subject;
        if let std::collections::hash_map::Entry::Vacant(slot) = cache.entry(i) {
            let shells = shells[subject]
                .as_ref()
                .expect("a training frame's subject");
            slot.insert(frame_cache(dataset, i, &canonicals[subject], shells)?);
        }
        let fc = &cache[&i];
        let batch =
            draw_batch(dataset, i, fc, opts, perceptual.is_some(), &mut rng).map_err(|source| {
                TrainError::Grid {
                    file: index_file.clone(),
                    frame: i,
                    source,
                }
            })?;
        let jitter_seed = opts
            .seed
            .wrapping_mul(0x9E37_79B9)
            .wrapping_add(step as u64);
        let grid = grids[subject].as_ref().expect("a training frame's subject");
        let samples = fc
            .sampler
            .sample(opts.sampler, &batch.rays, grid, jitter_seed)
            .map_err(|source| TrainError::Grid {
                file: index_file.clone(),
                frame: i,
                source,
            })?;
        let n_rays = batch.rays.len();
        let n_samples = samples.num_samples();
        let lr = opts.lr * 0.1f64.powf(step as f64 / opts.steps as f64);

        let (loss_value, mse_value, loss) = {
            let points: Vec<[f32; 3]> = samples
                .midpoints_in_world(&batch.rays)
                .into_iter()
                .map(|p| p.to_array())
                .collect();
            let layout = ray_samples(&samples);
            let input = FieldInput {
                points: &points,
                bone_masks: &samples.bone_mask,
                part_masks: &samples.part_mask,
                frame: &fc.conditions,
                step,
            };
            let output = field
                .forward(&input)
                .map_err(|source| TrainError::Field { source })?;
            let rendered = output
                .render(&layout.view())
                .map_err(|source| TrainError::Field { source })?;
            let rgb = rendered.rgb_over(dataset.background); // [r, 3]
            let target = Tensor::<2>::from_data(TensorData::new(batch.rgb, [n_rays, 3]), &device);
            let labels =
                Tensor::<1, Int>::from_data(TensorData::new(batch.labels, [n_rays]), &device);
            let l_mse = mse(rgb.clone(), target.clone());
            let l_seg = seg_cross_entropy(rendered.seg_logits, labels);
            let mut loss = l_mse.clone().mul_scalar(mse_weight) + l_seg.mul_scalar(SEG_WEIGHT);
            if let (Some(p), true) = (&perceptual, batch.has_patch) {
                let k = (PATCH * PATCH) as usize;
                let side = PATCH as usize;
                let to_image = |t: Tensor<2>| {
                    t.narrow(0, 0, k)
                        .reshape([1, side, side, 3])
                        .permute([0, 3, 1, 2])
                };
                let l_p = p.forward(to_image(rgb), to_image(target)).mean();
                loss = loss + l_p;
            }
            let loss_value = scalar(&loss);
            let mse_value = scalar(&l_mse);
            (loss_value, mse_value, loss)
        };
        if !loss_value.is_finite() {
            return Err(TrainError::NonFinite {
                step: step + 1,
                loss: loss_value,
            });
        }
        let grads = GradientsParams::from_grads(loss.backward(), &field);
        field = optim.step(lr, field, grads);

        if opts.sampler == SamplerKind::Accelerated && opts.occ_every > 0 {
            update_grids(
                &field,
                &mut grids,
                (step + 1) as u32,
                &occ_opts,
                face_dim,
                &index_file,
            )?;
        }

        let secs = t0.elapsed().as_secs_f64().max(1e-9);
        let entry = StepLog {
            step: step + 1,
            loss: loss_value,
            mse: mse_value,
            psnr: -10.0 * mse_value.max(1e-10).log10(),
            rays: n_rays,
            samples: n_samples,
            rays_per_s: n_rays as f64 / secs,
            samples_per_s: n_samples as f64 / secs,
            lr,
        };
        writeln!(
            log,
            "{},{},{},{},{},{},{:.1},{:.1},{:e}",
            entry.step,
            entry.loss,
            entry.mse,
            entry.psnr,
            entry.rays,
            entry.samples,
            entry.rays_per_s,
            entry.samples_per_s,
            entry.lr
        )
        .map_err(log_io)?;
        progress(&entry, opts.steps);
        logs.push(entry);
    }
    log.flush().map_err(log_io)?;
    drop(log);

    let state = CheckpointState {
        step: opts.steps,
        preset: opts.preset.clone(),
        sampler: opts.sampler.name().to_string(),
        seed: opts.seed,
        data: dataset.root.clone(),
    };
    let checkpoint = save_checkpoint(&out.join(CHECKPOINT_DIR), &field, &config, &state)?;
    Ok(TrainReport {
        logs,
        checkpoint,
        log_file,
        seconds: start.elapsed().as_secs_f64(),
        perceptual_note,
    })
}

fn check_options(opts: &TrainOptions) -> Result<(), TrainError> {
    let bad = |field, problem: &str| {
        Err(TrainError::BadOption {
            field,
            problem: problem.to_string(),
        })
    };
    if opts.steps == 0 {
        return bad("steps", "must be at least 1");
    }
    if opts.batch_rays == 0 {
        return bad("batch_rays", "must be at least 1");
    }
    if !(opts.lr.is_finite() && opts.lr > 0.0) {
        return bad("lr", "must be a positive number");
    }
    if !(0.0..=1.0).contains(&opts.bbox_fraction) {
        return bad("bbox_fraction", "must lie in [0, 1]");
    }
    if opts.grid_resolution < 8 {
        return bad("grid_resolution", "must be at least 8");
    }
    Ok(())
}

/// Reads a one-element tensor.
fn scalar(t: &Tensor<1>) -> f32 {
    t.clone()
        .try_to_vec_as::<f32>()
        .ok()
        .and_then(|v| v.first().copied())
        .unwrap_or(f32::NAN)
}

/// The nets' packed layout of grids' samples.
fn ray_samples(s: &PackedSamples) -> OwnedRaySamples {
    OwnedRaySamples {
        offsets: s.ray_offsets.iter().map(|&o| o as usize).collect(),
        t_start: s.t_start.clone(),
        t_end: s.t_end.clone(),
    }
}

/// The field's per-frame conditions.
fn frame_conditions(
    subject: usize,
    params: &crate::body::FrameParams,
    scene: &FrameScene,
) -> FrameConditions {
    let canonical_from_posed = scene
        .canonical_from_posed
        .iter()
        .map(|a| {
            let m = a.matrix3;
            let t = a.translation;
            [
                m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
                m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
                m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z, //
                0.0, 0.0, 0.0, 1.0,
            ]
        })
        .collect();
    let face = params.face_condition();
    let mut expression = [0.0f32; talkin_nets::field::EXPRESSION_DIM];
    expression.copy_from_slice(&face[..talkin_nets::field::EXPRESSION_DIM]);
    let mut jaw = [0.0f32; talkin_nets::field::JAW_DIM];
    jaw.copy_from_slice(&face[talkin_nets::field::EXPRESSION_DIM..]);
    FrameConditions {
        identity: subject,
        canonical_from_posed,
        body_pose: params.body_condition().to_vec(),
        expression,
        jaw,
        hand_pose: params.hand_condition().to_vec(),
    }
}

fn frame_cache(
    dataset: &Dataset,
    i: usize,
    canonical: &PosedSkeleton,
    shells: &CapsuleShells,
) -> Result<FrameCache, TrainError> {
    let frame = &dataset.frames[i];
    let skeleton = &dataset.subjects[frame.subject].skeleton;
    let images = dataset.images(i)?;
    let grid_err = |source| TrainError::Grid {
        file: dataset.root.join(crate::dataset::INDEX_FILE),
        frame: i,
        source,
    };
    let scene = FrameScene::new(skeleton, canonical, &frame.params);

    let mut bbox: Option<[u32; 4]> = None;
    let mut rays = Vec::new();
    for (x, y, m) in images.mask.enumerate_pixels() {
        if m.0[0] < 128 {
            continue;
        }
        bbox = Some(match bbox {
            None => [x, y, x, y],
            Some([x0, y0, x1, y1]) => [x0.min(x), y0.min(y), x1.max(x), y1.max(y)],
        });
        let (o, d) = frame.camera.pixel_ray(x, y);
        rays.push(Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY).map_err(grid_err)?);
    }
    let conditions = frame_conditions(frame.subject, &frame.params, &scene);
    let sampler = FrameSampler::new(scene, shells, &rays).map_err(grid_err)?;
    Ok(FrameCache {
        conditions,
        images,
        bbox,
        sampler,
    })
}

/// Draws the step's rays: with `patch`, first a `PATCH`x`PATCH` block inside the
/// person's box (clamped to the image); then `batch_rays` pixels, `bbox_fraction` of them
/// inside the person's box, the rest anywhere.
fn draw_batch(
    dataset: &Dataset,
    i: usize,
    fc: &FrameCache,
    opts: &TrainOptions,
    patch: bool,
    rng: &mut SplitMix64,
) -> Result<Batch, GridError> {
    let camera = &dataset.frames[i].camera;
    let (w, h) = (camera.width, camera.height);
    let mut pixels: Vec<(u32, u32)> = Vec::with_capacity(opts.batch_rays + 1024);
    let has_patch = patch && w >= PATCH && h >= PATCH;
    if has_patch {
        let [x0, y0, x1, y1] = fc.bbox.unwrap_or([0, 0, w - 1, h - 1]);
        // A patch corner so the patch lies in the image and overlaps the box.
        let cx = x0 + rng.below(u64::from(x1 - x0 + 1)) as u32;
        let cy = y0 + rng.below(u64::from(y1 - y0 + 1)) as u32;
        let px = cx.saturating_sub(PATCH / 2).min(w - PATCH);
        let py = cy.saturating_sub(PATCH / 2).min(h - PATCH);
        for y in py..py + PATCH {
            for x in px..px + PATCH {
                pixels.push((x, y));
            }
        }
    }
    for _ in 0..opts.batch_rays {
        let pixel = match fc.bbox {
            Some([x0, y0, x1, y1]) if rng.next_f32() < opts.bbox_fraction => (
                x0 + rng.below(u64::from(x1 - x0 + 1)) as u32,
                y0 + rng.below(u64::from(y1 - y0 + 1)) as u32,
            ),
            _ => (
                rng.below(u64::from(w)) as u32,
                rng.below(u64::from(h)) as u32,
            ),
        };
        pixels.push(pixel);
    }
    let mut batch = Batch {
        rays: Vec::with_capacity(pixels.len()),
        rgb: Vec::with_capacity(3 * pixels.len()),
        labels: Vec::with_capacity(pixels.len()),
        has_patch,
    };
    for (x, y) in pixels {
        let (o, d) = camera.pixel_ray(x, y);
        batch
            .rays
            .push(Ray::new(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY)?);
        let c = fc.images.rgb.get_pixel(x, y).0;
        batch.rgb.extend(c.iter().map(|&v| f32::from(v) / 255.0));
        let person = fc.images.mask.get_pixel(x, y).0[0] >= 128;
        let label = fc.images.segmentation.get_pixel(x, y).0[0];
        // A person pixel labelled background counts as body; labels beyond the classes
        // (never in valid data) as background.
        let label = if person { label.max(1) } else { 0 };
        batch
            .labels
            .push(if (label as usize) < crate::dataset::N_LABELS {
                i32::from(label)
            } else {
                0
            });
    }
    Ok(batch)
}

/// Updates every subject's grid with the field's density at canonical points (body net,
/// and the face and hand nets where built: the max, so a part another net renders is
/// never culled), times the cell's size as nerfacc's `density * step`, without gradients.
fn update_grids(
    field: &TalkinField,
    grids: &mut [Option<OccupancyGrid>],
    step: u32,
    opts: &OccUpdateOpts,
    d_e: usize,
    index_file: &Path,
) -> Result<(), TrainError> {
    if opts.n == 0 || !step.is_multiple_of(opts.n) {
        return Ok(());
    }
    let eval = field.valid();
    for (subject, grid) in grids.iter_mut().enumerate() {
        let Some(grid) = grid.as_mut() else { continue };
        let scale = grid.cell_size().min_element();
        let density = |points: &[Vec3]| canonical_density(&eval, subject, points, scale, d_e);
        grid.update_every_n_steps(step, density, opts)
            .map_err(|source| TrainError::Occupancy {
                file: index_file.to_path_buf(),
                subject,
                source,
            })?;
    }
    Ok(())
}

/// `max(sigma_body, sigma_face, sigma_hands) * scale` at canonical points of `subject`
/// (neutral expression and hand pose; no non-rigid offsets).
fn canonical_density(
    field: &TalkinField,
    subject: usize,
    points: &[Vec3],
    scale: f32,
    d_e: usize,
) -> Vec<f32> {
    let n = points.len();
    if n == 0 {
        return Vec::new();
    }
    let device = field.identity.val().device();
    let flat: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
    let x = Tensor::<2>::from_data(TensorData::new(flat, [n, 3]), &device);
    let unit = field.to_unit(x);
    let id = field
        .identity
        .val()
        .select(
            0,
            Tensor::<1, Int>::from_data(TensorData::new(vec![subject as i32], [1]), &device),
        )
        .repeat_dim(0, n);
    let raw_sigma = |raw: Tensor<2>| raw.narrow(1, 0, 1).squeeze_dim::<1>(1);
    let mut sigma = raw_sigma(
        field
            .body
            .forward(unit.clone(), vec![id.clone()], usize::MAX),
    );
    if let Some(face) = &field.face {
        let e = Tensor::<2>::zeros([n, d_e], &device);
        let s = raw_sigma(face.forward(unit.clone(), vec![e, id.clone()], usize::MAX));
        sigma = sigma.max_pair(s);
    }
    if let Some(hands) = &field.hands {
        let s = raw_sigma(hands.forward(unit, vec![id], usize::MAX));
        sigma = sigma.max_pair(s);
    }
    // softplus after the max (monotone, so the same as the max of the densities).
    let relu = sigma.clone().clamp_min(0.0);
    let sigma = relu + sigma.abs().neg().exp().log1p();
    sigma
        .mul_scalar(scale)
        .try_to_vec_as::<f32>()
        .unwrap_or_else(|_| vec![0.0; n])
        .into_iter()
        .map(|d| if d.is_finite() { d } else { 0.0 })
        .collect()
}
