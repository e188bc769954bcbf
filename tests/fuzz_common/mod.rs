//! The long fuzz runs shared by `tests/fuzz_*.rs` and `tests/model_fuzz.rs`.
//!
//! CI has stable Rust only (cargo-fuzz needs nightly), so the fuzz targets are proptest
//! properties: a short run in every `cargo test` (proptest's default case count, or
//! `PROPTEST_CASES`), and an ignored `fuzz_long_*` test per target that keeps drawing cases for
//! `FUZZ_SECONDS` (default 600) from a seeded generator, so a failure is reproducible:
//!
//! ```text
//! FUZZ_SECONDS=600 cargo test --release --test integration fuzz_ingest::fuzz_long -- --ignored --nocapture
//! ```

#![allow(dead_code)]

use std::time::{Duration, Instant};

use proptest::strategy::Strategy;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};

/// Runs `test` on values of `strategy` for `FUZZ_SECONDS` (default 600 s), in rounds of 10 000
/// cases, round `r` seeded with `r` (ChaCha): a failing round is replayed by its number.
/// Prints the cases run; panics with the shrunk failing input.
pub fn long_run<S: Strategy>(
    name: &str,
    strategy: S,
    test: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S::Value: std::fmt::Debug,
{
    let seconds: u64 = std::env::var("FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(600);
    let until = Instant::now() + Duration::from_secs(seconds);
    let began = Instant::now();
    let mut cases = 0u64;
    let mut round = 0u64;
    while Instant::now() < until {
        let mut seed = [0u8; 32];
        seed[..8].copy_from_slice(&round.to_le_bytes());
        let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &seed);
        let config = Config {
            cases: 10_000,
            failure_persistence: None,
            ..Config::default()
        };
        let mut runner = TestRunner::new_with_rng(config, rng);
        if let Err(e) = runner.run(&strategy, &test) {
            panic!("{name}: round {round} (seed {round}) failed: {e}");
        }
        cases += 10_000;
        round += 1;
    }
    println!(
        "{name}: {cases} cases in {:.0} s, no failure",
        began.elapsed().as_secs_f64()
    );
}
