//! Property tests that run the same cases every time: a fixed seed and no regression files
//! written, so a test passes or fails the same way on every machine. `PROPTEST_RNG_SEED` and
//! `PROPTEST_CASES` still explore other cases when set. Must never: write to the source tree.

use proptest::test_runner::{Config, RngSeed};

/// `cases` cases from the fixed `seed` (unless the environment asks for others), nothing
/// persisted, rejections unbounded (strategies that filter are judged by their cases).
pub fn proptest_config(seed: u64, cases: u32) -> Config {
    let base = Config::default();
    let rng_seed =
        if std::env::var_os("PROPTEST_RNG_SEED").is_some() { base.rng_seed } else { RngSeed::Fixed(seed) };
    let cases = if std::env::var_os("PROPTEST_CASES").is_some() { base.cases } else { cases };
    Config { cases, failure_persistence: None, rng_seed, max_local_rejects: u32::MAX, ..base }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_seed_and_count_are_the_ones_asked_for_and_nothing_is_persisted() {
        if std::env::var_os("PROPTEST_RNG_SEED").is_some() || std::env::var_os("PROPTEST_CASES").is_some() {
            return; // exploring on purpose
        }
        let c = proptest_config(7, 123);
        assert_eq!(c.cases, 123);
        assert!(matches!(c.rng_seed, RngSeed::Fixed(7)));
        assert!(c.failure_persistence.is_none());
    }
}
