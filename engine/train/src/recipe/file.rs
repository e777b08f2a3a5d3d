//! `RUN/recipe.json`: what a run was told, written when it starts and when a resume
//! re-anchors its schedule.

use std::path::Path;

use serde_json::{Value, json};
use talkin_nets::FieldConfig;

use super::{TrainOptions, record};
use crate::error::TrainError;
use crate::{loss, rays, schedule};

/// The recipe (options and the derived schedule) inside the run directory.
pub const RECIPE_FILE: &str = "recipe.json";

/// `RUN/recipe.json`: the options, the field config and the schedule they imply;
/// `extended` is where a resumed run's schedule was re-anchored to a new budget.
pub(crate) fn write_recipe(
    out: &Path,
    opts: &TrainOptions,
    config: &FieldConfig,
    extended: Option<Value>,
) -> Result<(), TrainError> {
    let path = out.join(RECIPE_FILE);
    let unserialisable = |problem: String| TrainError::Recipe {
        file: path.clone(),
        problem,
    };
    let loss = format!(
        "{}{}",
        if opts.perceptual_dir().is_some() {
            format!(
                "perceptual (LPIPS alex, else 1 - SSIM) on {} patch(es) of {p}x{p} + {} MSE + {} CE",
                opts.patches,
                loss::MSE_WEIGHT,
                loss::SEG_WEIGHT,
                p = rays::PATCH
            )
        } else {
            format!("MSE + {} CE (no perceptual term)", loss::SEG_WEIGHT)
        },
        if opts.mask_weight > 0.0 {
            format!(" + {} MSE(opacity, mask)", opts.mask_weight)
        } else {
            String::new()
        }
    );
    let mut schedule = json!({
        "virtual_iterations": schedule::PAPER_ITERATIONS,
        "lr_decay": format!("x0.1 per {} virtual iterations", schedule::LR_DECAY_ITERATIONS),
        "part_aware_rays": "virtual 0-20k: 20% hands; 20-40k: 20% hands + 60% arms; 40-60k: 40/40; 60-80k: 80/20; then 20% hands (of the in-box rays)",
        "non_rigid_start_step": config.non_rigid_start_step,
    });
    if let Some(extended) = extended {
        schedule["extended"] = extended;
    }
    let recipe = json!({
        "options": record::to_json(opts).map_err(unserialisable)?,
        "initial_lr": opts.initial_lr(),
        "loss": loss,
        "schedule": schedule,
        "field": serde_json::to_value(config).map_err(|e| unserialisable(e.to_string()))?,
    });
    let bytes = serde_json::to_vec_pretty(&recipe).map_err(|e| unserialisable(e.to_string()))?;
    talkin_data::atomic::write_atomic(&path, &bytes)
        .map_err(|source| TrainError::Io { file: path, source })
}
