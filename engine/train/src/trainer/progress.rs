//! A run's progress and what it trains on: the one part of a trainer that a checkpoint's
//! `state.json` saves as it is (its serde names are that file's keys), so that a piece
//! of state added here is saved and resumed with no other change.

use serde::{Deserialize, Serialize};
use talkin_grids::SplitMix64;

use super::ScheduleAnchor;

/// Where a run is and what it draws from.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct RunProgress {
    /// Steps taken.
    pub step: usize,
    /// Training seconds so far.
    #[serde(rename = "elapsed_seconds")]
    pub elapsed: f64,
    /// The run's own draws (frames, patches, jitter, occupancy seeds).
    #[serde(rename = "rng_state", with = "rng_state")]
    pub rng: SplitMix64,
    /// Where the schedule was last re-anchored to a new budget (absent: never).
    #[serde(rename = "schedule_anchor", default)]
    pub anchor: Option<ScheduleAnchor>,
    /// The dataset frames trained on (a frame code each, in order).
    pub frames: Vec<usize>,
    /// Per dataset subject: its identity code and subject slot.
    pub slot_of: Vec<Option<usize>>,
}

impl RunProgress {
    /// A run about to take its first step.
    pub fn start(seed: u64, frames: Vec<usize>, slot_of: Vec<Option<usize>>) -> Self {
        RunProgress {
            step: 0,
            elapsed: 0.0,
            rng: SplitMix64::new(seed ^ 0x7A1C_11E5_EED5_0001),
            anchor: None,
            frames,
            slot_of,
        }
    }
}

/// The generator saved as its one word of state.
mod rng_state {
    use serde::{Deserialize, Deserializer, Serializer};
    use talkin_grids::SplitMix64;

    pub fn serialize<S: Serializer>(rng: &SplitMix64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u64(rng.state())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<SplitMix64, D::Error> {
        u64::deserialize(d).map(SplitMix64::from_state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saves_under_the_state_files_names_and_loads_back_the_same_draws() {
        let mut p = RunProgress::start(7, vec![0, 3], vec![Some(0), None]);
        p.step = 12;
        p.elapsed = 1.5;
        p.rng.next_u64();
        let json = serde_json::to_value(&p).unwrap();
        for key in ["step", "elapsed_seconds", "rng_state", "frames", "slot_of"] {
            assert!(json.get(key).is_some(), "{key} missing from {json}");
        }
        // A run that never re-anchored its schedule may lack the key.
        let mut older = json.clone();
        older.as_object_mut().unwrap().remove("schedule_anchor");
        let mut back: RunProgress = serde_json::from_value(older).unwrap();
        assert_eq!((back.step, back.elapsed), (12, 1.5));
        assert_eq!(back.rng.next_u64(), p.rng.next_u64());
    }
}
