//! `talkin bench sampling`: the dense baseline against the accelerated sampler over every
//! frame of a dataset, with what the speed costs: surface points the samples miss.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;
use talkin_avatar::scene::{
    CanonicalGrid, CapsuleShells, DilatedGrids, FrameSampler, FrameScene, SubjectMargins,
    canonical_surface_points, fit_subject_margins, foreground_rays, grid_error,
};
use talkin_grids::{
    MarginFitOpts, OccupancyGrid, Part, Ray, SURFACE_SLACK_M, SamplerKind, sample_in_capsules,
    sample_in_front_of_cores,
};

use talkin_data::dataset::{Dataset, DatasetError, Split};
use talkin_human::body::canonical_params;

/// Canonical grid cells along its longest axis.
pub const GRID_RESOLUTION: u32 = 128;
/// Timing repeats per frame and sampler; the median is kept.
const REPEATS: usize = 3;

/// Surface coverage of one part's foreground rays.
#[derive(Clone, Debug, Serialize)]
pub struct PartCoverage {
    /// Foreground rays labelled with this part, over all frames.
    pub rays: usize,
    /// Margin fitted on the training masks, metres (maximum over subjects).
    pub margin_m: f32,
    /// Training rays covered by a capsule of their own part before / after the margin.
    pub train_coverage_bare: f64,
    pub train_coverage: f64,
    /// Rays whose true surface point lies in no accelerated sample.
    pub surface_misses: usize,
}

/// What the sampling benchmark measures. Rates are over the whole dataset; the per-frame
/// speed ratios' median is given beside them because shared machines are noisy.
#[derive(Clone, Debug, Serialize)]
pub struct SamplingReport {
    /// Which canonical grids culled: `initial` (built from the training frames) or
    /// `trained` (a run's, after its occupancy updates).
    pub grids: String,
    pub frames: usize,
    pub foreground_rays: usize,
    pub dense_samples_per_ray: f64,
    /// After the BVH intervals and the occupancy-grid culling.
    pub accelerated_samples_per_ray: f64,
    /// After the BVH intervals, before core truncation and grid culling.
    pub capsule_samples_per_ray: f64,
    /// After the BVH intervals and core truncation, before grid culling.
    pub truncated_samples_per_ray: f64,
    pub dense_rays_per_s: f64,
    pub accelerated_rays_per_s: f64,
    /// The grown capsules' exact, merged intervals alone through the BVH (a per-ray BVH
    /// query, before a single sample is cut), for scale: the accelerated sampler finds
    /// the same intervals without it (per-chunk cones, per-ray bounding spheres).
    pub bvh_intervals_rays_per_s: f64,
    /// Median over frames of (accelerated rays/s) / (dense rays/s).
    pub median_speed_ratio: f64,
    /// Share of the accelerated sampler's time spent building each frame's structures
    /// (the grown capsules and cores, the accelerated sampler) rather than sampling rays.
    pub accelerated_build_share: f64,
    /// Foreground pixels whose true surface point (ground-truth depth, or for data
    /// without depth: the ray itself) lies outside every accelerated sample.
    pub surface_misses: usize,
    /// Surface misses per split (train frames fitted the margins; the others test them).
    pub surface_misses_by_split: BTreeMap<String, usize>,
    /// Surface misses by the stage that lost them: `outside_grown_capsules`,
    /// `behind_a_core`, `culled_by_grid`.
    pub surface_misses_by_stage: BTreeMap<String, usize>,
    /// Foreground rays that had ground-truth depth to check against.
    pub surface_checked_rays: usize,
    pub coverage_by_part: BTreeMap<String, PartCoverage>,
    /// Median accelerated step (metres): the median dense step of each frame.
    pub accelerated_step_m: f32,
}

