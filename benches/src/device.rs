//! The device bench: per device and preset, in one run, the training step rate (steps/s,
//! samples/s, the host sampler's share of a step), the render rate at 540x540 (or another
//! size) and the peak memory; with a trained run, its avatar's render rate on each device
//! too.
//!
//! Each row trains a fresh field from the same seed for `warmup + steps` steps on the
//! same frames and times the last `steps` as one block (the mean step); then it renders
//! `renders` frames from that field and times them (the median render). The block starts
//! after the warm-up's losses are read and ends once its own are (a GPU reads a step's
//! loss only with later steps', so a step's own time is its queueing), and a render ends
//! with its pixels read back: a GPU's queued work is inside the time. Memory: the
//! process's peak resident set (reset before each row where Linux allows it) and, on a
//! GPU, the most the device's allocator reserved.
//!
//! A fresh field is not the avatar a user renders: its occupancy grid holds only its
//! initial marks and its segmentation routes no sample to the face and hand nets. The
//! avatar rows render a trained run's newest checkpoint on each device, the same shot
//! timed the same way: the frame a user's avatar costs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use talkin_data::dataset::{Dataset, Frame, Split};
use talkin_human::camera::Camera;
use talkin_nets::{ComputeDevice, Device};
use talkin_train::{Budget, Preset, TrainOptions, Trainer};

use crate::error::BenchError;
use crate::shared::avatar_of;
use talkin_avatar::Avatar;
use talkin_render::avatar::RenderFrame;

/// The default render size (InstantAvatar's 540x540).
pub const RENDER_SIDE: u32 = 540;

/// What to measure.
#[derive(Clone, Debug)]
pub struct DeviceBenchOptions {
    pub devices: Vec<ComputeDevice>,
    pub presets: Vec<Preset>,
    /// Untimed steps first (kernel compilation, allocator warm-up).
    pub warmup: usize,
    /// Timed steps.
    pub steps: usize,
    /// Timed renders (after one untimed).
    pub renders: usize,
    /// The renders' side in pixels (square).
    pub render_side: u32,
    /// A trained run whose avatar (newest checkpoint) each device also renders.
    pub avatar: Option<PathBuf>,
    /// Everything else (batch, sampler, seed); its preset, device and budget are set here.
    pub train: TrainOptions,
}

/// One device and preset.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceRow {
    pub device: String,
    pub adapter: String,
    pub preset: String,
    pub batch_rays: usize,
    /// The timed steps' mean.
    pub step_ms: f64,
    pub steps_per_s: f64,
    pub samples_per_step: f64,
    pub samples_per_s: f64,
    /// The host sampler's share of the timed steps' wall time.
    pub sampling_share: f64,
    #[serde(flatten)]
    pub render: RenderTiming,
    /// The process's peak resident set over the row, MiB (`None` where Linux's
    /// `/proc/self/status` is not there).
    pub peak_rss_mib: Option<f64>,
    /// The most the device's allocator reserved, MiB (`None` on the CPU, whose tensors are
    /// in the resident set).
    pub peak_device_mib: Option<f64>,
}

/// A frame's render rate: `renders` timed renders of one shot after an untimed one.
#[derive(Clone, Debug, Serialize)]
pub struct RenderTiming {
    pub render_ms_median: f64,
    pub render_fps: f64,
    /// Field samples a frame evaluates.
    pub render_samples: usize,
    /// The timed renders' host sampling, as a share of their wall time.
    pub render_sampling_share: f64,
    /// The timed renders' forwards (on a GPU: laying out inputs and queueing work), as a
    /// share of their wall time; the rest is the read back waiting for the device.
    pub render_forward_share: f64,
}

