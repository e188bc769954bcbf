//! Model-free signal analysis of a gate window: pre-processing, dominant frequency, Hilbert
//! envelope growth rate, ambient (noise-driven) damping from an AR model, and a classification of
//! the window as self-excited or damped.
//!
//! These figures need no equation of motion; the analysis uses them to check the identified model
//! and as a fallback verdict. Everything here is plain numerics (no async, no metrics).
//!
//! # Pieces
//! - [`remove_moving_average`], [`detrend_linear`], [`hann_into`]: pre-processing.
//! - [`SpectralAnalyzer`]: FFTs planned once per window length, with reused buffers;
//!   [`SpectralAnalyzer::dominant_frequency`] (Hann window + exact 3-point Hann interpolation),
//!   [`SpectralAnalyzer::envelope`] (analytic signal by FFT) and
//!   [`SpectralAnalyzer::growth_rate`] (least-squares slope of the log envelope).
//! - [`ambient_damping`]: AR(p) least squares, pole to damping ratio, delta-method interval.
//! - [`random_decrement`], [`random_decrement_damping`]: the random decrement technique.
//! - [`classify`] and [`SpectralAnalyzer::analyze_window`]: the building blocks put together.

use nalgebra::{DMatrix, DVector};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::f64::consts::PI;
use std::sync::Arc;

/// Why a spectral computation could not be done.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpectralError {
    /// The slice length differs from the analyzer's planned length.
    #[error("signal has {got} samples, the analyzer was planned for {expected}")]
    Length {
        /// Planned length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// Too few samples for the requested computation.
    #[error("too short: {0}")]
    TooShort(String),
    /// NaN or infinite samples.
    #[error("signal contains non-finite values")]
    NonFinite,
    /// Nothing usable in the signal (constant, no peak above the floor, no oscillatory pole...).
    #[error("no result: {0}")]
    NoResult(String),
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    Invalid(String),
}

// ---------------------------------------------------------------------------------------------
// Pre-processing
// ---------------------------------------------------------------------------------------------

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
/// whose spectral kernel the 3-point interpolation of [`SpectralAnalyzer::dominant_frequency`]
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

fn check_finite(x: &[f64]) -> Result<(), SpectralError> {
    if x.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SpectralError::NonFinite)
    }
}

// ---------------------------------------------------------------------------------------------
// Spectrum: dominant frequency, envelope, growth rate
// ---------------------------------------------------------------------------------------------

/// The dominant spectral peak.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// Frequency, Hz.
    pub frequency_hz: f64,
    /// Amplitude of the equivalent sinusoid, signal units (exact for a stationary sinusoid).
    pub amplitude: f64,
    /// Fractional bin index of the peak.
    pub bin: f64,
}

/// Options of [`SpectralAnalyzer::growth_rate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrowthOptions {
    /// Fraction of the window discarded at each end (Hilbert end effects).
    pub edge_fraction: f64,
    /// Minimum number of periods of the frequency discarded at each end.
    pub edge_periods: f64,
    /// Half-width of the band kept around the frequency in the analytic signal, as a fraction
    /// of the frequency (`0.5`: keep `[0.5 f, 1.5 f]`); `None` keeps all positive frequencies.
    /// The band-pass removes noise and, more importantly, the broadband content of the wrap-around
    /// jump of a growing or decaying signal, which otherwise pollutes the envelope.
    pub band_fraction: Option<f64>,
}

impl Default for GrowthOptions {
    fn default() -> Self {
        GrowthOptions {
            edge_fraction: 0.1,
            edge_periods: 3.0,
            band_fraction: Some(0.5),
        }
    }
}

/// Envelope growth rate of a window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrowthRate {
    /// Growth rate `sigma` of the envelope, 1/s (negative: decaying).
    pub sigma: f64,
    /// Standard error of `sigma`: the least-squares one inflated for the serial correlation of
    /// the log-envelope residuals (AR(1) effective sample size). Approximate.
    pub stderr: f64,
    /// Frequency used, Hz.
    pub frequency_hz: f64,
    /// Implied damping ratio `-sigma / sqrt(sigma^2 + (2 pi f)^2)`.
    pub zeta: f64,
    /// Coefficient of variation (std / mean) of the envelope after dividing out the fitted
    /// exponential, over the fitted span. A narrow-band Gaussian (noise-driven, linear) response
    /// has a Rayleigh envelope, CV `sqrt(4/pi - 1) = 0.52`; a limit cycle has a nearly constant
    /// one, CV well below that.
    pub envelope_cv: f64,
    /// First sample used in the fit.
    pub start: usize,
    /// One past the last sample used in the fit.
    pub end: usize,
}

