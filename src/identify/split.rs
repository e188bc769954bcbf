//! The train/test split and the initial conditions taken from the data.

use super::IdentifyError;
use crate::data::TimeSeries;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Fewest training samples of a split.
const MIN_TRAIN: usize = 4;
/// Fewest test samples of a split.
const MIN_TEST: usize = 2;

/// Whether `n` samples split at `fraction` leave enough on both sides.
fn fits(n: usize, fraction: f64) -> bool {
    let n_train = ((n as f64) * fraction).round() as usize;
    n_train >= MIN_TRAIN && n.saturating_sub(n_train) >= MIN_TEST
}

/// The fewest samples [`split`] takes at `fraction`, above `n`. Searched, since rounding makes a
/// closed form fiddly, and bounded for absurd fractions.
fn needed_above(n: usize, fraction: f64) -> usize {
    const SEARCH_LIMIT: usize = 10_000_000;
    (n + 1..=SEARCH_LIMIT)
        .find(|&m| fits(m, fraction))
        .unwrap_or(SEARCH_LIMIT)
}

/// The fewest samples [`split`] accepts at `fraction` (7 at one half), so a command can refuse
/// a short file by its own words before the analysis starts.
pub fn min_samples(fraction: f64) -> usize {
    needed_above(0, fraction)
}

/// A seeded random split: `round(n * fraction)` training indices, the rest for testing, both
/// sorted.
pub fn split(
    n: usize,
    fraction: f64,
    seed: u64,
) -> Result<(Vec<usize>, Vec<usize>), IdentifyError> {
    if !fits(n, fraction) {
        return Err(IdentifyError::TooFewSamples {
            samples: n,
            needed: needed_above(n, fraction),
            train: MIN_TRAIN,
            test: MIN_TEST,
        });
    }
    let n_train = ((n as f64) * fraction).round() as usize;
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    let mut train = idx[..n_train].to_vec();
    let mut test = idx[n_train..].to_vec();
    train.sort_unstable();
    test.sort_unstable();
    Ok((train, test))
}

/// `y0` = first sample; `v0` = slope at `t0` of the least-squares quadratic through the first
/// samples (up to 7), which tolerates mild noise better than a two-point difference.
pub fn initial_from_data(s: &TimeSeries) -> (f64, f64) {
    let m = s.len().min(7);
    if m < 2 {
        return (s.y.first().copied().unwrap_or(0.0), 0.0);
    }
    if m == 2 {
        return (s.y[0], (s.y[1] - s.y[0]) / (s.t[1] - s.t[0]));
    }
    // Fit y = a + b*dt + c*dt^2 with dt = t - t0; v0 = b.
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for i in 0..m {
        let dt = s.t[i] - s.t[0];
        let row = nalgebra::Vector3::new(1.0, dt, dt * dt);
        a += row * row.transpose();
        rhs += row * s.y[i];
    }
    match a.lu().solve(&rhs) {
        Some(sol) => (s.y[0], sol[1]),
        None => (s.y[0], (s.y[1] - s.y[0]) / (s.t[1] - s.t[0])),
    }
}
