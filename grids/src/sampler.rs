//! Which sampler to use, by name.

use std::fmt;
use std::str::FromStr;

use crate::GridError;

/// The two samplers: `dense` (HumanNeRF's baseline, every speed/quality claim is made
/// against it) and `accelerated` (capsule intervals + occupancy culling).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SamplerKind {
    /// [`crate::sample_dense`].
    Dense,
    /// [`crate::AcceleratedSampler`] (what the engine runs); [`crate::sample_reference`] is
    /// the same pipeline over the BVH with a callback map, the plain reference.
    Accelerated,
}

impl SamplerKind {
    pub const ALL: [SamplerKind; 2] = [SamplerKind::Dense, SamplerKind::Accelerated];

    pub const fn name(self) -> &'static str {
        match self {
            SamplerKind::Dense => "dense",
            SamplerKind::Accelerated => "accelerated",
        }
    }
}

impl fmt::Display for SamplerKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SamplerKind {
    type Err = GridError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        SamplerKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| GridError::UnknownSampler(s.to_owned()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in SamplerKind::ALL {
            assert_eq!(k.to_string().parse::<SamplerKind>(), Ok(k));
        }
        assert_eq!("dense".parse(), Ok(SamplerKind::Dense));
        assert!("Dense ".parse::<SamplerKind>().is_err());
        assert!("fast".parse::<SamplerKind>().is_err());
    }
}
