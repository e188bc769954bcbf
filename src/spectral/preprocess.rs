//! Pre-processing of a window: moving-average and linear detrending, the Hann window, and the
//! damping ratio of an envelope growth rate.

use std::f64::consts::PI;

/// Writes `input` minus its centred moving average of `window` samples into `out`.
///
/// This is the chapter's only pre-processing: it removes offsets and slow drift while leaving an
/// oscillation whose period is well below the window (choose the window as several periods of
/// the gate's frequency; an average over a whole number of periods removes no oscillation at all).
///
/// The average at sample `i` is taken over `[i - h, i + h]` with `h = window / 2` (an even
/// `window` is therefore treated as `window + 1`). **Edges**: near the ends the window is
/// truncated to the samples that exist (a one-sided, shrinking average), so the output stays
/// defined everywhere; there the average lags a trend by up to `h/2` samples and includes a
/// partial period of the oscillation, so the first and last `h` samples are less reliable and
/// later stages discard edges anyway. `window <= 1` gives all zeros (each sample is its own
/// mean), so callers wanting no filtering should skip the call. Runs in `O(n)` with a running
/// sum, no allocation.
///
/// # Panics
/// If `out.len() != input.len()`.
pub fn remove_moving_average(input: &[f64], window: usize, out: &mut [f64]) {
    assert_eq!(input.len(), out.len(), "output length must match input");
    let n = input.len();
    if n == 0 {
        return;
    }
    let h = window / 2;
    // Running sum over [lo, hi] (inclusive), advanced as i moves.
    let mut lo = 0usize;
    let mut hi = 0usize;
    let mut sum = input[0];
    for i in 0..n {
        let want_lo = i.saturating_sub(h);
        let want_hi = (i + h).min(n - 1);
        while hi < want_hi {
            hi += 1;
            sum += input[hi];
        }
        while lo < want_lo {
            sum -= input[lo];
            lo += 1;
        }
        out[i] = input[i] - sum / (hi - lo + 1) as f64;
    }
}

/// Removes the least-squares straight line `a + b*i` from `x` in place; returns `(a, b)`
/// (intercept and slope per sample). No allocation.
pub fn detrend_linear(x: &mut [f64]) -> (f64, f64) {
    let n = x.len();
    if n == 0 {
        return (0.0, 0.0);
    }
    if n == 1 {
        let a = x[0];
        x[0] = 0.0;
        return (a, 0.0);
    }
    let nf = n as f64;
    let tm = (nf - 1.0) / 2.0;
    let xm = x.iter().sum::<f64>() / nf;
    let mut sxy = 0.0;
    let mut sxx = 0.0;
    for (i, &v) in x.iter().enumerate() {
        let d = i as f64 - tm;
        sxy += d * (v - xm);
        sxx += d * d;
    }
    let b = sxy / sxx;
    let a = xm - b * tm;
    for (i, v) in x.iter_mut().enumerate() {
        *v -= a + b * i as f64;
    }
    (a, b)
}

/// Fills `w` with the periodic ("DFT-even") Hann window `0.5 - 0.5 cos(2 pi i / n)`, the form
/// whose spectral kernel the 3-point interpolation of [`SpectralAnalyzer::dominant_frequency`](super::SpectralAnalyzer::dominant_frequency)
/// inverts exactly.
pub fn hann_into(w: &mut [f64]) {
    let n = w.len() as f64;
    for (i, v) in w.iter_mut().enumerate() {
        *v = 0.5 - 0.5 * (2.0 * PI * i as f64 / n).cos();
    }
}

/// The periodic Hann window of length `n` (see [`hann_into`]).
pub fn hann(n: usize) -> Vec<f64> {
    let mut w = vec![0.0; n];
    hann_into(&mut w);
    w
}

/// Damping ratio implied by an envelope growth rate `sigma` (1/s) at damped frequency
/// `frequency_hz`: the pole is `s = sigma + i omega_d`, so `zeta = -sigma / |s|`.
pub fn damping_from_growth(sigma: f64, frequency_hz: f64) -> f64 {
    let wd = 2.0 * PI * frequency_hz;
    -sigma / (sigma * sigma + wd * wd).sqrt()
}