/// FFT-based analysis of windows of one fixed length.
///
/// The forward and inverse FFTs are planned once in [`SpectralAnalyzer::new`]; the complex
/// buffer, FFT scratch, window, magnitude and envelope buffers are allocated there and reused, so
/// the methods (which take `&mut self`) allocate nothing. Keep one analyzer per window length
/// (per gate or per worker thread).
pub struct SpectralAnalyzer {
    n: usize,
    rate_hz: f64,
    /// Forward FFT of length `n` (spectrum).
    fwd: Arc<dyn Fft<f64>>,
    /// Forward and inverse FFTs of length `2n` (zero-padded analytic signal).
    fwd2: Arc<dyn Fft<f64>>,
    inv2: Arc<dyn Fft<f64>>,
    window: Vec<f64>,
    buf: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    mag: Vec<f64>,
    env: Vec<f64>,
    work: Vec<f64>,
}

impl std::fmt::Debug for SpectralAnalyzer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpectralAnalyzer")
            .field("n", &self.n)
            .field("rate_hz", &self.rate_hz)
            .finish_non_exhaustive()
    }
}

impl SpectralAnalyzer {
    /// Plans the FFTs for windows of `n` samples at `rate_hz`. `n >= 16`.
    pub fn new(n: usize, rate_hz: f64) -> Result<SpectralAnalyzer, SpectralError> {
        if n < 16 {
            return Err(SpectralError::TooShort(format!(
                "window of {n} samples (need at least 16)"
            )));
        }
        if !(rate_hz > 0.0 && rate_hz.is_finite()) {
            return Err(SpectralError::Invalid(format!("sample rate {rate_hz}")));
        }
        let mut planner = FftPlanner::new();
        let fwd = planner.plan_fft_forward(n);
        let fwd2 = planner.plan_fft_forward(2 * n);
        let inv2 = planner.plan_fft_inverse(2 * n);
        let scratch_len = fwd
            .get_inplace_scratch_len()
            .max(fwd2.get_inplace_scratch_len())
            .max(inv2.get_inplace_scratch_len());
        Ok(SpectralAnalyzer {
            n,
            rate_hz,
            fwd,
            fwd2,
            inv2,
            window: hann(n),
            buf: vec![Complex::new(0.0, 0.0); 2 * n],
            scratch: vec![Complex::new(0.0, 0.0); scratch_len],
            mag: vec![0.0; n / 2 + 1],
            env: vec![0.0; n],
            work: vec![0.0; n],
        })
    }

    /// Planned window length, samples.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Always false (an analyzer has at least 16 samples); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Sample rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Bin spacing `rate_hz / n`, Hz.
    pub fn bin_hz(&self) -> f64 {
        self.rate_hz / self.n as f64
    }

    fn check(&self, x: &[f64]) -> Result<(), SpectralError> {
        if x.len() != self.n {
            return Err(SpectralError::Length {
                expected: self.n,
                got: x.len(),
            });
        }
        check_finite(x)
    }

    /// One-sided magnitude spectrum of the last [`Self::dominant_frequency`] call (bins
    /// `0..=n/2`, Hann-windowed, mean removed).
    pub fn magnitude(&self) -> &[f64] {
        &self.mag
    }

