//! Occupancy-grid updates from the field's density, in canonical space.

use burn::prelude::*;
use glam::Vec3;
use talkin_avatar::subject::SubjectSlot;
use talkin_grids::OccUpdateOpts;
use talkin_nets::TalkinField;
use talkin_nets::field::{N_SEG_CLASSES, SEG_HANDS, SEG_HEAD, argmax_rows};

use crate::error::TrainError;

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

/// A run's occupancy-grid updates: their options, and the occupied fraction of the grid
/// updated last (for the log; 1 before the first update).
pub(crate) struct GridUpdates {
    opts: OccUpdateOpts,
    occupied: f64,
}

impl GridUpdates {
    pub fn new(opts: OccUpdateOpts) -> Self {
        GridUpdates {
            opts,
            occupied: 1.0,
        }
    }

    /// The occupied fraction of the grid updated last.
    pub fn occupied(&self) -> f64 {
        self.occupied
    }

    /// Whether an update is due after physical step `step`.
    pub fn due(&self, step: usize) -> bool {
        self.opts.n > 0 && step.is_multiple_of(self.opts.n as usize)
    }

    /// The due update after physical step `step` ([`update_grids`]).
    pub fn update(
        &mut self,
        field: &TalkinField,
        subjects: &mut [SubjectSlot],
        step: usize,
        virtual_per_step: f64,
        face_dim: usize,
    ) -> Result<(), TrainError> {
        if let Some(occupied) = update_grids(
            field,
            subjects,
            step as u32,
            virtual_per_step,
            &self.opts,
            face_dim,
        )? {
            self.occupied = occupied;
        }
        Ok(())
    }
}

/// Updates one trained subject's grid (in turn) with the field's density at canonical points
/// as the renderer routes it ([`route_density`]), times the cell size as nerfacc's
/// `density * step`, without gradients. The
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

/// The density the renderer would give canonical points of `subject` (neutral
/// expression and hand pose; no non-rigid offsets), times `scale` as nerfacc's
/// `density * step`: F_body's, and where F_body's segmentation routes a point to the face
/// or the hands, the larger of F_body's and that net's (the renderer uses the routed
/// net's where the point is a candidate of that part, F_body's elsewhere). The face and
/// hand nets are never trained outside their regions, so their density there says
/// nothing; taking it everywhere (as this once did) kept every cell occupied: an
/// untrained net's softplus(0) times a 14 mm cell is just above nerfacc's 0.01.
/// Non-finite densities count as occupied (never cull what cannot be judged).
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
    let id = field.identity.val().select(
        0,
        Tensor::<1, Int>::from_data(TensorData::new(vec![subject as i32], [1]), &device),
    ); // [1, id]
    let host = |t: Tensor<2>| talkin_nets::read_floats(t).ok();
    let body = field.body.forward(
        unit.clone(),
        subject,
        field.body_condition_unseen(id.clone()),
        usize::MAX,
    );
    let (Some(body_sigma), Some(seg)) = (
        host(body.clone().narrow(1, 0, 1)),
        host(body.narrow(1, 4, N_SEG_CLASSES)),
    ) else {
        return vec![f32::MAX; n];
    };
    let routed_sigma = |net: &talkin_nets::field::RadianceNet, rows: &[usize], face: bool| {
        let idx = Tensor::<1, Int>::from_data(
            TensorData::new(rows.iter().map(|&i| i as i32).collect(), [rows.len()]),
            &device,
        );
        let cond = if face && face_dim > 0 {
            Tensor::cat(
                vec![Tensor::<2>::zeros([1, face_dim], &device), id.clone()],
                1,
            )
        } else {
            id.clone()
        };
        let raw = net.forward(unit.clone().select(0, idx), subject, cond, usize::MAX);
        host(raw.narrow(1, 0, 1)).unwrap_or_else(|| vec![f32::MAX; rows.len()])
    };
    let raw = route_density(
        &body_sigma,
        &seg,
        |rows| field.face.as_ref().map(|net| routed_sigma(net, rows, true)),
        |rows| {
            field
                .hands
                .as_ref()
                .map(|net| routed_sigma(net, rows, false))
        },
    );
    let density = field.density();
    raw.into_iter()
        .map(|r| {
            // Monotone, so after the max as well as before.
            let d = density.of(r) * scale;
            if d.is_finite() { d } else { f32::MAX }
        })
        .collect()
}

/// Raw densities routed as the renderer routes them: `body` (one per point), replaced by
/// the max of itself and `face(rows)` / `hands(rows)` at the rows whose segmentation
/// logits (`seg`, [`N_SEG_CLASSES`] per point) pick the head / the hands. A net that does
/// not exist returns `None` and leaves F_body's density.
pub(crate) fn route_density(
    body: &[f32],
    seg: &[f32],
    face: impl FnOnce(&[usize]) -> Option<Vec<f32>>,
    hands: impl FnOnce(&[usize]) -> Option<Vec<f32>>,
) -> Vec<f32> {
    let labels = argmax_rows(seg, N_SEG_CLASSES);
    let mut out = body.to_vec();
    let rows_of =
        |class: usize| -> Vec<usize> { (0..body.len()).filter(|&i| labels[i] == class).collect() };
    let face_rows = rows_of(SEG_HEAD);
    let hand_rows = rows_of(SEG_HANDS);
    for (rows, sigma) in [
        (
            &face_rows,
            (!face_rows.is_empty()).then(|| face(&face_rows)).flatten(),
        ),
        (
            &hand_rows,
            (!hand_rows.is_empty()).then(|| hands(&hand_rows)).flatten(),
        ),
    ] {
        if let Some(sigma) = sigma {
            for (&i, &s) in rows.iter().zip(&sigma) {
                // NaN from a net keeps the point (f32::max would drop it).
                out[i] = if s.is_nan() { f32::MAX } else { out[i].max(s) };
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn density_is_routed_as_the_renderer_routes_it() {
        // Four points labelled background, body, hands, head (logits: one-hot-ish).
        let mut seg = vec![0.0f32; 4 * N_SEG_CLASSES];
        for (i, class) in [0, 1, SEG_HANDS, SEG_HEAD].into_iter().enumerate() {
            seg[i * N_SEG_CLASSES + class] = 5.0;
        }
        let body = [-3.0, 2.0, -1.0, -2.0];
        let asked = std::cell::RefCell::new(Vec::new());
        let out = route_density(
            &body,
            &seg,
            |rows| {
                asked.borrow_mut().push(("face", rows.to_vec()));
                Some(vec![7.0])
            },
            |rows| {
                asked.borrow_mut().push(("hands", rows.to_vec()));
                Some(vec![-4.0])
            },
        );
        let asked = asked.into_inner();
        // The face net speaks only for the head point, the hands net only for the hand
        // point (and a lower density there never lowers F_body's).
        assert_eq!(out, vec![-3.0, 2.0, -1.0, 7.0]);
        assert_eq!(asked, vec![("face", vec![3]), ("hands", vec![2])]);
        // No nets: F_body's density throughout; NaN from a net keeps the point.
        assert_eq!(
            route_density(&body, &seg, |_| None, |_| None),
            body.to_vec()
        );
        let nan = route_density(&body, &seg, |_| Some(vec![f32::NAN]), |_| None);
        assert_eq!(nan[3], f32::MAX);
    }

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