/// A trained run's avatar rendered on one device.
#[derive(Clone, Debug, Serialize)]
pub struct AvatarRow {
    pub device: String,
    pub adapter: String,
    /// The run's directory (its newest checkpoint is rendered).
    pub run: PathBuf,
    #[serde(flatten)]
    pub render: RenderTiming,
    /// The most the device's allocator reserved over the renders, MiB (`None` on the CPU).
    pub peak_device_mib: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct DeviceReport {
    pub warmup: usize,
    pub steps: usize,
    pub renders: usize,
    pub render_size: [u32; 2],
    pub rows: Vec<DeviceRow>,
    /// With a trained run: its avatar on each device.
    pub avatar_rows: Vec<AvatarRow>,
}

/// Runs every device x preset row on `dataset`, training in `work/<device>-<preset>`.
pub fn run(
    dataset: &Dataset,
    work: &Path,
    opts: &DeviceBenchOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<DeviceReport, BenchError> {
    if opts.steps == 0 || opts.renders == 0 {
        return Err(BenchError::BadOption {
            field: "--steps/--renders",
            problem: "must be at least 1".into(),
        });
    }
    let (frame, camera) = render_shot(dataset, opts.render_side)?;
    let mut rows = Vec::new();
    let mut avatar_rows = Vec::new();
    for &device in &opts.devices {
        let opened = device.open().map_err(|e| BenchError::BadOption {
            field: "--devices",
            problem: e.to_string(),
        })?;
        if let Some(run) = &opts.avatar {
            progress(&format!("rendering {} on {device}", run.display()));
            let row = render_avatar(run, opts.renders, (device, &opened), (frame, &camera))?;
            progress(&format!(
                "{device} avatar: render {:.0} ms, {} samples",
                row.render.render_ms_median, row.render.render_samples
            ));
            avatar_rows.push(row);
        }
        for &preset in &opts.presets {
            progress(&format!("measuring {device} {}", preset.name()));
            let run = work.join(format!("{device}-{}", preset.name()).replace(':', "_"));
            let row = measure(
                dataset,
                &run,
                opts,
                (device, &opened),
                preset,
                (frame, &camera),
            )?;
            progress(&format!(
                "{device} {}: step {:.1} ms, {:.0} samples/s, render {:.0} ms",
                preset.name(),
                row.step_ms,
                row.samples_per_s,
                row.render.render_ms_median
            ));
            rows.push(row);
        }
    }
    Ok(DeviceReport {
        warmup: opts.warmup,
        steps: opts.steps,
        renders: opts.renders,
        render_size: [opts.render_side, opts.render_side],
        rows,
        avatar_rows,
    })
}

/// The newest checkpoint of `run` loaded on `device` and rendered as [`time_renders`]
/// says.
fn render_avatar(
    run: &Path,
    renders: usize,
    (device, opened): (ComputeDevice, &Device),
    (frame, camera): (&Frame, &Camera),
) -> Result<AvatarRow, BenchError> {
    let reserved = || opened.memory_pool_usage().map_or(0, |u| u.bytes_reserved);
    let avatar = Avatar::load_on(run, opened)?;
    let mut peak_device = reserved();
    let render = time_renders(&avatar, renders, (frame, camera), &mut || {
        peak_device = peak_device.max(reserved())
    })?;
    Ok(AvatarRow {
        device: device.to_string(),
        adapter: device.describe(opened),
        run: run.to_path_buf(),
        render,
        peak_device_mib: device.is_gpu().then_some(peak_device as f64 / MIB),
    })
}

/// `renders` timed renders of `frame` through `camera` after an untimed one (the first
/// compiles a GPU's kernels): their median, each ending with its pixels read back, so a
/// GPU's queued work is inside the time. `after_each` runs after every render.
fn time_renders(
    avatar: &Avatar,
    renders: usize,
    (frame, camera): (&Frame, &Camera),
    after_each: &mut dyn FnMut(),
) -> Result<RenderTiming, BenchError> {
    let mut render_samples = 0;
    let mut times = Vec::with_capacity(renders);
    let (mut wall, mut sampling, mut forward) = (0.0, 0.0, 0.0);
    for k in 0..=renders {
        let start = Instant::now();
        let out = avatar.render(frame.subject, &frame.params, camera, None)?;
        let _pixels = out.to_image();
        if k > 0 {
            times.push(start.elapsed().as_secs_f64());
            wall += out.seconds;
            sampling += out.sampling_seconds;
            forward += out.forward_seconds;
        }
        render_samples = out.samples;
        after_each();
    }
    let render_ms = median(times) * 1e3;
    Ok(RenderTiming {
        render_ms_median: render_ms,
        render_fps: 1e3 / render_ms,
        render_samples,
        render_sampling_share: sampling / f64::max(wall, 1e-12),
        render_forward_share: forward / f64::max(wall, 1e-12),
    })
}

/// One row: `device` as named and as opened, the frame and camera it renders.
fn measure(
    dataset: &Dataset,
    run: &Path,
    opts: &DeviceBenchOptions,
    (device, opened): (ComputeDevice, &Device),
    preset: Preset,
    (frame, camera): (&Frame, &Camera),
) -> Result<DeviceRow, BenchError> {
    // What the device's allocator holds (0 where it does not say).
    let reserved = || opened.memory_pool_usage().map_or(0, |u| u.bytes_reserved);
    let train = TrainOptions {
        device,
        preset,
        budget: Budget::Steps(opts.warmup + opts.steps),
        // No checkpoint inside the timed steps.
        checkpoint_every_s: f64::MAX,
        ..opts.train.clone()
    };
    let _ = std::fs::remove_dir_all(run);
    reset_peak_rss();
    let mut peak_device = 0u64;
    let mut trainer = Trainer::new(dataset, run, &train)?;
    for _ in 0..opts.warmup {
        trainer.step()?;
        peak_device = peak_device.max(reserved());
    }
    trainer.settle()?;
    let start = Instant::now();
    let mut logs = Vec::with_capacity(opts.steps);
    for _ in 0..opts.steps {
        logs.extend(trainer.step()?);
        peak_device = peak_device.max(reserved());
    }
    logs.extend(trainer.settle()?);
    let wall = start.elapsed().as_secs_f64().max(1e-12);
    let step_ms = wall * 1e3 / opts.steps as f64;
    let samples = logs.iter().map(|l| l.samples as f64).sum::<f64>() / opts.steps as f64;
    let sampling = logs.iter().map(|l| l.sampling_s).sum::<f64>() / wall;

    let avatar = avatar_of(&trainer);
    let render = time_renders(&avatar, opts.renders, (frame, camera), &mut || {
        peak_device = peak_device.max(reserved())
    })?;
    Ok(DeviceRow {
        device: device.to_string(),
        adapter: device.describe(opened),
        preset: preset.name().to_string(),
        batch_rays: train.batch_rays,
        step_ms,
        steps_per_s: 1e3 / step_ms,
        samples_per_step: samples,
        samples_per_s: samples / (step_ms / 1e3),
        sampling_share: sampling,
        render,
        peak_rss_mib: peak_rss_bytes().map(|b| b as f64 / MIB),
        peak_device_mib: device.is_gpu().then_some(peak_device as f64 / MIB),
    })
}

const MIB: f64 = 1024.0 * 1024.0;

/// The shot every row renders: the first training frame, and its camera widened to
/// `side` square, the focal length scaled so the longer side fills it, the principal
/// point moved to keep the subject centred.
pub fn render_shot(dataset: &Dataset, side: u32) -> Result<(&Frame, Camera), BenchError> {
    if !(16..=4096).contains(&side) {
        return Err(BenchError::BadOption {
            field: "--render-size",
            problem: format!("{side} is not in 16..=4096 pixels"),
        });
    }
    let frame = dataset
        .frames
        .iter()
        .find(|f| f.split == Split::Train)
        .or(dataset.frames.first())
        .ok_or_else(|| BenchError::BadOption {
            field: "--data",
            problem: "the dataset has no frames".into(),
        })?;
    let c = &frame.camera;
    let px = f64::from(side);
    let scale = px / c.width.max(c.height) as f64;
    let mut k = c.intrinsics_rows();
    for v in &mut k[0] {
        *v *= scale;
    }
    for v in &mut k[1] {
        *v *= scale;
    }
    k[0][2] += (px - c.width as f64 * scale) / 2.0;
    k[1][2] += (px - c.height as f64 * scale) / 2.0;
    let camera =
        Camera::new(side, side, k, c.extrinsics_rows()).map_err(|e| BenchError::BadOption {
            field: "--data",
            problem: format!("the first training frame's camera at {side}px: {e}"),
        })?;
    Ok((frame, camera))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => (v[n / 2 - 1] + v[n / 2]) / 2.0,
    }
}

/// Resets the kernel's peak-RSS counter for this process (Linux; a no-op elsewhere).
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// `VmHWM` of this process, in bytes.
fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The report as a Markdown table.
pub fn table(r: &DeviceReport) -> String {
    let mut s = format!(
        "{} timed steps after {} warm-up (their mean), {} renders at {}x{} (the median).\n\n\
         | device | preset | batch | step ms | steps/s | samples/s | sampler share | \
         render ms | fps | render sampling / forwards | peak RSS MiB | peak device MiB |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
        r.steps, r.warmup, r.renders, r.render_size[0], r.render_size[1]
    );
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.0}"));
    for row in &r.rows {
        s += &format!(
            "| {} | {} | {} | {:.1} | {:.2} | {:.0} | {:.1}% | {:.0} | {:.2} | {:.0}% / {:.0}% | {} | {} |\n",
            row.adapter,
            row.preset,
            row.batch_rays,
            row.step_ms,
            row.steps_per_s,
            row.samples_per_s,
            100.0 * row.sampling_share,
            row.render.render_ms_median,
            row.render.render_fps,
            100.0 * row.render.render_sampling_share,
            100.0 * row.render.render_forward_share,
            opt(row.peak_rss_mib),
            opt(row.peak_device_mib),
        );
    }
    if !r.avatar_rows.is_empty() {
        s += "\nA trained avatar, the same shot (its grid updated, samples routed to its \
              face and hand nets, where a fresh field's are not):\n\n\
              | device | run | render ms | fps | samples | render sampling / forwards | \
              peak device MiB |\n|---|---|---|---|---|---|---|\n";
        for row in &r.avatar_rows {
            s += &format!(
                "| {} | {} | {:.0} | {:.2} | {} | {:.0}% / {:.0}% | {} |\n",
                row.adapter,
                row.run.display(),
                row.render.render_ms_median,
                row.render.render_fps,
                row.render.render_samples,
                100.0 * row.render.render_sampling_share,
                100.0 * row.render.render_forward_share,
                opt(row.peak_device_mib),
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(vec![]).is_nan());
    }
}