    /// The dominant frequency of `x`: the largest bin of the Hann-windowed magnitude spectrum
    /// (mean removed first) strictly above DC and at or above `min_freq_hz`, refined to sub-bin
    /// accuracy.
    ///
    /// Refinement: for the periodic Hann window the magnitudes of a pure tone at fractional
    /// offset `d` from bin `k` satisfy exactly
    /// `d = 2 (|X[k+1]| - |X[k-1]|) / (|X[k-1]| + 2 |X[k]| + |X[k+1]|)`, and the amplitude is
    /// `4 |X[k]| / n * (1 - d^2) / sinc(d)`. The only errors are leakage from the negative-
    /// frequency image (the Hann sidelobes fall as `1/bin^3`, so it is negligible a few bins away
    /// from DC and Nyquist), from other components and from noise. The peak must have both
    /// neighbours, so the highest usable bin is `n/2 - 1`.
    pub fn dominant_frequency(
        &mut self,
        x: &[f64],
        min_freq_hz: f64,
    ) -> Result<Peak, SpectralError> {
        self.check(x)?;
        let n = self.n;
        let mean = x.iter().sum::<f64>() / n as f64;
        let buf = &mut self.buf[..n];
        for ((b, &v), &w) in buf.iter_mut().zip(x).zip(&self.window) {
            *b = Complex::new((v - mean) * w, 0.0);
        }
        self.fwd.process_with_scratch(buf, &mut self.scratch);
        for (m, b) in self.mag.iter_mut().zip(&self.buf) {
            *m = b.norm();
        }
        let k_lo = ((min_freq_hz / self.bin_hz()).ceil() as usize).max(1);
        let k_hi = n / 2 - 1;
        if k_lo > k_hi {
            return Err(SpectralError::Invalid(format!(
                "frequency floor {min_freq_hz} Hz leaves no bins"
            )));
        }
        let mut k = k_lo;
        for j in k_lo..=k_hi {
            if self.mag[j] > self.mag[k] {
                k = j;
            }
        }
        let (a, b, c) = (self.mag[k - 1], self.mag[k], self.mag[k + 1]);
        if b <= 0.0 {
            return Err(SpectralError::NoResult("flat (zero) spectrum".into()));
        }
        let d = (2.0 * (c - a) / (a + 2.0 * b + c)).clamp(-0.99, 0.99);
        let sinc = if d.abs() < 1e-12 {
            1.0
        } else {
            (PI * d).sin() / (PI * d)
        };
        let amplitude = 4.0 * b / n as f64 * (1.0 - d * d) / sinc;
        let bin = k as f64 + d;
        Ok(Peak {
            frequency_hz: bin * self.bin_hz(),
            amplitude,
            bin,
        })
    }

    /// Amplitude envelope `|x + i H[x]|` of `x` from the analytic signal computed by FFT: `x` is
    /// zero-padded to `2n`, the spectrum's negative frequencies are zeroed and the positive ones
    /// doubled (DC and Nyquist kept once), and the magnitude of the inverse FFT's first `n`
    /// samples is returned (a view of an internal buffer).
    ///
    /// Zero padding stops the FFT's periodic wrap-around from coupling the two ends of the window
    /// (a growing signal would otherwise see its large end next to its small start); each end
    /// still has its own truncation effect ("Hilbert end effects"), so discard a few periods
    /// there. With `band = Some((lo, hi))` the positive frequencies are weighted by a Tukey
    /// (tapered-cosine) band: 1 over the central half of `[lo, hi]`, cosine tapers to 0 over the
    /// outer quarters, 0 outside. The band removes offsets, drift and out-of-band noise, and its
    /// smooth edges confine the end effects to about `2 / (hi - lo)` seconds, where an ideal
    /// band-pass would ring over the whole window. Without a band the end error decays only like
    /// `1 / (omega t)` from each end.
    pub fn envelope(
        &mut self,
        x: &[f64],
        band: Option<(f64, f64)>,
    ) -> Result<&[f64], SpectralError> {
        self.check(x)?;
        let n = self.n;
        let m = 2 * n;
        for (i, b) in self.buf.iter_mut().enumerate() {
            *b = Complex::new(if i < n { x[i] } else { 0.0 }, 0.0);
        }
        self.fwd2
            .process_with_scratch(&mut self.buf, &mut self.scratch);
        let df = self.rate_hz / m as f64;
        let half = m / 2;
        let (centre, half_width) = match band {
            Some((lo, hi)) => (0.5 * (lo + hi), 0.5 * (hi - lo).max(0.0)),
            None => (0.0, f64::INFINITY),
        };
        for (k, b) in self.buf.iter_mut().enumerate() {
            let gain = if k == 0 || k == half {
                1.0
            } else if k < half {
                2.0
            } else {
                0.0
            };
            let weight = if band.is_some() && gain > 0.0 {
                let d = (k as f64 * df - centre).abs();
                if d <= 0.5 * half_width {
                    1.0
                } else if d < half_width {
                    0.5 * (1.0 + (PI * (d - 0.5 * half_width) / (0.5 * half_width)).cos())
                } else {
                    0.0
                }
            } else {
                1.0
            };
            *b *= gain * weight;
        }
        self.inv2
            .process_with_scratch(&mut self.buf, &mut self.scratch);
        let scale = 1.0 / m as f64;
        for (e, b) in self.env.iter_mut().zip(&self.buf[..n]) {
            *e = b.norm() * scale;
        }
        Ok(&self.env)
    }

