//! Model-free early-warning indicators of critical slowing down, as in `ewstools`: as a system
//! approaches a bifurcation (here: damping through zero), its recovery from perturbations slows,
//! so the variance and the lag-1 autocorrelation of its (detrended) signal rise; Kendall's tau of
//! an indicator against time measures how steadily it rises.
//!
//! These are the baseline that `GateDampingDeclining` (built on the identified `zeta0` and its
//! interval, [`super::DampingTrend`]) is benchmarked against: they need no model, but they say
//! "something is changing", never "zeta0 will cross 0 in 4 minutes". Pure functions over slices;
//! they allocate only their output.
//!
//! ```
//! use gatewatch::analysis::{kendall_tau, lag1_autocorrelation, rolling, variance};
//! let x: Vec<f64> = (0..200).map(|i| (i as f64 * 0.3).sin() * (1.0 + i as f64 / 100.0)).collect();
//! let var = rolling(&x, 50, variance);
//! assert_eq!(var.len(), 200 - 50 + 1);
//! assert!(kendall_tau(&var).unwrap() > 0.5); // the amplitude grows: the variance rises
//! let ac = rolling(&x, 50, lag1_autocorrelation);
//! assert!(ac.iter().all(|a| a.is_nan() || a.abs() <= 1.0));
//! ```

use serde::Serialize;

/// The indicators of one series over rolling windows, and their Kendall tau against time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EwsIndicators {
    /// Rolling variance, one value per window position (window ending at sample `w - 1 + i`).
    pub variance: Vec<f64>,
    /// Rolling lag-1 autocorrelation, aligned with `variance`.
    pub autocorrelation: Vec<f64>,
    /// Kendall tau of the variance against time (`None`: fewer than 2 finite values).
    pub variance_tau: Option<f64>,
    /// Kendall tau of the autocorrelation against time.
    pub autocorrelation_tau: Option<f64>,
}

impl EwsIndicators {
    /// Both indicators over windows of `window` samples (clamped to 2..=len) of `x`, which the
    /// caller has detrended (ewstools subtracts a Gaussian or Lowess smoothing first).
    /// An empty or one-sample `x` gives empty indicators.
    pub fn compute(x: &[f64], window: usize) -> EwsIndicators {
        let variance = rolling(x, window, self::variance);
        let autocorrelation = rolling(x, window, lag1_autocorrelation);
        EwsIndicators {
            variance_tau: kendall_tau(&variance),
            autocorrelation_tau: kendall_tau(&autocorrelation),
            variance,
            autocorrelation,
        }
    }
}

/// `f` over every window of `window` samples (clamped to 2..=len) of `x`, oldest first:
/// `len - window + 1` values; empty when `x` has fewer than 2 samples.
pub fn rolling(x: &[f64], window: usize, f: impl Fn(&[f64]) -> f64) -> Vec<f64> {
    if x.len() < 2 {
        return Vec::new();
    }
    let w = window.clamp(2, x.len());
    x.windows(w).map(f).collect()
}

/// Sample variance (divisor `n - 1`); NaN with fewer than 2 samples.
pub fn variance(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return f64::NAN;
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)
}

/// Lag-1 autocorrelation (the estimator of `pandas.Series.autocorr(1)` used by ewstools: the
/// Pearson correlation of `x[..n-1]` with `x[1..]`); NaN with fewer than 3 samples or a
/// constant series.
pub fn lag1_autocorrelation(x: &[f64]) -> f64 {
    if x.len() < 3 {
        return f64::NAN;
    }
    let (a, b) = (&x[..x.len() - 1], &x[1..]);
    let m = a.len() as f64;
    let ma = a.iter().sum::<f64>() / m;
    let mb = b.iter().sum::<f64>() / m;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (u, v) in a.iter().zip(b) {
        sab += (u - ma) * (v - mb);
        saa += (u - ma).powi(2);
        sbb += (v - mb).powi(2);
    }
    let d = (saa * sbb).sqrt();
    if d > 0.0 {
        sab / d
    } else {
        f64::NAN
    }
}

