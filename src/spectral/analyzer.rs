//! The spectral analyzer: FFTs planned once per window length with reused buffers; dominant
//! frequency, Hilbert envelope, envelope growth rate, and the whole window analysis.

use super::preprocess::{damping_from_growth, detrend_linear, hann, remove_moving_average};
use super::{
    ambient_damping, check_finite, classify, ssi_cov_damping, AmbientDamping, AmbientMethod,
    ArOptions, SpectralError, SsiOptions, WindowOptions, WindowSpectral,
};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::f64::consts::PI;
use std::sync::Arc;

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
                band_gain(k as f64 * df - centre, half_width)
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

    /// Two-sided density (units squared per Hz) of the white noise on `x`, from the median of
    /// its Hann-tapered periodogram between `lo_hz` and `hi_hz` (divided by `ln 2`: the median of
    /// an exponential ordinate); `None` without at least 8 ordinates there below the Nyquist
    /// frequency or on a bad `x`.
    pub fn noise_density(&mut self, x: &[f64], lo_hz: f64, hi_hz: f64) -> Option<f64> {
        self.check(x).ok()?;
        let n = self.n;
        let m = 2 * n;
        // Hann-tapered: the rectangular window's side lobes of a strong mode (a limit cycle) fall
        // only as 1/df^2 and outweigh a sensor's floor one or two frequencies away
        let mut energy = 0.0;
        for (i, b) in self.buf.iter_mut().enumerate() {
            let v = if i < n {
                let w = 0.5 - 0.5 * (2.0 * PI * i as f64 / n as f64).cos();
                energy += w * w;
                w * x[i]
            } else {
                0.0
            };
            *b = Complex::new(v, 0.0);
        }
        self.fwd2
            .process_with_scratch(&mut self.buf, &mut self.scratch);
        let df = self.rate_hz / m as f64;
        let hi = hi_hz.min(0.95 * self.rate_hz / 2.0);
        let mut p: Vec<f64> = (1..m / 2)
            .filter(|&k| (lo_hz..=hi).contains(&(k as f64 * df)))
            .map(|k| self.buf[k].norm_sqr() / (energy * self.rate_hz))
            .collect();
        if p.len() < 8 {
            return None;
        }
        p.sort_by(f64::total_cmp);
        Some(p[p.len() / 2] / std::f64::consts::LN_2)
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
    /// analysis: dominant frequency, envelope growth, ambient damping near the dominant
    /// frequency ([`AmbientMethod`], SSI-COV by default), and [`classify`]. Allocates only the
    /// ambient estimator's small matrices.
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
            // The regime is classified on the lagged SSI reading, on which the classifier's
            // limit-cycle test was calibrated (`SsiOptions::common_reference`: a window growing
            // into its cycle reads as stable there, as a cycle with common instants). Both
            // readings are made whichever the options report: their difference shows a window
            // whose variance grows (`analysis::read_growing_window`). A second SSI-COV estimate
            // costs a few hankel sums and one small decomposition, a fraction of a per cent of
            // an identification.
            let mut lagged = None;
            let mut common = None;
            let ambient = match opts.ambient {
                AmbientMethod::Ssi(ssi) => {
                    let read = |common_reference: bool| {
                        let o = SsiOptions {
                            common_reference,
                            ..ssi
                        };
                        ssi_cov_damping(&work, self.rate_hz, peak.frequency_hz, &o)
                            .ok()
                            .map(AmbientDamping::from)
                    };
                    let (l, c) = (read(false), read(true));
                    (lagged, common) = (Some(l), c);
                    if ssi.common_reference {
                        c
                    } else {
                        l
                    }
                }
                AmbientMethod::Ar(ar) => {
                    let ar = ArOptions {
                        frequency_hint_hz: Some(peak.frequency_hz),
                        ..ar
                    };
                    ambient_damping(&work, self.rate_hz, &ar).ok()
                }
                AmbientMethod::Skip => None,
            };
            let for_regime = lagged.unwrap_or(ambient);
            let regime = classify(&growth, for_regime.as_ref(), &opts.classify);
            Ok(WindowSpectral {
                peak,
                growth,
                ambient,
                ambient_common: common,
                regime,
            })
        })();
        self.work = work;
        result
    }
}

/// Gain of [`SpectralAnalyzer::envelope`]'s band-pass at `offset` Hz from the band's centre:
/// flat over the inner half of `half_width`, a raised cosine to zero at `half_width`.
pub(super) fn band_gain(offset: f64, half_width: f64) -> f64 {
    let d = offset.abs();
    if d <= 0.5 * half_width {
        1.0
    } else if d < half_width {
        0.5 * (1.0 + (PI * (d - 0.5 * half_width) / (0.5 * half_width)).cos())
    } else {
        0.0
    }
}
