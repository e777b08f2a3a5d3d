//! Damage to a valid file for the property tests (each includes this file with
//! `#[path]`): bytes flipped, bytes spliced in, and a cut.

use proptest::prelude::*;

/// Damage to a valid file: bytes flipped, bytes spliced in, and a cut.
#[derive(Clone, Debug)]
pub struct Damage {
    flips: Vec<(prop::sample::Index, u8)>,
    splice: Option<(prop::sample::Index, Vec<u8>)>,
    cut: Option<prop::sample::Index>,
}

pub fn damage() -> impl Strategy<Value = Damage> {
    (
        prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..8),
        prop::option::of((
            any::<prop::sample::Index>(),
            prop::collection::vec(any::<u8>(), 1..16),
        )),
        prop::option::weighted(0.3, any::<prop::sample::Index>()),
    )
        .prop_map(|(flips, splice, cut)| Damage { flips, splice, cut })
}

impl Damage {
    pub fn apply(&self, mut bytes: Vec<u8>) -> Vec<u8> {
        for (at, byte) in &self.flips {
            let i = at.index(bytes.len());
            bytes[i] ^= byte;
        }
        if let Some((at, spliced)) = &self.splice {
            let i = at.index(bytes.len() + 1);
            bytes.splice(i..i, spliced.iter().copied());
        }
        if let Some(cut) = &self.cut {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        bytes
    }
}