/// Kendall's tau-b of the finite values of `y` against their position (time), as
/// `scipy.stats.kendalltau(range(n), y)`; `None` with fewer than 2 finite values or when all
/// are equal. O(n^2): indicator series are a few thousand values at most.
pub fn kendall_tau(y: &[f64]) -> Option<f64> {
    let pts: Vec<(usize, f64)> = y
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let (mut concordant, mut discordant, mut ties_y) = (0i64, 0i64, 0i64);
    for i in 0..pts.len() {
        for j in i + 1..pts.len() {
            // positions are distinct and increasing, so the sign is that of y's difference
            match pts[j].1.partial_cmp(&pts[i].1) {
                Some(std::cmp::Ordering::Greater) => concordant += 1,
                Some(std::cmp::Ordering::Less) => discordant += 1,
                _ => ties_y += 1,
            }
        }
    }
    let n0 = (concordant + discordant + ties_y) as f64;
    let denom = (n0 * (n0 - ties_y as f64)).sqrt();
    if denom > 0.0 {
        Some((concordant - discordant) as f64 / denom)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn known_values() {
        assert_relative_eq!(variance(&[1.0, 2.0, 3.0, 4.0]), 5.0 / 3.0);
        assert!(variance(&[1.0]).is_nan());
        // a straight line: successive values perfectly correlated
        assert_relative_eq!(lag1_autocorrelation(&[1.0, 2.0, 3.0, 4.0, 5.0]), 1.0);
        // alternating: perfectly anti-correlated
        assert_relative_eq!(lag1_autocorrelation(&[1.0, -1.0, 1.0, -1.0, 1.0]), -1.0);
        assert!(lag1_autocorrelation(&[2.0, 2.0, 2.0]).is_nan());
        assert_relative_eq!(kendall_tau(&[1.0, 2.0, 3.0]).unwrap(), 1.0);
        assert_relative_eq!(kendall_tau(&[3.0, 2.0, 1.0]).unwrap(), -1.0);
        // scipy.stats.kendalltau([0,1,2,3,4], [1,3,2,5,4]).statistic == 0.6
        assert_relative_eq!(kendall_tau(&[1.0, 3.0, 2.0, 5.0, 4.0]).unwrap(), 0.6);
        // NaN values are skipped; one finite value is not enough
        assert_relative_eq!(kendall_tau(&[1.0, f64::NAN, 2.0]).unwrap(), 1.0);
        assert_eq!(kendall_tau(&[f64::NAN, 1.0]), None);
        assert_eq!(kendall_tau(&[1.0, 1.0, 1.0]), None);
    }

    #[test]
    fn rolling_windows_are_clamped() {
        let x = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(rolling(&x, 2, |w| w[0]), vec![1.0, 2.0, 3.0]);
        assert_eq!(rolling(&x, 99, |w| w.len() as f64), vec![4.0]);
        assert_eq!(rolling(&x, 0, |w| w.len() as f64).len(), 3);
        assert!(rolling(&[1.0], 5, variance).is_empty());
    }

    #[test]
    fn slowing_down_raises_both_indicators() {
        // AR(1) noise whose coefficient rises from 0.1 to 0.9: slower recovery, larger variance
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let n = 4000;
        let mut x = Vec::with_capacity(n);
        let mut prev = 0.0;
        for i in 0..n {
            let phi = 0.1 + 0.8 * i as f64 / n as f64;
            prev = phi * prev + uniform();
            x.push(prev);
        }
        let ews = EwsIndicators::compute(&x, 500);
        assert!(ews.variance_tau.unwrap() > 0.8, "{:?}", ews.variance_tau);
        assert!(
            ews.autocorrelation_tau.unwrap() > 0.8,
            "{:?}",
            ews.autocorrelation_tau
        );
    }
}