    /// Envelope growth rate of `x` oscillating at `frequency_hz`: least-squares slope of
    /// `ln(envelope)` against time over the window minus `max(edge_fraction * n,
    /// edge_periods / frequency_hz * rate_hz)` samples at each end, with its standard error and
    /// the implied damping ratio (see [`damping_from_growth`]).
    ///
    /// Limits: the fit assumes one exponential over the window; a signal that saturates, or a
    /// noise-driven random response (whose envelope wanders on the scale `1/(zeta omega)`),
    /// gives a slope that says little about the damping (use [`ambient_damping`] for that).
    /// The standard error inflates the least-squares one by `sqrt((1 + r1)/(1 - r1))`, `r1` the
    /// lag-1 autocorrelation of the residuals; this first-order correction is approximate for
    /// the strongly correlated residuals of a random response, and conservative there: on 120
    /// simulated 30 s noise-driven windows (`zeta` = 1 % and 2 %) none had `|sigma| > 2 stderr`.
    pub fn growth_rate(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        opts: &GrowthOptions,
    ) -> Result<GrowthRate, SpectralError> {
        if !(frequency_hz > 0.0 && frequency_hz.is_finite()) {
            return Err(SpectralError::Invalid(format!("frequency {frequency_hz}")));
        }
        let band = opts.band_fraction.map(|b| {
            let b = b.clamp(0.0, 0.99);
            (frequency_hz * (1.0 - b), frequency_hz * (1.0 + b))
        });
        let rate = self.rate_hz;
        let n = self.n;
        let env = self.envelope(x, band)?;
        let edge = ((opts.edge_fraction * n as f64).max(opts.edge_periods / frequency_hz * rate))
            .ceil() as usize;
        if 2 * edge + 8 > n {
            return Err(SpectralError::TooShort(format!(
                "{n} samples leave fewer than 8 after discarding {edge} at each end"
            )));
        }
        let (start, end) = (edge, n - edge);
        let m = (end - start) as f64;
        // Centred time (in samples) and log envelope means.
        let tm = (start + end - 1) as f64 / 2.0;
        let floor = env[start..end].iter().fold(0.0f64, |a, &v| a.max(v)) * 1e-12;
        if floor <= 0.0 {
            return Err(SpectralError::NoResult("zero envelope".into()));
        }
        let lnv = |v: f64| v.max(floor).ln();
        let ym = env[start..end].iter().map(|&v| lnv(v)).sum::<f64>() / m;
        let mut sxy = 0.0;
        let mut sxx = 0.0;
        for (i, &v) in env.iter().enumerate().take(end).skip(start) {
            let d = i as f64 - tm;
            sxy += d * (lnv(v) - ym);
            sxx += d * d;
        }
        let slope = sxy / sxx; // per sample
        let mut rss = 0.0;
        let mut c1 = 0.0;
        let mut prev: Option<f64> = None;
        for (i, &v) in env.iter().enumerate().take(end).skip(start) {
            let r = lnv(v) - ym - slope * (i as f64 - tm);
            rss += r * r;
            if let Some(p) = prev {
                c1 += p * r;
            }
            prev = Some(r);
        }
        // Coefficient of variation of the envelope with the fitted exponential divided out.
        let (mut s1, mut s2) = (0.0, 0.0);
        for (i, &v) in env.iter().enumerate().take(end).skip(start) {
            let q = v / (ym + slope * (i as f64 - tm)).exp();
            s1 += q;
            s2 += q * q;
        }
        let qm = s1 / m;
        let envelope_cv = ((s2 / m - qm * qm).max(0.0)).sqrt() / qm;
        let r1 = if rss > 0.0 {
            (c1 / rss).clamp(0.0, 0.999)
        } else {
            0.0
        };
        let se_ls = (rss / (m - 2.0) / sxx).sqrt();
        let stderr = se_ls * ((1.0 + r1) / (1.0 - r1)).sqrt() * rate;
        let sigma = slope * rate;
        Ok(GrowthRate {
            sigma,
            stderr,
            frequency_hz,
            zeta: damping_from_growth(sigma, frequency_hz),
            envelope_cv,
            start,
            end,
        })
    }

    /// Pre-processes `x` (centred moving-average removal of `opts.moving_average` samples if
    /// `> 1`, else linear detrending) into an internal buffer and runs the whole model-free
    /// analysis: dominant frequency, envelope growth, ambient AR damping near the dominant
    /// frequency, and [`classify`]. Allocates only the AR fit's small `p x p` matrices.
    pub fn analyze_window(
        &mut self,
        x: &[f64],
        opts: &WindowOptions,
    ) -> Result<WindowSpectral, SpectralError> {
        self.check(x)?;
        let mut work = std::mem::take(&mut self.work);
        if opts.moving_average > 1 {
            remove_moving_average(x, opts.moving_average, &mut work);
        } else {
            work.copy_from_slice(x);
            detrend_linear(&mut work);
        }
        let result = (|| {
            let peak = self.dominant_frequency(&work, opts.min_freq_hz)?;
            let growth = self.growth_rate(&work, peak.frequency_hz, &opts.growth)?;
            let ar = ArOptions {
                frequency_hint_hz: Some(peak.frequency_hz),
                ..opts.ar
            };
            let ambient = ambient_damping(&work, self.rate_hz, &ar).ok();
            let regime = classify(&growth, ambient.as_ref(), &opts.classify);
            Ok(WindowSpectral {
                peak,
                growth,
                ambient,
                regime,
            })
        })();
        self.work = work;
        result
    }
}

