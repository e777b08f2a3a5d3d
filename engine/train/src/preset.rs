//! A preset names everything that changes together between the paper's networks and the
//! CPU-sized ones: the field's architecture, the initial learning rate, Adam's settings
//! and the learning-rate ratio of a novel-identity adaptation.

use serde::{Deserialize, Serialize};
use talkin_nets::FieldConfig;

/// The field and optimiser recipe of a run.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// Hash grid and 2x64 MLPs: the CPU default.
    #[default]
    Fast,
    /// The paper's sizes: positional encoding and 8x256 MLPs.
    Paper,
}

/// Adam's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamSettings {
    pub beta_1: f32,
    pub beta_2: f32,
    pub epsilon: f32,
}

/// The adaptation rate of the paper (1e-5 against its 5e-4 training rate): a new 32-d
/// code fed to shared MLPs, which only need nudging.
pub const PAPER_ADAPT_LR_RATIO: f64 = 1.0 / 50.0;

impl Preset {
    pub const ALL: [Preset; 2] = [Preset::Fast, Preset::Paper];

    /// The name on the command line and in `recipe.json`.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Fast => "fast",
            Preset::Paper => "paper",
        }
    }

    /// The field's architecture for `n_identities` subjects.
    pub fn field_config(self, n_identities: usize) -> FieldConfig {
        match self {
            Preset::Fast => FieldConfig::fast(n_identities),
            Preset::Paper => FieldConfig::paper(n_identities),
        }
    }

    /// Adam's initial learning rate: the paper's 5e-4 for `paper`; 1e-2 for `fast`,
    /// whose hash grid and small MLPs take a larger rate (1e-2 beat 5e-3 on every metric
    /// of the demo).
    pub fn learning_rate(self) -> f64 {
        match self {
            Preset::Fast => 1e-2,
            Preset::Paper => 5e-4,
        }
    }

    /// The paper's Adam (betas 0.9, 0.999, eps 1e-8) for `paper`; instant-ngp's (0.9,
    /// 0.99, 1e-15) for the hash-grid `fast` preset, whose sparse, tiny table gradients
    /// an eps of 1e-5 (burn's default) all but freezes.
    pub fn adam(self) -> AdamSettings {
        match self {
            Preset::Fast => AdamSettings {
                beta_1: 0.9,
                beta_2: 0.99,
                epsilon: 1e-15,
            },
            Preset::Paper => AdamSettings {
                beta_1: 0.9,
                beta_2: 0.999,
                epsilon: 1e-8,
            },
        }
    }

    /// A novel-identity adaptation's learning rate over the training rate: the paper's
    /// 1/50 for `paper`; 1 for `fast`, whose identity also lives in per-identity hash
    /// features that a novel subject must learn almost from nothing (at 1/50 of the rate,
    /// 1000 steps left it a fog: 14.8 dB against 22.8 at the full rate, 30-s clip).
    pub fn adapt_lr_ratio(self) -> f64 {
        match self {
            Preset::Fast => 1.0,
            Preset::Paper => PAPER_ADAPT_LR_RATIO,
        }
    }
}

impl std::fmt::Display for Preset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs written when the preset was a string resume with the same preset.
    #[test]
    fn names_are_the_recorded_strings() {
        for p in Preset::ALL {
            let json = serde_json::to_string(&p).unwrap();
            assert_eq!(json, format!("\"{}\"", p.name()));
            assert_eq!(serde_json::from_str::<Preset>(&json).unwrap(), p);
        }
        assert!(serde_json::from_str::<Preset>("\"slow\"").is_err());
    }

    #[test]
    fn the_paper_preset_is_the_papers_recipe() {
        let p = Preset::Paper;
        assert_eq!(p.learning_rate(), 5e-4);
        assert!((p.learning_rate() * p.adapt_lr_ratio() - 1e-5).abs() < 1e-18);
        assert_eq!(p.adam().beta_2, 0.999);
        assert_eq!(p.field_config(2).n_identities, 2);
    }
}
