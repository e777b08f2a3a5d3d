//! The property tests' configuration, one for every property test in the workspace (each
//! includes this file with `#[path]`): 64 cases and a fixed seed, so the same command runs
//! the same cases; proptest's own `PROPTEST_CASES` and `PROPTEST_RNG_SEED` override them
//! (`PROPTEST_CASES=20000` runs many more, docs/results.md).

use proptest::test_runner::{Config, RngSeed, contextualize_config};

/// 64 cases drawn from `seed` (one seed a test file), unless the environment says else.
pub fn config(seed: u64) -> Config {
    contextualize_config(Config {
        cases: 64,
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        ..Config::default()
    })
}