// ---------------------------------------------------------------------------------------------
// Ambient damping: AR(p)
// ---------------------------------------------------------------------------------------------

/// Options of [`ambient_damping`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArOptions {
    /// AR order `p` (2 to 12). Default 4: a sampled, noise-forced oscillator is ARMA(2,1), and
    /// an OLS AR(2) fit of it underestimates the damping badly (about half the true `zeta` for
    /// the lab gate at 200 Hz, see the tests), while AR(4) absorbs the MA part. Raise it to 8
    /// with measurement noise above a few percent of the signal std or with several modes: on
    /// the simulator with 20 % noise AR(4) gave `zeta ~ 0.12` for a true 0.02, AR(8) 0.024.
    pub order: usize,
    /// Pick the complex pole whose frequency is nearest this (Hz); `None`: the least-damped
    /// oscillatory pole (largest `|z|`) above 0.
    pub frequency_hint_hz: Option<f64>,
    /// Two-sided confidence level of the interval (e.g. 0.95).
    pub confidence: f64,
}

impl Default for ArOptions {
    fn default() -> Self {
        ArOptions {
            order: 4,
            frequency_hint_hz: None,
            confidence: 0.95,
        }
    }
}

/// Damping of the dominant mode from a noise-driven (ambient) response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmbientDamping {
    /// Natural frequency `|s| / (2 pi)` of the chosen pole, Hz.
    pub frequency_hz: f64,
    /// Damping ratio `-Re(s) / |s|` (negative: self-excited).
    pub zeta: f64,
    /// Lower end of the interval.
    pub zeta_low: f64,
    /// Upper end of the interval.
    pub zeta_high: f64,
    /// Delta-method standard error of `zeta`.
    pub zeta_stderr: f64,
    /// AR order used.
    pub order: usize,
    /// Standard deviation of the one-step prediction residuals.
    pub residual_std: f64,
}

