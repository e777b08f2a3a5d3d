//! Occupancy-grid updates from the field's density, in canonical space.

use burn::prelude::*;
use glam::Vec3;
use talkin_grids::OccUpdateOpts;
use talkin_nets::TalkinField;

use super::TrainError;
use crate::checkpoint::SubjectSlot;

/// nerfacc updates its grid every this many iterations, decaying occupancy by
/// `ema_decay` each time; the decay here is applied per this many *virtual* steps.
const NERFACC_UPDATE_EVERY: f64 = 16.0;

/// The EMA decay for one update of a subject whose previous update was
/// `virtual_steps_since` virtual steps ago: `ema_decay ^ (virtual_steps_since / 16)`, so
/// occupancy forgets at the rate nerfacc's does over the paper's 400k iterations whatever
/// the run's length. (A 0.95 decay per physical update never culled a cell in a
/// 10-minute run: a marked cell needs ~90 updates to fall below 0.01.)
pub(crate) fn virtual_time_decay(ema_decay: f32, virtual_steps_since: f64) -> f32 {
    let updates = (virtual_steps_since / NERFACC_UPDATE_EVERY).max(0.0);
    (f64::from(ema_decay).powf(updates) as f32).clamp(0.0, 1.0)
}

/// Updates one trained subject's grid (in turn) with the field's density at canonical points
/// (the max over body, face and hand nets, so a part another net renders is never
/// culled), times the cell size as nerfacc's `density * step`, without gradients. The
/// caller calls it when an update is due (`step` a multiple of `opts.n`).
/// `virtual_per_step` is the number of virtual steps one physical step stands for now.
/// Returns the occupied fraction of the updated subject's grid, if one was updated.
pub(crate) fn update_grids(
    field: &TalkinField,
    subjects: &mut [SubjectSlot],
    step: u32,
    virtual_per_step: f64,
    opts: &OccUpdateOpts,
    face_dim: usize,
) -> Result<Option<f64>, TrainError> {
    if opts.n == 0 {
        return Ok(None);
    }
    // One subject per update, in turn: an update evaluates every occupied cell and a
    // random quarter of the rest with every net (~250k points per subject at 128 cells),
    // which for all subjects at once cost ~15% of a run's time on 2 cores.
    let trained: Vec<usize> = (0..subjects.len())
        .filter(|&s| subjects[s].model.is_some())
        .collect();
    if trained.is_empty() {
        return Ok(None);
    }
    let turn = trained[(step / opts.n) as usize % trained.len()];
    // Each subject is updated every `n * trained` physical steps.
    let since = f64::from(opts.n) * trained.len() as f64 * virtual_per_step;
    let opts = OccUpdateOpts {
        ema_decay: virtual_time_decay(opts.ema_decay, since),
        ..*opts
    };
    let mut occupied = None;
    for (subject, slot) in subjects.iter_mut().enumerate() {
        if subject != turn {
            continue;
        }
        let name = slot.name.clone();
        let Some(model) = slot.model.as_mut() else {
            continue;
        };
        let scale = model.grid.cell_size().min_element();
        let density = |points: &[Vec3]| canonical_density(field, subject, points, scale, face_dim);
        model
            .grid
            .update(step, density, &opts)
            .map_err(|source| TrainError::Occupancy {
                subject: name,
                source,
            })?;
        occupied = Some(model.grid.num_occupied() as f64 / model.grid.num_cells() as f64);
    }
    Ok(occupied)
}

/// `max(sigma_body, sigma_face, sigma_hands) * scale` at canonical points of `subject`
/// (neutral expression and hand pose; no non-rigid offsets). Non-finite densities count
/// as occupied (never cull what cannot be judged).
fn canonical_density(
    field: &TalkinField,
    subject: usize,
    points: &[Vec3],
    scale: f32,
    face_dim: usize,
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
    let mut sigma = raw_sigma(field.body.forward(
        unit.clone(),
        subject,
        vec![id.clone()],
        usize::MAX,
    ));
    if let Some(face) = &field.face {
        let e = Tensor::<2>::zeros([n, face_dim], &device);
        let s = raw_sigma(face.forward(unit.clone(), subject, vec![e, id.clone()], usize::MAX));
        sigma = sigma.max_pair(s);
    }
    if let Some(hands) = &field.hands {
        let s = raw_sigma(hands.forward(unit, subject, vec![id], usize::MAX));
        sigma = sigma.max_pair(s);
    }
    // softplus after the max (monotone, so the same as the max of the densities).
    let relu = sigma.clone().clamp_min(0.0);
    let sigma = relu + sigma.abs().neg().exp().log1p();
    sigma
        .mul_scalar(scale)
        .try_to_vec_as::<f32>()
        .unwrap_or_else(|_| vec![f32::MAX; n])
        .into_iter()
        .map(|d| if d.is_finite() { d } else { f32::MAX })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decay_follows_virtual_time() {
        // At the paper's scale (one virtual step a step) 16 steps decay once.
        assert!((virtual_time_decay(0.95, 16.0) - 0.95).abs() < 1e-6);
        assert!((virtual_time_decay(0.95, 192.0) - 0.95f32.powi(12)).abs() < 1e-6);
        // A short run's update spans thousands of virtual steps: marks are forgotten.
        assert!(virtual_time_decay(0.95, 100_000.0) < 1e-6);
        assert_eq!(virtual_time_decay(0.95, 0.0), 1.0);
        assert_eq!(virtual_time_decay(0.95, -5.0), 1.0);
        assert_eq!(virtual_time_decay(0.95, f64::INFINITY), 0.0);
    }
}
