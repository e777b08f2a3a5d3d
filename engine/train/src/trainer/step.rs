//! One training step, in the order it runs: rays -> samples -> field and loss ->
//! optimizer -> grid update. Each stage is a method below [`Trainer::step`], which reads
//! as the list of them.

use std::borrow::Cow;
use std::time::Instant;

use burn::module::Module;
use burn::optim::GradientsParams;
use talkin_grids::{GridError, PackedSamples, SamplerKind};
use talkin_nets::field::FrameConditions;
use talkin_nets::profile;

use super::{StepMode, Trainer};
use crate::error::TrainError;
use crate::loss::{LossValues, StepBatch, StepLoss, loss_and_grads};
use crate::peers::{StepShare, share_of};
use crate::rays::{Batch, BatchSpec, CacheError, FrameCache, PATCH, draw_batch};
use crate::refine::chain::correction_gradient;
use crate::schedule;
use crate::step_log::StepLog;
use crate::step_log::pending::psnr;
use talkin_avatar::subject::{SubjectModel, SubjectSlot};
use talkin_data::dataset::Dataset;
use talkin_nets::PoseGrads;
use talkin_nets::skinning::skinned_candidates;

impl Trainer<'_> {
    /// One optimizer step (and, when due, an occupancy-grid update). Returns the log
    /// entries completed by it: on the CPU this step's; on a GPU, where the losses stay
    /// on the device, none, or every queued step's once 16 are queued (and
    /// any that a checkpoint read since the last call).
    pub fn step(&mut self) -> Result<Vec<StepLog>, TrainError> {
        let t0 = Instant::now();
        let vstep = match self.mode {
            StepMode::Train => self.field_step(),
            StepMode::FitPoses { field_step } => field_step,
        };
        let lr = schedule::learning_rate(self.opts.initial_lr(), vstep);

        // Rays: a seeded training frame (posed as its refined pose, when refining), its
        // LPIPS patches and part-aware pixels.
        let frame = profile::timed(
            "step (wall): the frame (a first visit builds its cache)",
            || self.pick_frame(),
        )?;
        self.follow_refined_pose(frame)?;
        let refining = self
            .refiner
            .as_ref()
            .is_some_and(|r| r.learning_at(self.progress.step));
        let mean_code = self.draws_mean_code();
        let mut batch = profile::timed("step (wall): rays", || self.draw_rays(frame, vstep))?;
        let background = self.step_background();
        if background != self.dataset.background {
            batch.recomposite(self.dataset.background, background);
        }

        // Samples along each ray, by the run's sampler (timed for the log).
        let sampling_start = Instant::now();
        let samples = self.draw_samples(frame, &batch)?;
        let sampling_took = sampling_start.elapsed();
        profile::record("step (wall): sampling", sampling_took);
        let sampling_s = sampling_took.as_secs_f64();
        let (n_rays, n_samples) = (batch.rays.len(), samples.num_samples());
        let bones_per_sample =
            mean_candidate_bones(&samples.bone_mask, self.config.skinning.skins_fingers());

        // Field and loss: forward, render, loss and backward (of this peer's share of the
        // rays, among peers), then the peers' sum: the whole batch's.
        let share = self.share_of(&batch);
        let field_start = Instant::now();
        let StepLoss {
            values,
            grads,
            pose,
        } = self.field_loss(
            &self.step_conditions(frame, mean_code),
            &batch,
            share,
            background,
            samples,
            vstep,
            refining,
        )?;
        profile::record(
            "step (wall): field, loss and gradients",
            field_start.elapsed(),
        );
        let (values, grads, pose) = self.exchange(frame, values, grads, pose, t0)?;
        if let LossValues::Read { loss, .. } = values
            && !loss.is_finite()
        {
            return Err(TrainError::NonFinite {
                step: self.progress.step + 1,
                loss,
            });
        }

        // Optimizer (and the frame's pose correction), then the grid update when due; a
        // pose fit moves the correction alone.
        let update_start = Instant::now();
        if self.mode == StepMode::Train {
            profile::timed("step (wall): Adam", || self.optimize(lr, grads));
        }
        self.refine_pose(frame, pose.as_ref());
        self.progress.step += 1;
        if self.mode == StepMode::Train {
            profile::timed("step (wall): occupancy grid update", || {
                self.update_grids_if_due()
            })?;
        }
        if let Some(link) = &mut self.peers {
            // What every peer repeats whatever its share: Adam and the grid updates.
            link.costs.update_s += update_start.elapsed().as_secs_f64();
            link.costs.sampling_s += sampling_s;
        }

        // On a GPU the step's queued ops go to the device now, without waiting for them:
        // fusion then cuts every step's ops at the same places and the same fused kernels
        // serve every step (left to fill its queue across steps, it cut them anywhere and
        // compiled new kernels for a minute: design.md, "Devices").
        if let LossValues::Queued(values) = &values {
            values.device().flush().map_err(|e| TrainError::Flush {
                step: self.progress.step,
                problem: format!("{e:?}"),
            })?;
        }

        profile::record("step (wall): whole step", t0.elapsed());
        let secs = t0.elapsed().as_secs_f64().max(1e-9);
        self.spend(secs);
        // A queued step's loss, MSE and PSNR are filled in when they are read.
        let mut entry = StepLog {
            step: self.progress.step,
            seconds: self.progress.elapsed,
            loss: f32::NAN,
            mse: f32::NAN,
            psnr: f32::NAN,
            rays: n_rays,
            samples: n_samples,
            rays_per_s: n_rays as f64 / secs,
            samples_per_s: n_samples as f64 / secs,
            lr,
            progress: self.progress(),
            grid_occupied: self.grids.occupied(),
            sampling_s,
            bones_per_sample,
        };
        match values {
            LossValues::Read { loss, mse } => {
                (entry.loss, entry.mse, entry.psnr) = (loss, mse, psnr(mse));
                self.journal.record(entry)
            }
            LossValues::Queued(values) => {
                let done = self.journal.queue(entry, secs, *values)?;
                // The read's wait for the device counts as training time.
                self.spend(done.waited_s);
                Ok(done.entries)
            }
        }
    }

    /// The log entries of every step taken and not yet returned by [`Trainer::step`]: the
    /// losses still on the device are read first (the wait counts as training time).
    pub fn settle(&mut self) -> Result<Vec<StepLog>, TrainError> {
        let done = self.journal.settle()?;
        self.spend(done.waited_s);
        Ok(done.entries)
    }

    /// A seeded training frame, cached with its decoded images and sampler on first use.
    fn pick_frame(&mut self) -> Result<usize, TrainError> {
        let n = self.progress.frames.len();
        // A pose fit visits its frames in turn, each as often.
        let k = match self.mode {
            StepMode::Train => self.progress.rng.below(n as u64) as usize,
            StepMode::FitPoses { .. } => self.progress.step % n,
        };
        let i = self.progress.frames[k];
        // A run's frame codes are its training frames', in order; the frames a pose fit
        // draws have none (the mean code, as renders use).
        let code = (self.mode == StepMode::Train && k < self.field().n_frame_codes()).then_some(k);
        // Only a frame's first draw builds its cache (the closure borrows the fields it
        // reads beside the caches it fills).
        let dataset = self.dataset;
        self.frame_caches.get_or_build(i, || {
            let (slot, model) = trained_subject(dataset, &self.progress.slot_of, &self.subjects, i);
            let mask_edge = self.opts.mask_edge_in(dataset, i);
            let fingers = self.config.skinning.skins_fingers();
            FrameCache::new(dataset, i, slot, model, mask_edge, fingers, code).map_err(
                |e| match e {
                    CacheError::Dataset(e) => TrainError::Dataset(e),
                    CacheError::Grid(source) => grid_error(dataset, i, source),
                },
            )
        })?;
        Ok(i)
    }

    /// Whether this step trains with the codes' mean instead of its frame's own code
    /// (`--frame-code-dropout`); the draw is taken only where the option is on, so runs
    /// without it keep their seeded stream.
    fn draws_mean_code(&mut self) -> bool {
        let p = self.opts.frame_code_dropout;
        self.mode == StepMode::Train
            && p > 0.0
            && self.field().n_frame_codes() > 0
            && self.progress.rng.next_f32() < p
    }

    /// The frame's conditions for this step: its own, or with `mean_code` the codes' mean
    /// in place of its code.
    fn step_conditions(&self, frame: usize, mean_code: bool) -> Cow<'_, FrameConditions> {
        let own = &self.frame_caches.get(frame).conditions;
        if mean_code {
            Cow::Owned(FrameConditions {
                frame_code: None,
                ..own.clone()
            })
        } else {
            Cow::Borrowed(own)
        }
    }

    /// The colour this step's targets and render are composited over: with
    /// `--random-background` on a dataset whose person can be shown over another colour
    /// (composited by its masks, or matted with coverage masks) a seeded random one (the
    /// field cannot then paint the background into the person's edge or hide a fog in
    /// front of it), else the dataset's.
    fn step_background(&mut self) -> [f32; 3] {
        if self.opts.random_background && self.dataset.can_show_over() {
            std::array::from_fn(|_| self.progress.rng.next_f32())
        } else {
            self.dataset.background
        }
    }

    /// The step's rays: LPIPS patches (when the perceptual term is on) and part-aware
    /// random pixels at the schedule's fractions for virtual step `vstep`.
    fn draw_rays(&mut self, frame: usize, vstep: usize) -> Result<Batch, TrainError> {
        let spec = BatchSpec {
            patches: if self.perceptual.is_some() {
                self.opts.patches
            } else {
                0
            },
            random_rays: self.opts.batch_rays,
            bbox_fraction: self.opts.bbox_fraction,
            parts: schedule::part_fractions(vstep),
        };
        draw_batch(
            self.dataset,
            frame,
            self.frame_caches.get(frame),
            &spec,
            &mut self.progress.rng,
        )
        .map_err(|source| grid_error(self.dataset, frame, source))
    }

    /// The samples along `batch`'s rays, with this step's seeded jitter.
    fn draw_samples(&self, frame: usize, batch: &Batch) -> Result<PackedSamples, TrainError> {
        let jitter_seed = self
            .opts
            .seed
            .wrapping_mul(0x9E37_79B9)
            .wrapping_add(self.progress.step as u64);
        let model = self.model_of(frame);
        self.frame_caches
            .get(frame)
            .sampler
            .sample(
                self.opts.sampler,
                &batch.rays,
                &model.grid,
                &model.dilated,
                Some(jitter_seed),
            )
            .map_err(|source| grid_error(self.dataset, frame, source))
    }

    /// Rebuilds frame `frame`'s conditions and sampler when its pose correction moved
    /// since they were built (refining runs only).
    fn follow_refined_pose(&mut self, frame: usize) -> Result<(), TrainError> {
        let Some(refiner) = &self.refiner else {
            return Ok(());
        };
        let Some(delta) = refiner.delta_of(frame) else {
            return Ok(());
        };
        let cache = self.frame_caches.get_mut(frame);
        let current = match &cache.posed_with {
            Some(d) => d.as_slice() == delta,
            None => delta.iter().all(|&d| d == 0.0),
        };
        if current {
            return Ok(());
        }
        let (slot, model) =
            trained_subject(self.dataset, &self.progress.slot_of, &self.subjects, frame);
        let params = refiner.params_of(self.dataset, frame);
        cache
            .repose(
                &params,
                delta,
                slot,
                model,
                self.config.skinning.skins_fingers(),
            )
            .map_err(|source| grid_error(self.dataset, frame, source))
    }

    /// Moves frame `frame`'s pose correction down the loss's gradient `pose` (w.r.t. the
    /// frame's skinning transforms and conditions, at its corrected pose; `None` during
    /// the warm-up), then by the prior and smoothness steps. Nothing without refinement.
    fn refine_pose(&mut self, frame: usize, pose: Option<&PoseGrads>) {
        let Some(delta) = self.refiner.as_ref().and_then(|r| r.delta_of(frame)) else {
            return;
        };
        let model = self.model_of(frame);
        let fit = &self.dataset.frames[frame].params;
        let g = pose.map(|p| correction_gradient(&model.skeleton, &model.canonical, fit, delta, p));
        if let Some(refiner) = self.refiner.as_mut() {
            refiner.update(frame, g.as_ref());
        }
    }

    /// The rays of `batch` this process computes: all of them alone, its share among
    /// peers.
    fn share_of(&self, batch: &Batch) -> std::ops::Range<usize> {
        let n = batch.rays.len();
        match &self.peers {
            None => 0..n,
            Some(link) => {
                let patch_rays = if self.perceptual.is_some() {
                    batch.patches * (PATCH * PATCH) as usize
                } else {
                    0
                };
                share_of(link.rank(), link.size(), n, patch_rays)
            }
        }
    }

    /// Among peers: sums this peer's loss, gradients and pose gradients with the others'
    /// (each then holds the whole batch's) and sets the run's clock to peer 0's. Alone:
    /// the step's own, unchanged.
    fn exchange(
        &mut self,
        frame: usize,
        values: LossValues,
        grads: GradientsParams,
        pose: Option<PoseGrads>,
        step_start: Instant,
    ) -> Result<(LossValues, GradientsParams, Option<PoseGrads>), TrainError> {
        let Some(link) = self.peers.as_mut() else {
            return Ok((values, grads, pose));
        };
        let (loss, mse) = match &values {
            LossValues::Read { loss, mse } => (*loss, *mse),
            LossValues::Queued(t) => {
                let v = t
                    .as_ref()
                    .clone()
                    .try_to_vec_as::<f32>()
                    .unwrap_or_default();
                (
                    v.first().copied().unwrap_or(f32::NAN),
                    v.get(1).copied().unwrap_or(f32::NAN),
                )
            }
        };
        let share = StepShare {
            step: self.progress.step + 1,
            loss,
            mse,
            clock: link.local_elapsed + step_start.elapsed().as_secs_f64(),
            agree: [
                frame as f32,
                // Occupied cells to 1/65536 of the grid: exact in an f32 sum.
                ((self.grids.occupied() * 65536.0).round() % 65536.0) as f32,
            ],
        };
        let field = self
            .field
            .as_ref()
            .expect("the field is back after every step");
        let out = link.exchange(field, grads, pose, share)?;
        self.progress.elapsed = out.clock;
        Ok((
            LossValues::Read {
                loss: out.loss,
                mse: out.mse,
            },
            out.grads,
            out.pose,
        ))
    }

    /// The field at the samples, rendered, scored against the batch's targets and
    /// differentiated ([`loss_and_grads`]); with `pose_grads`, w.r.t. the frame's pose
    /// too. `share`: the rays of the batch this process computes.
    fn field_loss(
        &self,
        conditions: &FrameConditions,
        batch: &Batch,
        share: std::ops::Range<usize>,
        background: [f32; 3],
        samples: PackedSamples,
        vstep: usize,
        pose_grads: bool,
    ) -> Result<StepLoss, TrainError> {
        loss_and_grads(
            self.field(),
            self.perceptual.as_ref(),
            StepBatch {
                rays: &batch.rays,
                share,
                samples,
                rgb: &batch.rgb,
                labels: &batch.labels,
                silhouette: &batch.silhouette,
                patches: batch.patches,
                patch_side: PATCH as usize,
                frame: conditions,
                step: vstep,
                background,
                mask_weight: self.opts.mask_weight,
                distortion: self.opts.distortion,
                hard_surface: self.opts.hard_surface,
                pose_grads,
            },
        )
        .map_err(|source| TrainError::Field { source })
    }

    /// Adam at learning rate `lr` (D_nr at `lr` times `--non-rigid-lr-scale`). The field
    /// is moved through the optimizer so that no other handle shares its buffers and Adam
    /// updates them in place.
    fn optimize(&mut self, lr: f64, mut grads: GradientsParams) {
        let field = self
            .field
            .take()
            .expect("the field is back after every step");
        let slow = match &field.non_rigid {
            Some(nr) if self.opts.non_rigid_lr_scale != 1.0 => take_grads(nr, &mut grads),
            _ => GradientsParams::new(),
        };
        let mut field = self.optim.step(lr, field, grads);
        if !slow.is_empty() {
            field = self
                .optim
                .step(lr * self.opts.non_rigid_lr_scale, field, slow);
        }
        self.field = Some(field);
    }

    /// Every `occ_every` steps (accelerated sampler only), one trained subject's
    /// occupancy grid, in turn, from the field's density.
    fn update_grids_if_due(&mut self) -> Result<(), TrainError> {
        if self.opts.sampler != SamplerKind::Accelerated || !self.grids.due(self.progress.step) {
            return Ok(());
        }
        let face_dim = self.config.expression_dim();
        let virtual_per_step = self.field_step() as f64 / self.progress.step as f64;
        let field = self.field().valid();
        self.grids.update(
            &field,
            &mut self.subjects,
            self.progress.step,
            virtual_per_step,
            face_dim,
        )
    }

    /// The model of the subject dataset frame `frame` shows.
    fn model_of(&self, frame: usize) -> &SubjectModel {
        trained_subject(self.dataset, &self.progress.slot_of, &self.subjects, frame).1
    }
}