/// Ambient damping of `x` (sampled at `rate_hz`) from a least-squares AR(p) fit.
///
/// Method: the mean is removed and `x[t] = a1 x[t-1] + ... + ap x[t-p] + e[t]` is fitted by
/// ordinary least squares (normal equations, Cholesky). The roots `z` of
/// `z^p - a1 z^(p-1) - ... - ap` (eigenvalues of the companion matrix) are the discrete poles;
/// the pole with positive imaginary part nearest the hint frequency is mapped to continuous time
/// by `s = ln(z) * rate_hz`, giving `f_n = |s| / 2 pi` and `zeta = -Re(s) / |s|`.
///
/// Interval: delta method. The coefficient covariance is the OLS one, `s_e^2 (Phi^T Phi)^-1`;
/// the gradient of `zeta` with respect to the coefficients is taken by central differences
/// (following the chosen root), and the interval is `zeta +- q * se` with `q` the normal quantile
/// of `confidence`.
///
/// Limits: a sampled, continuously noise-forced oscillator is an ARMA(2,1) process, not an
/// AR(2), and measurement noise makes it ARMA(2,2); OLS AR(p) is then biased (towards more
/// damping with measurement noise) and its residuals are not white, so the OLS covariance is
/// only approximate. Higher orders reduce the bias. The interval is first-order (symmetric) and
/// ignores the bias; it assumes stationarity over the window (a ramping damping gives an
/// average). Coverage measured on the simulator is reported in the module tests.
pub fn ambient_damping(
    x: &[f64],
    rate_hz: f64,
    opts: &ArOptions,
) -> Result<AmbientDamping, SpectralError> {
    let p = opts.order;
    if !(2..=12).contains(&p) {
        return Err(SpectralError::Invalid(format!("AR order {p} (2..=12)")));
    }
    if !(opts.confidence > 0.0 && opts.confidence < 1.0) {
        return Err(SpectralError::Invalid(format!(
            "confidence {}",
            opts.confidence
        )));
    }
    if !(rate_hz > 0.0 && rate_hz.is_finite()) {
        return Err(SpectralError::Invalid(format!("sample rate {rate_hz}")));
    }
    check_finite(x)?;
    let n = x.len();
    if n < 10 * p + 10 {
        return Err(SpectralError::TooShort(format!(
            "{n} samples for an AR({p}) fit"
        )));
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    // A noise-free signal of a single mode is exactly AR(2): the higher-order normal equations
    // are then singular, so fall back order by order.
    let (p, a, cov, s2) = (2..=p)
        .rev()
        .find_map(|q| fit_ar(x, mean, q).map(|(a, cov, s2)| (q, a, cov, s2)))
        .ok_or_else(|| SpectralError::NoResult("singular AR normal equations".into()))?;

    let coeffs: Vec<f64> = a.iter().copied().collect();
    let roots = ar_roots(&coeffs);
    let min_arg = 1e-9;
    let chosen = match opts.frequency_hint_hz {
        Some(fh) => {
            let target = 2.0 * PI * fh / rate_hz;
            roots
                .iter()
                .filter(|z| z.im > min_arg)
                .min_by(|a, b| {
                    (a.arg() - target)
                        .abs()
                        .total_cmp(&(b.arg() - target).abs())
                })
                .copied()
        }
        None => roots
            .iter()
            .filter(|z| z.im > min_arg)
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))
            .copied(),
    }
    .ok_or_else(|| SpectralError::NoResult("no oscillatory AR pole".into()))?;
    let (fz, zeta) = pole_to_modal(chosen, rate_hz);

    // Delta method: gradient of zeta by central differences, following the chosen root.
    let mut grad = DVector::<f64>::zeros(p);
    let mut pert = coeffs.clone();
    for j in 0..p {
        let h = 1e-6 * (cov[(j, j)].sqrt()).max(1e-9);
        let mut zeta_at = |delta: f64| -> Result<f64, SpectralError> {
            pert.copy_from_slice(&coeffs);
            pert[j] += delta;
            let r = ar_roots(&pert);
            let z = r
                .iter()
                .min_by(|a, b| (*a - chosen).norm().total_cmp(&(*b - chosen).norm()))
                .copied()
                .ok_or_else(|| SpectralError::NoResult("no roots".into()))?;
            Ok(pole_to_modal(Complex::new(z.re, z.im.abs()), rate_hz).1)
        };
        grad[j] = (zeta_at(h)? - zeta_at(-h)?) / (2.0 * h);
    }
    let var = (grad.transpose() * &cov * &grad)[(0, 0)].max(0.0);
    let se = var.sqrt();
    let q = normal_quantile(0.5 + opts.confidence / 2.0);
    Ok(AmbientDamping {
        frequency_hz: fz,
        zeta,
        zeta_low: zeta - q * se,
        zeta_high: zeta + q * se,
        zeta_stderr: se,
        order: p,
        residual_std: s2.sqrt(),
    })
}

/// OLS fit of an AR(`p`) model to `x - mean`: coefficients, their covariance and the residual
/// variance; `None` if the normal equations are (numerically) singular.
fn fit_ar(x: &[f64], mean: f64, p: usize) -> Option<(DVector<f64>, DMatrix<f64>, f64)> {
    let n = x.len();
    // Normal equations, accumulated without building the regressor matrix.
    let mut ata = DMatrix::<f64>::zeros(p, p);
    let mut atb = DVector::<f64>::zeros(p);
    for t in p..n {
        let y = x[t] - mean;
        for i in 0..p {
            let xi = x[t - 1 - i] - mean;
            atb[i] += xi * y;
            for j in 0..=i {
                ata[(i, j)] += xi * (x[t - 1 - j] - mean);
            }
        }
    }
    for i in 0..p {
        for j in 0..i {
            ata[(j, i)] = ata[(i, j)];
        }
    }
    let chol = ata.cholesky()?;
    // Reject near-singular systems: the Cholesky diagonal squared spans the eigenvalue range.
    let diag = chol.l_dirty().diagonal();
    let (dmin, dmax) = diag
        .iter()
        .fold((f64::MAX, 0.0f64), |(lo, hi), &d| (lo.min(d), hi.max(d)));
    if dmin.is_nan() || dmin <= 1e-7 * dmax {
        return None;
    }
    let a = chol.solve(&atb);
    let mut rss = 0.0;
    for t in p..n {
        let mut pred = 0.0;
        for i in 0..p {
            pred += a[i] * (x[t - 1 - i] - mean);
        }
        let r = x[t] - mean - pred;
        rss += r * r;
    }
    let s2 = rss / (n - 2 * p) as f64;
    let cov = chol.inverse() * s2;
    Some((a, cov, s2))
}

