//! The plan: what a run builds, decided from the census of its training frames. Each
//! decision names the flag that sets it, the value the data calls for, the value the run
//! uses (the command line's where it named the flag) and its reason in one line. The plan
//! is recorded with the run's options, so a resumed run keeps the plan it started with.

pub mod record;
mod rules;

use talkin_data::census::Census;
use talkin_data::dataset::Dataset;

use crate::error::TrainError;
use crate::setup::training_frames;

use crate::recipe::TrainOptions;

pub use record::{Decision, Plan};
pub use rules::Thresholds;

/// A setting the plan decides: its flag, its clap id, and how to read and set it.
pub(crate) struct Setting {
    pub flag: &'static str,
    pub id: &'static str,
    pub get: fn(&TrainOptions) -> String,
    pub set: fn(&mut TrainOptions, &Choice),
}

/// What the rules chose for one setting.
pub(crate) enum Choice {
    Switch(bool),
    Count(usize),
    Fingers(crate::recipe::FingerSkinning),
}

impl Plan {
    /// Decides every setting of `opts` from `census`: where `named(id)` (the command line
    /// named the option) the option stays as given and the decision says so; elsewhere it
    /// takes the census' value. Returns the options with the plan recorded in them.
    pub fn apply(
        census: Census,
        mut opts: TrainOptions,
        named: impl Fn(&str) -> bool,
    ) -> TrainOptions {
        let mut decisions = Vec::new();
        // In order: a rule reads the options as the rules before it left them (finger
        // bones follow the hands' decision, the face's inputs the face's).
        for rule in rules::RULES {
            let Some((choice, reason)) = (rule.choose)(&census, &opts, &Thresholds::MEASURED)
            else {
                continue;
            };
            let setting = &rule.setting;
            let overridden = named(setting.id);
            let mut planned_opts = opts.clone();
            (setting.set)(&mut planned_opts, &choice);
            let planned = (setting.get)(&planned_opts);
            if !overridden {
                opts = planned_opts;
            }
            decisions.push(Decision {
                flag: setting.flag.to_string(),
                planned,
                used: (setting.get)(&opts),
                overridden,
                reason,
            });
        }
        opts.plan = Some(Plan { census, decisions });
        opts
    }

    /// The plan for a run of `opts` on `dataset`: the census of the frames it would
    /// train on (its subjects and clip), then [`Plan::apply`].
    pub fn for_run(
        dataset: &Dataset,
        opts: TrainOptions,
        named: impl Fn(&str) -> bool,
    ) -> Result<TrainOptions, TrainError> {
        let frames = training_frames(dataset, opts.identities.names(), opts.clip_seconds)?;
        let census = Census::of(dataset, &frames).map_err(TrainError::from)?;
        Ok(Plan::apply(census, opts, named))
    }
}

#[cfg(test)]
mod tests;