/// Why a run's grids cannot stand in for a dataset's in [`bench_sampling`].
#[derive(Debug, thiserror::Error)]
pub enum TrainedGridsError {
    #[error(transparent)]
    Checkpoint(#[from] talkin_avatar::checkpoint::CheckpointError),
    #[error("{}: no trained model for subject `{subject}` of {}", checkpoint.display(), dataset.display())]
    NoModel {
        checkpoint: std::path::PathBuf,
        subject: String,
        dataset: std::path::PathBuf,
    },
}

/// The canonical grid the run in `run` trained for each of `dataset`'s subjects, matched
/// by name (`talkin bench sampling --run`).
pub fn trained_grids(
    run: &std::path::Path,
    dataset: &Dataset,
) -> Result<Vec<OccupancyGrid>, TrainedGridsError> {
    let checkpoint = talkin_avatar::checkpoint::Checkpoint::load(run)?;
    dataset
        .subjects
        .iter()
        .map(|subject| {
            checkpoint
                .subjects
                .iter()
                .find(|slot| slot.name == subject.name)
                .and_then(|slot| slot.model.as_ref())
                .map(|model| model.grid.clone())
                .ok_or_else(|| TrainedGridsError::NoModel {
                    checkpoint: checkpoint.dir.clone(),
                    subject: subject.name.clone(),
                    dataset: dataset.root.clone(),
                })
        })
        .collect()
}

/// Runs both samplers over every frame, after fitting margins and building each
/// subject's initial canonical grid from its training frames. With `trained` (one grid
/// per dataset subject, e.g. a run's after its occupancy updates), the accelerated
/// sampler culls with those instead; each must cover the box the initial grid covers
/// (the same data fits the same shells), else it is an error.
pub fn bench_sampling(
    dataset: &Dataset,
    trained: Option<&[OccupancyGrid]>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SamplingReport, DatasetError> {
    let (margins, grids) = subject_grids(dataset, trained)?;
    // Each subject's dilated grid is made once and shared by its frames, as in training.
    let dilated: Vec<DilatedGrids> = grids.iter().map(|_| DilatedGrids::default()).collect();
    let mut tally = Tally::new();
    for i in 0..dataset.frames.len() {
        let frame = &dataset.frames[i];
        measure_frame(
            dataset,
            i,
            &margins[frame.subject].shells,
            &grids[frame.subject],
            &dilated[frame.subject],
            &mut tally,
        )?;
        progress(i + 1, dataset.frames.len());
    }
    Ok(tally.report(dataset, &margins, trained.is_some()))
}

/// Per subject: the margins fitted on its training masks, and the grid that culls, its
/// initial one or (with `trained`) the run's, checked to cover the same box.
fn subject_grids(
    dataset: &Dataset,
    trained: Option<&[OccupancyGrid]>,
) -> Result<(Vec<SubjectMargins>, Vec<OccupancyGrid>), DatasetError> {
    let invalid = |field: String, problem: String| DatasetError::Invalid {
        file: dataset.root.join(talkin_data::dataset::INDEX_FILE),
        field,
        problem,
    };
    if let Some(t) = trained
        && t.len() != dataset.subjects.len()
    {
        return Err(invalid(
            "subjects".into(),
            format!(
                "{} trained grids for {} subjects",
                t.len(),
                dataset.subjects.len()
            ),
        ));
    }
    let mut subject_margins: Vec<SubjectMargins> = Vec::new();
    let mut grids: Vec<OccupancyGrid> = Vec::new();
    let train = dataset.split_indices(Split::Train);
    for s in 0..dataset.subjects.len() {
        let m = fit_subject_margins(dataset, s, &MarginFitOpts::default())?;
        let own: Vec<usize> = train
            .iter()
            .copied()
            .filter(|&i| dataset.frames[i].subject == s)
            .collect();
        let surface = canonical_surface_points(dataset, &own, &m.shells)?;
        let grid = CanonicalGrid::initial(
            &dataset.subjects[s].skeleton,
            own.iter().map(|&i| &dataset.frames[i].params),
            &m.shells,
            GRID_RESOLUTION,
            surface.as_deref(),
        )
        .map_err(|e| grid_error(dataset, 0, e))?;
        let grid = match trained.map(|t| &t[s]) {
            None => grid,
            Some(t) if t.aabb() == grid.aabb() && t.resolution() == grid.resolution() => t.clone(),
            Some(t) => {
                return Err(invalid(
                    format!("subjects[{s}]"),
                    format!(
                        "the trained grid covers {:?} at {:?} cells, this dataset's {:?} at \
                         {:?}: was the run trained on this dataset?",
                        t.aabb(),
                        t.resolution(),
                        grid.aabb(),
                        grid.resolution()
                    ),
                ));
            }
        };
        subject_margins.push(m);
        grids.push(grid);
    }
    Ok((subject_margins, grids))
}

/// Times both samplers on frame `i`'s foreground rays and counts its samples and the
/// surface points the accelerated samples miss.
fn measure_frame(
    dataset: &Dataset,
    i: usize,
    shells: &CapsuleShells,
    grid: &OccupancyGrid,
    dilated: &DilatedGrids,
    tally: &mut Tally,
) -> Result<(), DatasetError> {
    let frame = &dataset.frames[i];
    let skeleton = &dataset.subjects[frame.subject].skeleton;
    let canonical = skeleton.pose(&canonical_params());
    let scene = FrameScene::new(skeleton, &canonical, &frame.params);
    let images = dataset.images(i)?;
    let depth = dataset.depth(i)?;
    let grid_err = |e| grid_error(dataset, i, e);
    let (labelled, pixels) = foreground_rays(&frame.camera, &images).map_err(grid_err)?;
    let rays: Vec<Ray> = labelled.iter().map(|l| l.ray).collect();
    let seed = i as u64;
    // Building the frame's structures (the capsules, the accelerated sampler) is part
    // of the accelerated sampler's cost (once per frame); the BVHs are the reference,
    // built outside the timing.
    let (sampler, build_s) = median_time(|| {
        let sampler = FrameSampler::new(scene.clone(), shells, &rays, true)?;
        sampler.prepare(grid, dilated)?;
        Ok::<_, talkin_grids::GridError>(sampler)
    });
    let sampler = sampler.map_err(grid_err)?;
    tally.steps.push(sampler.step);
    let (dense, dense_s) =
        median_time(|| sampler.sample(SamplerKind::Dense, &rays, grid, dilated, Some(seed)));
    let dense = dense.map_err(grid_err)?;
    let (acc, acc_s) =
        median_time(|| sampler.sample(SamplerKind::Accelerated, &rays, grid, dilated, Some(seed)));
    let acc = acc.map_err(grid_err)?;
    let (bvh, core_bvh) = sampler.bvhs().map_err(grid_err)?;
    let (intervals, intervals_s) = median_time(|| bvh.intervals(&rays));
    intervals.map_err(grid_err)?;
    let totals = &mut tally.totals;
    totals.intervals_s += intervals_s;
    totals.build_s += build_s;
    let acc_s = acc_s + build_s;
    // Outside the timing, for the counts and to tell which stage loses a surface point:
    // the grown capsules alone, and with the cores (deterministic, so the same samples
    // as inside the timed pipeline).
    let acc_opts = sampler.accelerated_opts(Some(seed));
    let in_capsules = sample_in_capsules(bvh, &rays, &acc_opts).map_err(grid_err)?;
    let in_front = sample_in_front_of_cores(bvh, core_bvh, &rays, sampler.step, &acc_opts)
        .map_err(grid_err)?;
    totals.rays += rays.len();
    totals.dense_samples += dense.num_samples();
    totals.acc_samples += acc.num_samples();
    totals.capsule_samples += in_capsules.num_samples();
    totals.truncated_samples += in_front.num_samples();
    totals.dense_s += dense_s;
    totals.acc_s += acc_s;
    if !rays.is_empty() && dense_s > 0.0 && acc_s > 0.0 {
        tally.ratios.push(dense_s / acc_s);
    }
    let forward = frame.camera.forward_in_world().as_vec3();
    for (r, l) in labelled.iter().enumerate() {
        let k = Part::from_label(l.label)
            .map(|p| p.label() as usize - 1)
            .unwrap_or(0);
        tally.part_rays[k] += 1;
        // A person pixel without depth: at least one sample must exist.
        let t_surface = depth
            .as_ref()
            .and_then(|d| d[pixels[r] as usize])
            .map(|z| z / l.ray.direction.dot(forward));
        let covered = match t_surface {
            Some(t) => {
                tally.totals.checked += 1;
                let found = acc.holds(r, t, SURFACE_SLACK_M);
                if !found {
                    let stage = if !in_capsules.holds(r, t, SURFACE_SLACK_M) {
                        "outside_grown_capsules"
                    } else if !in_front.holds(r, t, SURFACE_SLACK_M) {
                        "behind_a_core"
                    } else {
                        "culled_by_grid"
                    };
                    *tally.stage_misses.entry(stage.to_string()).or_default() += 1;
                }
                found
            }
            None => !acc.range(r).is_empty(),
        };
        if !covered {
            tally.part_misses[k] += 1;
            *tally
                .split_misses
                .entry(frame.split.name().to_string())
                .or_default() += 1;
        }
    }
    Ok(())
}

/// What the frames add up to.
struct Tally {
    totals: Totals,
    /// Per frame, dense over accelerated seconds.
    ratios: Vec<f64>,
    /// Per frame, the accelerated sampler's step.
    steps: Vec<f32>,
    part_rays: [usize; 4],
    part_misses: [usize; 4],
    stage_misses: BTreeMap<String, usize>,
    split_misses: BTreeMap<String, usize>,
}

impl Tally {
    fn new() -> Tally {
        Tally {
            totals: Totals::default(),
            ratios: Vec::new(),
            steps: Vec::new(),
            part_rays: [0; 4],
            part_misses: [0; 4],
            stage_misses: BTreeMap::new(),
            split_misses: Split::ALL
                .iter()
                .map(|s| (s.name().to_string(), 0))
                .collect(),
        }
    }

    fn report(
        mut self,
        dataset: &Dataset,
        margins: &[SubjectMargins],
        trained: bool,
    ) -> SamplingReport {
        let totals = &self.totals;
        let per_ray = |n: usize| n as f64 / totals.rays.max(1) as f64;
        SamplingReport {
            grids: if trained { "trained" } else { "initial" }.to_string(),
            frames: dataset.frames.len(),
            foreground_rays: totals.rays,
            dense_samples_per_ray: per_ray(totals.dense_samples),
            accelerated_samples_per_ray: per_ray(totals.acc_samples),
            capsule_samples_per_ray: per_ray(totals.capsule_samples),
            truncated_samples_per_ray: per_ray(totals.truncated_samples),
            dense_rays_per_s: totals.rays as f64 / totals.dense_s.max(1e-12),
            accelerated_rays_per_s: totals.rays as f64 / totals.acc_s.max(1e-12),
            bvh_intervals_rays_per_s: totals.rays as f64 / totals.intervals_s.max(1e-12),
            median_speed_ratio: median(&mut self.ratios),
            accelerated_build_share: totals.build_s / totals.acc_s.max(1e-12),
            surface_misses: self.part_misses.iter().sum(),
            surface_checked_rays: totals.checked,
            coverage_by_part: coverage_by_part(margins, &self.part_rays, &self.part_misses),
            accelerated_step_m: median(
                &mut self.steps.iter().map(|&s| s as f64).collect::<Vec<_>>(),
            ) as f32,
            surface_misses_by_split: self.split_misses,
            surface_misses_by_stage: self.stage_misses,
        }
    }
}

/// Per part: its rays, margin, training coverage before and after the margin, misses.
fn coverage_by_part(
    margins: &[SubjectMargins],
    part_rays: &[usize; 4],
    part_misses: &[usize; 4],
) -> BTreeMap<String, PartCoverage> {
    let mut coverage = BTreeMap::new();
    for (k, part) in Part::ALL.into_iter().enumerate() {
        let (rays, bare, fitted) = margins.iter().fold((0, 0, 0), |acc, m| {
            (
                acc.0 + m.coverage[k].0,
                acc.1 + m.coverage[k].1,
                acc.2 + m.coverage[k].2,
            )
        });
        let frac = |n: usize| {
            if rays == 0 {
                1.0
            } else {
                n as f64 / rays as f64
            }
        };
        coverage.insert(
            part.name().to_string(),
            PartCoverage {
                rays: part_rays[k],
                margin_m: margins
                    .iter()
                    .map(|m| m.part_margins.get(part))
                    .fold(0.0, f32::max),
                train_coverage_bare: frac(bare),
                train_coverage: frac(fitted),
                surface_misses: part_misses[k],
            },
        );
    }
    coverage
}

#[derive(Default)]
struct Totals {
    rays: usize,
    checked: usize,
    dense_samples: usize,
    acc_samples: usize,
    capsule_samples: usize,
    truncated_samples: usize,
    dense_s: f64,
    acc_s: f64,
    build_s: f64,
    intervals_s: f64,
}

/// Runs `f` `REPEATS` times; returns the last result and the median seconds.
fn median_time<T>(mut f: impl FnMut() -> T) -> (T, f64) {
    let mut times = Vec::with_capacity(REPEATS);
    let mut out = None;
    for _ in 0..REPEATS {
        let start = Instant::now();
        out = Some(f());
        times.push(start.elapsed().as_secs_f64());
    }
    (out.expect("REPEATS > 0"), median(&mut times))
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A human-readable table of a sampling report.
pub fn format_report(r: &SamplingReport) -> String {
    let mut s = String::new();
    use std::fmt::Write;
    let _ = writeln!(
        s,
        "{} frames, {} foreground rays, accelerated step {:.2} mm, {} grids",
        r.frames,
        r.foreground_rays,
        1e3 * r.accelerated_step_m,
        r.grids
    );
    let _ = writeln!(s, "{:<28} {:>14} {:>14}", "", "dense", "accelerated");
    let _ = writeln!(
        s,
        "{:<28} {:>14.1} {:>14.2}",
        "samples per foreground ray", r.dense_samples_per_ray, r.accelerated_samples_per_ray
    );
    let _ = writeln!(
        s,
        "{:<28} {:>14} {:>14.2}",
        "  in grown capsules", "", r.capsule_samples_per_ray
    );
    let _ = writeln!(
        s,
        "{:<28} {:>14} {:>14.2}",
        "  after core truncation", "", r.truncated_samples_per_ray
    );
    let _ = writeln!(
        s,
        "{:<28} {:>14.0} {:>14.0}",
        "rays per second", r.dense_rays_per_s, r.accelerated_rays_per_s
    );
    let _ = writeln!(
        s,
        "{:<28} {:>14} {:>14.0}",
        "  BVH intervals alone", "", r.bvh_intervals_rays_per_s
    );
    let _ = writeln!(
        s,
        "accelerated samples = {:.1}% of dense; speed ratio (median over frames) {:.2}x; \
         {:.0}% of the accelerated time builds the frames' structures",
        100.0 * r.accelerated_samples_per_ray / r.dense_samples_per_ray.max(1e-12),
        r.median_speed_ratio,
        100.0 * r.accelerated_build_share
    );
    let _ = writeln!(
        s,
        "surface misses: {} of {} rays checked against depth\n  by split: {:?}\n  by stage: {:?}",
        r.surface_misses,
        r.surface_checked_rays,
        r.surface_misses_by_split,
        r.surface_misses_by_stage
    );
    let _ = writeln!(
        s,
        "{:<8} {:>8} {:>10} {:>12} {:>12} {:>8}",
        "part", "rays", "margin mm", "bare cover", "fit cover", "misses"
    );
    for (name, p) in &r.coverage_by_part {
        let _ = writeln!(
            s,
            "{:<8} {:>8} {:>10.1} {:>11.2}% {:>11.2}% {:>8}",
            name,
            p.rays,
            1e3 * p.margin_m,
            100.0 * p.train_coverage_bare,
            100.0 * p.train_coverage,
            p.surface_misses
        );
    }
    s
}