/// `(natural frequency Hz, damping ratio)` of the discrete pole `z` at `rate_hz`.
fn pole_to_modal(z: Complex<f64>, rate_hz: f64) -> (f64, f64) {
    let s = z.ln() * rate_hz;
    let wn = s.norm();
    (wn / (2.0 * PI), -s.re / wn)
}

/// Roots of `z^p - a1 z^(p-1) - ... - ap`: closed form for `p = 2`, companion-matrix
/// eigenvalues otherwise.
fn ar_roots(a: &[f64]) -> Vec<Complex<f64>> {
    let p = a.len();
    if p == 2 {
        // z^2 - a1 z - a2 = 0
        let disc = Complex::new(a[0] * a[0] + 4.0 * a[1], 0.0).sqrt();
        let h = Complex::new(a[0], 0.0);
        return vec![(h + disc) * 0.5, (h - disc) * 0.5];
    }
    let mut c = DMatrix::<f64>::zeros(p, p);
    for (j, &v) in a.iter().enumerate() {
        c[(0, j)] = v;
    }
    for i in 1..p {
        c[(i, i - 1)] = 1.0;
    }
    c.complex_eigenvalues().iter().copied().collect()
}

/// Standard normal quantile (Acklam's rational approximation, relative error < 1.2e-9).
pub fn normal_quantile(prob: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e+01,
        2.209460984245205e+02,
        -2.759285104469687e+02,
        1.38357751867269e+02,
        -3.066479806614716e+01,
        2.506628277459239e+00,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e+01,
        1.615858368580409e+02,
        -1.556989798598866e+02,
        6.680131188771972e+01,
        -1.328068155288572e+01,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-03,
        3.224671290700398e-01,
        2.445134137142996e+00,
        3.754408661907416e+00,
    ];
    let p = prob.clamp(1e-300, 1.0 - 1e-16);
    let plow = 0.02425;
    if p < plow {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - plow {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -normal_quantile(1.0 - p)
    }
}

// ---------------------------------------------------------------------------------------------
// Random decrement
// ---------------------------------------------------------------------------------------------

/// Random decrement signature of `x` (mean removed): the average of the `out.len()`-sample
/// segments that start where `x - mean` crosses `trigger` upwards (level up-crossing). For a
/// linear system driven by stationary Gaussian noise this average is proportional to the
/// auto-correlation function, i.e. to a free decay from an initial displacement `trigger`, so the
/// damping can be read from it like from a free decay. Returns the number of segments averaged
/// (0 leaves `out` zeroed). No allocation.
///
/// A trigger around `sqrt(2)` standard deviations is the usual compromise between the number of
/// segments and their signal-to-noise ratio.
pub fn random_decrement(x: &[f64], trigger: f64, out: &mut [f64]) -> usize {
    out.iter_mut().for_each(|v| *v = 0.0);
    let len = out.len();
    if len == 0 || x.len() < len + 1 {
        return 0;
    }
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let mut count = 0usize;
    for i in 1..=x.len() - len {
        if x[i - 1] - mean < trigger && x[i] - mean >= trigger {
            for (o, &v) in out.iter_mut().zip(&x[i..i + len]) {
                *o += v - mean;
            }
            count += 1;
        }
    }
    if count > 0 {
        let c = 1.0 / count as f64;
        out.iter_mut().for_each(|v| *v *= c);
    }
    count
}

/// Damping from the random decrement signature: [`random_decrement`] with a trigger of
/// `sqrt(2)` standard deviations over `periods` periods of `frequency_hz`, then an AR(2) fit of
/// the signature (a free decay, so AR(2) is exact up to the averaging noise) and the pole nearest
/// `frequency_hz`. Returns `(natural frequency Hz, zeta, segments averaged)`; no interval (the
/// signature's errors are strongly correlated; use [`ambient_damping`] for one).
pub fn random_decrement_damping(
    x: &[f64],
    rate_hz: f64,
    frequency_hz: f64,
    periods: f64,
) -> Result<(f64, f64, usize), SpectralError> {
    check_finite(x)?;
    let len = (periods / frequency_hz * rate_hz).round() as usize;
    if len < 40 || len > x.len() / 4 {
        return Err(SpectralError::TooShort(format!(
            "signature of {len} samples from {} samples",
            x.len()
        )));
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let std = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let mut sig = vec![0.0; len];
    let count = random_decrement(x, std::f64::consts::SQRT_2 * std, &mut sig);
    if count < 10 {
        return Err(SpectralError::NoResult(format!("{count} trigger points")));
    }
    let a = ambient_damping(
        &sig,
        rate_hz,
        &ArOptions {
            order: 2,
            frequency_hint_hz: Some(frequency_hz),
            confidence: 0.95,
        },
    )?;
    Ok((a.frequency_hz, a.zeta, count))
}

// ---------------------------------------------------------------------------------------------
// Classification
// ---------------------------------------------------------------------------------------------

/// Model-free regime of a window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Regime {
    /// The envelope grows significantly, or the ambient damping is significantly negative.
    SelfExcited,
    /// Self-excited and saturated: a nearly constant envelope (CV far below the Rayleigh value of
    /// a noise-driven response) with an ambient damping interval reaching zero or below.
    LimitCycle,
    /// The ambient damping is significantly positive, the envelope neither grows nor looks like a
    /// limit cycle.
    Damped,
    /// None of the above: too little evidence either way.
    Undecided,
}