/// The identity slot and model of the trained subject dataset frame `frame` shows (a
/// free function so that a caller may hold another part of the trainer meanwhile).
fn trained_subject<'s>(
    dataset: &Dataset,
    slot_of: &[Option<usize>],
    subjects: &'s [SubjectSlot],
    frame: usize,
) -> (usize, &'s SubjectModel) {
    let slot =
        slot_of[dataset.frames[frame].subject].expect("training frames belong to trained subjects");
    let model = subjects[slot]
        .model
        .as_ref()
        .expect("a trained subject has a model");
    (slot, model)
}

/// The mean number of bones inverse skinning evaluates per sample: each sample's
/// candidate joints mapped to their skinned joints (all 22 body joints for a dense
/// sample).
fn mean_candidate_bones(bone_masks: &[u64], finger_bones: bool) -> f64 {
    let total: u64 = bone_masks
        .iter()
        .map(|&m| u64::from(skinned_candidates(m, finger_bones).count_ones()))
        .sum();
    total as f64 / bone_masks.len().max(1) as f64
}

/// Moves `module`'s parameters' gradients out of `grads` into their own set.
fn take_grads<M: Module>(module: &M, grads: &mut GradientsParams) -> GradientsParams {
    struct Take<'a> {
        from: &'a mut GradientsParams,
        to: GradientsParams,
    }
    impl burn::module::ModuleVisitor for Take<'_> {
        fn visit_float<const D: usize>(
            &mut self,
            param: &burn::module::Param<burn::prelude::Tensor<D>>,
        ) {
            if let Some(g) = self.from.remove::<D>(param.id) {
                self.to.register::<D>(param.id, g);
            }
        }
    }
    let mut take = Take {
        from: grads,
        to: GradientsParams::new(),
    };
    module.visit(&mut take);
    take.to
}

/// A sampling error at dataset frame `frame`, naming the index file.
fn grid_error(dataset: &Dataset, frame: usize, source: GridError) -> TrainError {
    TrainError::Grid {
        file: dataset.root.join(talkin_data::dataset::INDEX_FILE),
        frame,
        source,
    }
}
