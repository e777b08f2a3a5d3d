//! A run's budget and where it stands in the paper's schedule, including a budget changed
//! on resume: the schedule is re-anchored where it changes, so the virtual step never
//! goes back and reaches the paper's end when the new budget is spent.

use serde::{Deserialize, Serialize};

use super::Trainer;
use crate::error::TrainError;
use crate::recipe::write_recipe;
use crate::recipe::{Budget, TrainOptions};

/// The point a resumed run's budget changed at: from here the schedule's remaining
/// virtual iterations are spread over the rest of the new budget, so the virtual step
/// never jumps (see [`Trainer::set_budget`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScheduleAnchor {
    /// Steps taken when the budget changed.
    pub step: usize,
    /// Training seconds then.
    pub elapsed_seconds: f64,
    /// Schedule progress then, in [0, 1] (virtual step / 400k).
    pub schedule_progress: f64,
}

impl Trainer<'_> {
    /// Run progress in [0, 1] (steps or training seconds against the budget).
    pub fn progress(&self) -> f64 {
        let (done, total) = self.budget_position();
        (done / total).clamp(0.0, 1.0)
    }

    /// Steps or training seconds so far, and the budget's total, in the budget's unit.
    fn budget_position(&self) -> (f64, f64) {
        match self.opts.budget {
            Budget::Steps(n) => (self.progress.step as f64, n as f64),
            Budget::Seconds(s) => (self.progress.elapsed, s),
        }
    }

    /// Where the run is in the paper's schedule, in [0, 1]: the budget's progress, or,
    /// after a budget change, the anchor's position plus the new budget's remainder
    /// spread over the schedule's remainder.
    pub fn schedule_progress(&self) -> f64 {
        let Some(a) = self.progress.anchor else {
            return self.progress();
        };
        let (done, total) = self.budget_position();
        let start = match self.opts.budget {
            Budget::Steps(_) => a.step as f64,
            Budget::Seconds(_) => a.elapsed_seconds,
        };
        // A budget already spent at the anchor trains nothing and moves nothing.
        let f = if total > start {
            ((done - start) / (total - start)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        a.schedule_progress + f * (1.0 - a.schedule_progress)
    }

    /// Gives the run a new total budget (`Steps(80)` after 40 steps: 40 more). The
    /// schedule (see [`crate::schedule`]) is re-anchored here: the virtual step keeps its value
    /// and the remaining virtual iterations are spread over the rest of the new budget,
    /// so it never goes back (no learning-rate jump, no replayed ray phases) and always
    /// reaches the paper's end when the budget does. A finished run, being at the end,
    /// trains on at the schedule's final learning rate and ray mix. The same budget
    /// changes nothing (an interrupted run resumes exactly).
    pub fn set_budget(&mut self, budget: Budget) -> Result<(), TrainError> {
        TrainOptions {
            budget,
            ..self.opts.clone()
        }
        .check()?;
        if budget == self.opts.budget {
            return Ok(());
        }
        let anchor = ScheduleAnchor {
            step: self.progress.step,
            elapsed_seconds: self.progress.elapsed,
            schedule_progress: self.schedule_progress(),
        };
        self.progress.anchor = Some(anchor);
        self.opts.budget = budget;
        let extended = serde_json::to_value(anchor).map_err(|e| TrainError::Recipe {
            file: self.out.join(crate::recipe::RECIPE_FILE),
            problem: e.to_string(),
        })?;
        if !self.writes() {
            return Ok(());
        }
        write_recipe(&self.out, &self.opts, &self.config, Some(extended))
    }

    /// Whether the budget is spent.
    pub fn done(&self) -> bool {
        self.progress() >= 1.0
    }
}