/// Thresholds of [`classify`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassifyOptions {
    /// The envelope grows significantly when `sigma - k * stderr > min_growth_rate`; this is `k`.
    pub growth_sigmas: f64,
    /// Minimum growth rate to call self-excitation, 1/s (guards against tiny, irrelevant growth).
    pub min_growth_rate: f64,
    /// Damped requires `zeta_low` above this (a small positive margin keeps a limit cycle, whose
    /// damping estimate sits near zero, out of `Damped`).
    pub min_damped_zeta: f64,
    /// A limit cycle has an envelope CV below this (Rayleigh: 0.52).
    pub max_limit_cycle_cv: f64,
    /// ... and an ambient `zeta_low` below this (its equivalent damping is zero).
    pub max_limit_cycle_zeta: f64,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        ClassifyOptions {
            growth_sigmas: 3.0,
            min_growth_rate: 0.02,
            min_damped_zeta: 0.001,
            max_limit_cycle_cv: 0.3,
            max_limit_cycle_zeta: 0.002,
        }
    }
}

/// Classifies a window from its envelope growth and (optional) ambient damping, in this order:
/// self-excited if the envelope grows significantly (`sigma - k se > min_growth_rate`) or the
/// whole ambient interval is below zero; limit cycle if the envelope CV is below
/// `max_limit_cycle_cv` and the ambient `zeta_low` below `max_limit_cycle_zeta` (a noise-driven
/// response near zero damping also has a large, slowly varying envelope, but a Rayleigh-like CV);
/// damped if the ambient interval lies above `min_damped_zeta`; otherwise undecided.
///
/// Limits: growth is only seen while it happens (seconds at `zeta = -1 %`); a window that saw
/// nothing but a steady limit cycle relies on the CV test, which needs several envelope
/// correlation times `1/(|zeta| omega)` in the window and fails near the bifurcation where the
/// limit cycle is small against the noise.
pub fn classify(
    growth: &GrowthRate,
    ambient: Option<&AmbientDamping>,
    opts: &ClassifyOptions,
) -> Regime {
    let grows = growth.sigma - opts.growth_sigmas * growth.stderr > opts.min_growth_rate;
    if grows {
        return Regime::SelfExcited;
    }
    match ambient {
        Some(a) if a.zeta_high < 0.0 => Regime::SelfExcited,
        Some(a)
            if growth.envelope_cv < opts.max_limit_cycle_cv
                && a.zeta_low < opts.max_limit_cycle_zeta =>
        {
            Regime::LimitCycle
        }
        Some(a) if a.zeta_low > opts.min_damped_zeta => Regime::Damped,
        _ => Regime::Undecided,
    }
}

/// Options of [`SpectralAnalyzer::analyze_window`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowOptions {
    /// Centred moving-average window, samples (`<= 1`: linear detrending instead).
    pub moving_average: usize,
    /// Lowest frequency considered for the dominant peak, Hz.
    pub min_freq_hz: f64,
    /// Envelope growth options.
    pub growth: GrowthOptions,
    /// AR options (the hint is replaced by the dominant frequency).
    pub ar: ArOptions,
    /// Classification thresholds.
    pub classify: ClassifyOptions,
}

impl Default for WindowOptions {
    /// 1 s moving average at 200 Hz (~10 periods of the lab gate), 1 Hz floor.
    fn default() -> Self {
        WindowOptions {
            moving_average: 201,
            min_freq_hz: 1.0,
            growth: GrowthOptions::default(),
            ar: ArOptions::default(),
            classify: ClassifyOptions::default(),
        }
    }
}

/// The model-free analysis of one window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowSpectral {
    /// Dominant spectral peak.
    pub peak: Peak,
    /// Envelope growth.
    pub growth: GrowthRate,
    /// Ambient damping (`None` if the AR fit failed).
    pub ambient: Option<AmbientDamping>,
    /// The regime.
    pub regime: Regime,
}

#[cfg(test)]
mod tests;
