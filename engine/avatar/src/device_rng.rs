//! Turns at burn's random number generator. burn draws every random tensor (a field's
//! initial weights) from one RNG per process: burn-flex keeps it in a static, which
//! `Device::seed` replaces and every draw on any thread advances. A seeded draw gives the
//! same weights only if no other thread draws between the seed and the last draw, and
//! tests and benchmarks run trainers and renders side by side.
//!
//! [`DeviceRng`] is a turn at that RNG, taken once by whoever seeds or draws and handed
//! to the functions that draw ([`Checkpoint::field`](crate::checkpoint::Checkpoint::field)),
//! which never take one themselves: a caller already holding its turn cannot deadlock
//! them (taking the turn inside them once deadlocked every adaptation).

use std::sync::{Mutex, MutexGuard};

use burn::prelude::*;

/// A turn at burn's process-wide RNG, held until dropped; see the module docs.
pub struct DeviceRng {
    _turn: MutexGuard<'static, ()>,
}

impl DeviceRng {
    /// Waits until no one else holds a turn, then holds it. Never call it while holding
    /// one (a turn is not re-entrant): pass the one you hold instead.
    pub fn take_turn() -> DeviceRng {
        // One per process because burn's RNG is one per process.
        static TURN: Mutex<()> = Mutex::new(());
        DeviceRng {
            _turn: TURN.lock().unwrap_or_else(|e| e.into_inner()),
        }
    }

    /// Seeds `device`'s RNG: the draws made during this turn follow from `seed` alone.
    pub fn seed(&mut self, device: &Device, seed: u64) {
        device.seed(seed);
    }
}
