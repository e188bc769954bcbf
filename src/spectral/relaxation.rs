//! Damping at rest of a gate on its limit cycle, from how fast the turbulent forcing's kicks to
//! the amplitude relax back to the cycle (stochastic averaging of the Hilbert envelope).
//!
//! # Why
//! On a limit cycle the equivalent damping is zero by definition, so an ambient or growth
//! estimate reads about zero whatever `zeta0` is, and a free-vibration model fitted to ten
//! seconds of an almost pure sine cannot separate `c1` from `c2`. What still carries `zeta0` is
//! the envelope's *dynamics*: the forcing keeps pushing the amplitude off the cycle and the
//! damping slope pulls it back.
//!
//! # Derivation (checked numerically in the tests and `tests/damping_regimes.rs`)
//! For `m ydd + (c1 + c2 yd^2) yd + k y = F(t)`, write `y = A cos(w t + phi)`. First-order
//! stochastic averaging (Roberts & Spanos) gives the Ito equation of the amplitude
//!
//! ```text
//! dA = [ -w A zeta_eq(A) + q / (4 w^2 A) ] dt + sqrt(q / (2 w^2)) dW,
//! zeta_eq(A) = zeta0 + 3 c2 w A^2 / (8 m),
//! ```
//!
//! `q` the intensity of `F/m` (white). The deterministic limit cycle is `zeta_eq(A_lc) = 0`.
//! Linearised about the cycle, `a = A - A_lc` is an Ornstein-Uhlenbeck process with rate
//!
//! ```text
//! lambda = d/dA [ -w A zeta_eq(A) ] at A_lc  -  q / (4 w^2 A_lc^2)
//!        = p w zeta0                         -  s^2 / (2 A_lc^2),
//! ```
//!
//! where `p = A zeta_eq'(A) / (zeta_eq(A) - zeta0)` at `A_lc` is the exponent of the damping's
//! amplitude dependence (`p = 2` for cubic velocity damping `c2 yd^3` and for Van der Pol's
//! `c2 y^2 yd`: any nonlinearity whose equivalent damping grows like `A^2`), and `s^2 = q/(2w^2)`
//! the diffusion. The OU process's stationary variance is `v = s^2 / (2 |lambda|)`, so the
//! diffusion term is `|lambda| v / A^2 = |lambda| CV^2` with `CV` the envelope's coefficient of
//! variation, and
//!
//! ```text
//! zeta0 = lambda (1 - CV^2) / (p w).
//! ```
//!
//! Scale-free: `lambda / w` and `CV` have no unit, so nothing depends on the gate's mass,
//! frequency, units or sample rate.
//!
//! # Estimator
//! 1. The envelope of the band-passed analytic signal (`(1 +- band) f`), edges discarded; the band
//!    is far wider than the envelope's own bandwidth `|lambda| / pi` but removes most of the
//!    sensor noise, which would otherwise dominate the envelope's short lags.
//! 2. Its autocovariance `r(tau)` at lags from [`RelaxationOptions::min_lag_periods`] periods (past
//!    what is left of the noise) out to where `r` has fallen by `e^-fit_decay` (where it is
//!    still well above its own noise), `lambda` by least squares on `ln r(tau)`. Lag 0, where any
//!    white noise sits, is never used (the principle of SSI-COV).
//! 3. Removing the sample mean biases every `r(tau)` down by the variance of the mean,
//!    `2 v / (|lambda| T)` for an OU process; the fit adds that back and is repeated (this
//!    removes the dominant `-2/T`-like bias of short records, which would read the damping too
//!    negative by about `1 / (w T)`).
//!    On a cycle that drifts (the damping still ramping after an onset's growth: the amplitude
//!    follows `sqrt(-zeta0)`) the envelope's least-squares line is removed instead of its mean
//!    when its slope is significant against the OU wandering about it
//!    ([`RelaxationOptions::detrend_significance`]); the line takes twice the mean's variance
//!    from the autocovariance, and the fit adds that back the same way. Where the ramp ends
//!    inside the record the envelope bends, and a quadratic or cubic is removed instead when
//!    its own top coefficient is significant ([`RelaxationOptions::detrend_max_degree`]; a
//!    polynomial of degree `d` takes `d + 1` times the mean's variance).
//! 4. Standard error from the OU estimator's asymptotic variance `2 |lambda| / T` (Fisher
//!    information of a continuous record), times [`RelaxationOptions::se_inflation`] for the
//!    inefficiency of the log-covariance fit; the interval is normal.
//!
//! # Assumptions (and when the interval is wrong)
//! - Stationary, white forcing (coloured forcing near `w` changes `q` but not `lambda`), a
//!   saturated cycle (not a growth or a decay), and a linearisable drift: the envelope's CV must
//!   be small ([`RelaxationOptions::max_cv`]); beyond, the OU linearisation is poor.
//! - The exponent `p` ([`RelaxationOptions::exponent`]): a gate whose damping depends on the
//!   amplitude otherwise (friction, `A^1`) gets `zeta0` scaled by `2/p`.
//! - The record must hold several correlation times `1/|lambda|`; with fewer than
//!   [`RelaxationOptions::min_correlation_times`] the estimate is refused.

use super::SpectralError;
use std::f64::consts::PI;

/// Options of [`envelope_relaxation`]; every length is in periods or correlation times.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelaxationOptions {
    /// Half-width of the band-pass in front of the envelope, as a fraction of the frequency.
    pub band: f64,
    /// Envelope samples discarded at each end, periods (the band-pass's end effects last about
    /// `2 / (band f)` seconds).
    pub edge_periods: f64,
    /// Shortest lag of the fit, periods.
    pub min_lag_periods: f64,
    /// The fit stops where `r(tau)` has fallen to `e^-fit_decay` of `r(min_lag)`.
    ///
    /// Values of both (0.5 period, 0.5): measured on 30 ten-second windows of the lab gate and
    /// of a 5 Hz lock gate at -2 % (`explore_relaxation_options` in `tests/damping_regimes.rs`).
    /// Longer fits (decay 1 to 2.5, lags from 1 to 2 periods) doubled or tripled the spread,
    /// because the far lags of a short record are mostly noise; shorter ones (decay 0.25)
    /// read zeta0 0.6 points too close to zero, because what is left of the band-passed noise
    /// correlates over a period or two and flattens the first lags.
    pub fit_decay: f64,
    /// The exponent `p` of the damping's amplitude dependence (2: cubic velocity damping).
    pub exponent: f64,
    /// Refused above this envelope CV (the OU linearisation needs a small spread).
    pub max_cv: f64,
    /// Refused when the record holds fewer correlation times `T |lambda|`.
    pub min_correlation_times: f64,
    /// Inflation of the asymptotic standard error for the log-covariance fit's inefficiency and
    /// the bias correction's own error (value: `tests/damping_regimes.rs`, coverage measured on
    /// two gates of different scale).
    pub se_inflation: f64,
    /// Two-sided confidence level of the interval.
    pub confidence: f64,
    /// The envelope's least-squares line is removed (not only its mean) when its slope exceeds
    /// this many of its standard errors under the OU fitted about the line (`f64::INFINITY`:
    /// never). Why: on a cycle whose damping still ramps (the onset after its growth) the
    /// amplitude follows `sqrt(-zeta0)` by tens of percent per window, and that trend read as
    /// a relaxation too slow to fit (refused, or about zero); a stationary cycle's line is
    /// rarely significant, and there the mean alone is removed as before. Value:
    /// `tests/damping_regimes.rs` (`ramping_limit_cycle_*`) and `bench warning` (2 and 2.5 gave
    /// the same onset windows, docs/benchmarks.md). The Whittle fit does not read it.
    pub detrend_significance: f64,
    /// Highest degree of the polynomial trend that may be removed (1, the default: a line).
    /// The degrees are tried from this one down, and the first whose own coefficient is
    /// significant (as the line's is, [`RelaxationOptions::detrend_significance`]) is removed
    /// with all below it. Why more than a line: where the damping ramps, or the ramp ends inside
    /// the record (an onset's cycle reaching its final amplitude), the envelope bends, and the
    /// bend left about a line read as a relaxation too slow: the lab gate's window the ramp ends
    /// in (-1.9 %) read -0.3 to -0.6 % in 7 of 12 seeds. Why not always: on a weak held cycle
    /// (-0.5 %, a 10 s record of about 7 correlation times) the wandering envelope passes the
    /// test too often, and the estimate moves away from the truth (the pooled coverage of the
    /// lab gate fell from 86 to 62 %). The analyzer raises it to 3 only where the cycle's level
    /// moved (`analysis::series`, `BEND_LEVEL_CHANGE`); measurements in docs/damping.md.
    pub detrend_max_degree: usize,
    /// The analyzer's estimate ([`super::SpectralAnalyzer::envelope_relaxation`]) is refused
    /// unless the envelope's variance is at least this many times what a steady sine's envelope
    /// shows in the same record (the band-pass's ripple plus the sensor noise measured away from
    /// the mode); 0 turns the test off. Why: on a steady sine with a little sensor noise (a
    /// forced vibration, or a cycle with no turbulence to kick it) the envelope moves only by
    /// that floor, which decorrelates within about a period of the band-pass, and the fit read
    /// it as a violent relaxation, -4 to -11 % with a confident interval (session 49). Why 3:
    /// on 100-cycle records the ratio was 0.6 to 1.5 on sines of 10.4, 5 and 2 Hz with noise
    /// from none to 5 % of the amplitude, and 12.1 or more on the three bench gates' -2 % cycles
    /// at the issue's noise floor (4.8 or more at four times it; `explore_relaxation_floor` in
    /// `tests/damping_regimes.rs`) (docs/damping.md, "A steady
    /// sine is not a limit cycle one can read").
    pub floor_factor: f64,
}

impl RelaxationOptions {
    /// The options measured for [`envelope_relaxation_whittle`] (experimental): the defaults but
    /// edges of 10 periods and an inflation of 1.2.
    ///
    /// Why 10 periods: the band-pass's start and stop transients leave a ripple on the envelope
    /// of a pure sine of 0.34 % of its amplitude 5 periods in, 0.03 % at 10 (0.017 % at 15). On a
    /// cycle whose envelope barely moves (CV 0.03) that ripple is a visible share of the fitted
    /// ordinates' power, and with 5 periods the fit read -2 % as -2.36 % (six seeds of the bench's
    /// presets), with 10 as -2.17 and -2.13 %, with 15 no better. Why 1.2: single-record coverage
    /// 92 to 100 % on both test gates from -0.5 % to -3 % (`explore_relaxation_across_zeta`).
    pub fn whittle() -> RelaxationOptions {
        RelaxationOptions {
            edge_periods: 10.0,
            se_inflation: 1.2,
            ..RelaxationOptions::default()
        }
    }
}

impl Default for RelaxationOptions {
    fn default() -> Self {
        RelaxationOptions {
            band: 0.25,
            edge_periods: 5.0,
            min_lag_periods: 0.5,
            fit_decay: 0.5,
            exponent: 2.0,
            max_cv: 0.4,
            min_correlation_times: 2.0,
            se_inflation: 1.5,
            confidence: 0.95,
            detrend_significance: 2.5,
            detrend_max_degree: 1,
            floor_factor: 3.0,
        }
    }
}

/// `zeta0` of a gate on its limit cycle, with the envelope statistics behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeRelaxation {
    /// Damping ratio at rest (negative on a limit cycle).
    pub zeta0: f64,
    /// Interval of [`RelaxationOptions::confidence`].
    pub zeta0_interval: (f64, f64),
    /// Standard error of `zeta0`.
    pub zeta0_stderr: f64,
    /// Relaxation rate of amplitude perturbations, 1/s (negative: they decay).
    pub lambda: f64,
    /// Mean envelope (the cycle's amplitude, in the signal's unit).
    pub amplitude: f64,
    /// Coefficient of variation of the envelope (noise-free part, extrapolated to lag 0).
    pub cv: f64,
    /// Correlation times `T |lambda|` in the record.
    pub correlation_times: f64,
}

/// Autocovariance of `e` (mean already removed) at lag `k` samples.
fn autocov(e: &[f64], k: usize) -> f64 {
    let n = e.len();
    e[..n - k]
        .iter()
        .zip(&e[k..])
        .map(|(a, b)| a * b)
        .sum::<f64>()
        / n as f64
}

/// Above this many multiply-adds (lags times samples) [`autocovs`] computes the autocovariances
/// by one FFT instead of a direct sum per lag. The direct cost grows as the square of the record
/// (lags up to n/4): a 1M-sample force record took minutes. Below it the direct sum stays, so
/// the daemon's windows (a few thousand samples, at most a few 1e7 multiply-adds) give the same
/// bits as before and the benchmarks that score them do not move. At this size the FFT of the
/// doubled record costs a few milliseconds, the direct sum about a tenth of a second.
const DIRECT_AUTOCOV_MAX_WORK: usize = 1 << 27;

/// Autocovariances of `e` (mean already removed) at each of `lags` (ascending, each below
/// `e.len()`): a direct sum per lag when that is cheap, else all lags from one FFT.
fn autocovs(e: &[f64], lags: &[usize]) -> Vec<f64> {
    let Some(&max_lag) = lags.last() else {
        return Vec::new();
    };
    if lags.len().saturating_mul(e.len()) <= DIRECT_AUTOCOV_MAX_WORK {
        return lags.iter().map(|&k| autocov(e, k)).collect();
    }
    let all = autocov_fft(e, max_lag);
    lags.iter().map(|&k| all[k]).collect()
}

/// Autocovariances of `e` at lags `0..=max_lag` (`max_lag < e.len()`), each divided by `n` as
/// [`autocov`] does, by the Wiener-Khinchin route: zero-padded to at least `2n` so the circular
/// correlation equals the linear one, `|X|^2`, inverse transform.
fn autocov_fft(e: &[f64], max_lag: usize) -> Vec<f64> {
    use rustfft::num_complex::Complex;
    let n = e.len();
    let m = (2 * n).next_power_of_two();
    let mut buf: Vec<Complex<f64>> = Vec::with_capacity(m);
    buf.extend(e.iter().map(|&v| Complex::new(v, 0.0)));
    buf.resize(m, Complex::new(0.0, 0.0));
    let mut planner = rustfft::FftPlanner::<f64>::new();
    planner.plan_fft_forward(m).process(&mut buf);
    buf.iter_mut()
        .for_each(|z| *z = Complex::new(z.norm_sqr(), 0.0));
    planner.plan_fft_inverse(m).process(&mut buf);
    // rustfft does not normalise: the round trip multiplies by `m`.
    let scale = 1.0 / (m as f64 * n as f64);
    buf[..=max_lag.min(n - 1)]
        .iter()
        .map(|z| z.re * scale)
        .collect()
}

/// Samples per period, after the checks both estimators share: a frequency below the Nyquist
/// frequency, a finite envelope.
fn check_inputs(env: &[f64], rate_hz: f64, frequency_hz: f64) -> Result<f64, SpectralError> {
    if !(rate_hz > 0.0 && frequency_hz > 0.0 && frequency_hz < rate_hz / 2.0) {
        return Err(SpectralError::Invalid(format!(
            "rate {rate_hz} Hz, frequency {frequency_hz} Hz"
        )));
    }
    super::check_finite(env)?;
    Ok(rate_hz / frequency_hz)
}

/// The refusals both estimators share: an envelope too spread for the OU linearisation, or a
/// record of too few correlation times.
fn check_record(cv: f64, corr_times: f64, opts: &RelaxationOptions) -> Result<(), SpectralError> {
    if cv > opts.max_cv {
        return Err(SpectralError::NoResult(format!(
            "envelope CV {cv:.2} above {}: not a saturated limit cycle",
            opts.max_cv
        )));
    }
    if corr_times < opts.min_correlation_times {
        return Err(SpectralError::TooShort(format!(
            "{corr_times:.1} correlation times of the envelope in the record, need {}",
            opts.min_correlation_times
        )));
    }
    Ok(())
}

/// Estimates `zeta0` from the envelope `env` (e.g. [`super::SpectralAnalyzer::envelope`] with
/// the band `(1 +- band) frequency_hz`), sampled at `rate_hz`, of a gate on its limit cycle at
/// `frequency_hz`. See the module documentation for the derivation and the assumptions.
pub fn envelope_relaxation(
    env: &[f64],
    rate_hz: f64,
    frequency_hz: f64,
    opts: &RelaxationOptions,
) -> Result<EnvelopeRelaxation, SpectralError> {
    let per = check_inputs(env, rate_hz, frequency_hz)?;
    let edge = (opts.edge_periods * per).ceil() as usize;
    let min_lag = ((opts.min_lag_periods * per).round() as usize).max(1);
    if env.len() < 2 * edge + 8 * min_lag {
        return Err(SpectralError::TooShort(format!(
            "{} envelope samples: need {} after {} edge samples at each end",
            env.len(),
            8 * min_lag,
            edge
        )));
    }
    let x = &env[edge..env.len() - edge];
    let n = x.len();
    let t_rec = n as f64 / rate_hz;
    let mean = x.iter().sum::<f64>() / n as f64;
    if mean.is_nan() || mean <= 0.0 {
        return Err(SpectralError::NoResult("zero envelope".into()));
    }
    let centred: Vec<f64> = x.iter().map(|v| v - mean).collect();
    // Lags on a grid of a quarter period (enough points for the fit, cost n per lag).
    let step = ((per / 4.0).round() as usize).max(1);
    let (lambda, ln_r0) = fit_relaxation(&centred, rate_hz, min_lag, step, opts)?;
    let v0 = ln_r0.exp();
    let cv = v0.sqrt() / mean;
    let corr_times = -lambda * t_rec;
    check_record(cv, corr_times, opts)?;
    let w = 2.0 * PI * frequency_hz;
    let factor = (1.0 - cv * cv) / (opts.exponent * w);
    let zeta0 = lambda * factor;
    let se_lambda = opts.se_inflation * (2.0 * -lambda / t_rec).sqrt();
    let se = se_lambda * factor;
    let q = super::normal_quantile(0.5 + opts.confidence / 2.0);
    Ok(EnvelopeRelaxation {
        zeta0,
        zeta0_interval: (zeta0 - q * se, zeta0 + q * se),
        zeta0_stderr: se,
        lambda,
        amplitude: mean,
        cv,
        correlation_times: corr_times,
    })
}

/// `(lambda, ln r0)` of the envelope `centred` (its mean removed): about its least-squares
/// polynomial of the highest degree `d <= detrend_max_degree` whose own coefficient is
/// significant ([`RelaxationOptions::detrend_significance`]) under the OU fitted about it, else
/// about its mean.
fn fit_relaxation(
    centred: &[f64],
    rate_hz: f64,
    min_lag: usize,
    step: usize,
    opts: &RelaxationOptions,
) -> Result<(f64, f64), SpectralError> {
    let about_mean = || fit_log_covariance(centred, rate_hz, min_lag, step, 2.0, opts);
    if !opts.detrend_significance.is_finite() || opts.detrend_max_degree == 0 {
        return about_mean();
    }
    let basis = orthonormal_polynomials(centred.len(), opts.detrend_max_degree);
    let coef: Vec<f64> = basis.iter().map(|u| dot(u, centred)).collect();
    // About the polynomial of degree `d`: `(lambda, ln r0)` when its top coefficient is
    // significant under the OU fitted about it. Each removed polynomial takes about the mean's
    // variance from the autocovariance (2 v / (|lambda| T) each, on the flat low end of the OU
    // spectrum), so degree `d` adds back `2 (d + 1)` of it.
    let about = |d: usize| -> Option<(f64, f64)> {
        let mut resid = centred.to_vec();
        for (u, c) in basis.iter().zip(&coef).take(d + 1).skip(1) {
            resid.iter_mut().zip(u).for_each(|(r, b)| *r -= c * b);
        }
        let removed = 2.0 * (d + 1) as f64;
        let (lambda, ln_r0) =
            fit_log_covariance(&resid, rate_hz, min_lag, step, removed, opts).ok()?;
        // A coefficient on a unit-norm basis vector has the variance S(0) of the OU about it,
        // 2 v / |lambda| per second, times the rate per sample.
        let var = 2.0 * ln_r0.exp() / (-lambda) * rate_hz;
        (coef[d].abs() > opts.detrend_significance * var.sqrt()).then_some((lambda, ln_r0))
    };
    // The highest significant degree wins; below the line, the mean alone is removed.
    if let Some(bent) = (2..basis.len()).rev().find_map(about) {
        return Ok(bent);
    }
    about(1).map_or_else(about_mean, Ok)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The polynomials of degree 0 to `max_degree` on `n` equally spaced points, orthonormal on
/// them (Gram-Schmidt of the monomials of `t` in [-1, 1], twice for accuracy). Written here
/// rather than taken from a crate: a few lines, and the degrees stay low (conditioning of the
/// monomials on [-1, 1] is no concern below degree 10).
fn orthonormal_polynomials(n: usize, max_degree: usize) -> Vec<Vec<f64>> {
    let half = ((n as f64 - 1.0) / 2.0).max(1.0);
    let t: Vec<f64> = (0..n).map(|i| i as f64 / half - 1.0).collect();
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(max_degree + 1);
    for d in 0..=max_degree {
        let mut v: Vec<f64> = t.iter().map(|x| x.powi(d as i32)).collect();
        for _ in 0..2 {
            for u in &basis {
                let c = dot(&v, u);
                v.iter_mut().zip(u).for_each(|(a, b)| *a -= c * b);
            }
        }
        let norm = dot(&v, &v).sqrt();
        if norm > 0.0 {
            v.iter_mut().for_each(|a| *a /= norm);
        }
        basis.push(v);
    }
    basis
}

/// `(lambda, ln r0)` of the least-squares fit of `ln r(tau)` for the residual envelope `e`, lags
/// from `min_lag` on a grid of `step` samples, adding back `removed` times the OU's variance of
/// the mean (2 for the mean, 4 for a line), refitted.
fn fit_log_covariance(
    e: &[f64],
    rate_hz: f64,
    min_lag: usize,
    step: usize,
    removed: f64,
    opts: &RelaxationOptions,
) -> Result<(f64, f64), SpectralError> {
    let n = e.len();
    let t_rec = n as f64 / rate_hz;
    let max_lag = n / 4;
    let lags: Vec<usize> = (0..)
        .map(|j| min_lag + j * step)
        .take_while(|&k| k <= max_lag)
        .collect();
    let raw = autocovs(e, &lags);
    if raw.first().is_none_or(|&r| r <= 0.0) {
        return Err(SpectralError::NoResult(
            "the envelope is uncorrelated at one period: no relaxation to fit".into(),
        ));
    }
    // Fit, add back the variance of the mean, refit.
    let mut offset = 0.0;
    let mut fit = (0.0, 0.0);
    for _ in 0..4 {
        let r: Vec<f64> = raw.iter().map(|v| v + offset).collect();
        let stop = r[0] * (-opts.fit_decay).exp();
        let used = r.iter().take_while(|&&v| v > stop).count().max(2);
        if used > r.len() {
            break;
        }
        let (mut st, mut sy, mut stt, mut sty) = (0.0, 0.0, 0.0, 0.0);
        for (k, v) in lags.iter().zip(&r).take(used) {
            let t = *k as f64 / rate_hz;
            let y = v.max(f64::MIN_POSITIVE).ln();
            st += t;
            sy += y;
            stt += t * t;
            sty += t * y;
        }
        let m = used as f64;
        let lambda = (m * sty - st * sy) / (m * stt - st * st);
        let ln_r0 = (sy - lambda * st) / m;
        if !(lambda < 0.0 && lambda.is_finite()) {
            return Err(SpectralError::NoResult(format!(
                "the envelope's autocovariance does not decay (slope {lambda:.3} 1/s)"
            )));
        }
        fit = (lambda, ln_r0);
        offset = removed * ln_r0.exp() / (-lambda * t_rec);
    }
    Ok(fit)
}

/// Where [`super::SpectralAnalyzer::envelope_relaxation_whittle`] measures the additive noise's
/// density, in multiples of the mode's frequency: away from the mode, below the third harmonic
/// of a cubic damping.
pub const NOISE_BAND: (f64, f64) = (1.4, 2.6);

/// The Whittle fit's periodogram ordinates reach this fraction of the band-pass's half-width
/// (squared gain 0.25): beyond, the filtered model falls to nothing while the envelope keeps a
/// floor (the magnitude's nonlinearity, the noise spread past the band), and fitting it read
/// some windows as a random walk. 0.75 and 0.5 both unbiased on 200-cycle records, 0.75 the
/// smaller error.
const FIT_FRACTION: f64 = 0.75;

/// **Experimental, not the daemon's estimator** (docs/benchmarks.md, "The relaxation by the
/// debiased Whittle likelihood (session 22, not shipped)"): `zeta0` as [`envelope_relaxation`]
/// gives it, but `lambda` from the debiased Whittle likelihood of the envelope's periodogram
/// (`whittle`), which models the record's length and the band-pass instead of fitting the log
/// autocovariance: unbiased on the test gates from -0.5 % to -3 %, where the log-covariance fit
/// is compressed towards -1.5 %. The interval is symmetric in `ln(-zeta0)`. Reads `band`,
/// `edge_periods`, `exponent`, `max_cv`, `min_correlation_times`, `se_inflation` and
/// `confidence` of `opts`
/// ([`RelaxationOptions::whittle`] the measured values).
///
/// `noise_psd` is the two-sided density (signal units squared per Hz) of the additive white
/// noise on the signal, a known floor in the model ([`super::SpectralAnalyzer::
/// envelope_relaxation_whittle`] measures it between [`NOISE_BAND`] times the frequency).
pub fn envelope_relaxation_whittle(
    env: &[f64],
    rate_hz: f64,
    frequency_hz: f64,
    noise_psd: f64,
    opts: &RelaxationOptions,
) -> Result<EnvelopeRelaxation, SpectralError> {
    if !(opts.band > 0.0 && opts.band < 1.0) {
        return Err(SpectralError::Invalid(format!("band {}", opts.band)));
    }
    let per = check_inputs(env, rate_hz, frequency_hz)?;
    let edge = (opts.edge_periods * per).ceil() as usize;
    // two samples per period: the band-passed envelope holds nothing above `band f`
    let step = ((per / 2.0).floor() as usize).max(1);
    let x: Vec<f64> = env
        .get(edge..env.len().saturating_sub(edge))
        .unwrap_or_default()
        .iter()
        .step_by(step)
        .copied()
        .collect();
    let n = x.len();
    let dt = step as f64 / rate_hz;
    let t_rec = n as f64 * dt;
    let mean = x.iter().sum::<f64>() / n.max(1) as f64;
    if n == 0 || mean.is_nan() || mean <= 0.0 {
        return Err(SpectralError::NoResult(format!(
            "no envelope left after {edge} edge samples at each end of {}",
            env.len()
        )));
    }
    let e: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let half_width = opts.band * frequency_hz;
    let w = 2.0 * PI * frequency_hz;
    // rates of zeta0 from 0.01 % to 30 % (the Lorentzian's corner then lies past the band)
    let fit = super::whittle::fit_ou_spectrum(
        &e,
        dt,
        FIT_FRACTION * half_width,
        (opts.exponent * w * 1e-4, opts.exponent * w * 0.3),
        |nu| super::analyzer::band_gain(nu, half_width).powi(2),
        // white noise of density N on the signal is 2 N on the envelope (its in-phase part)
        2.0 * noise_psd,
    )?;
    let lambda = -fit.lambda;
    let cv = fit.variance.sqrt() / mean;
    let corr_times = fit.lambda * t_rec;
    check_record(cv, corr_times, opts)?;
    let factor = (1.0 - cv * cv) / (opts.exponent * w);
    let zeta0 = lambda * factor;
    let s = opts.se_inflation * fit.ln_lambda_se;
    let q = super::normal_quantile(0.5 + opts.confidence / 2.0);
    Ok(EnvelopeRelaxation {
        zeta0,
        // zeta0 < 0: the lower bound is the faster relaxation
        zeta0_interval: (zeta0 * (q * s).exp(), zeta0 * (-q * s).exp()),
        zeta0_stderr: -zeta0 * s,
        lambda,
        amplitude: mean,
        cv,
        correlation_times: corr_times,
    })
}

impl super::SpectralAnalyzer {
    /// [`envelope_relaxation`] of `x` (the analyzer's length and rate): the envelope of the
    /// band `(1 +- opts.band) frequency_hz`, then the relaxation fit.
    pub fn envelope_relaxation(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        opts: &RelaxationOptions,
    ) -> Result<EnvelopeRelaxation, SpectralError> {
        let rate = self.rate_hz();
        let floor = if opts.floor_factor > 0.0 {
            Some(self.envelope_floor(x, frequency_hz, opts)?)
        } else {
            None
        };
        let env = self.band_envelope(x, frequency_hz, opts.band)?;
        let r = envelope_relaxation(env, rate, frequency_hz, opts)?;
        if let Some((ripple_cv2, noise_var)) = floor {
            let floor_cv2 = ripple_cv2 + noise_var / (r.amplitude * r.amplitude);
            if r.cv * r.cv < opts.floor_factor * floor_cv2 {
                return Err(SpectralError::NoResult(format!(
                    "the envelope's fluctuations (CV {:.4}) are within {} times the variance \
                     the sensor noise and the band-pass leave on a steady sine (CV {:.4}): no \
                     relaxation to read",
                    r.cv,
                    opts.floor_factor,
                    floor_cv2.sqrt()
                )));
            }
        }
        Ok(r)
    }

    /// What a steady sine's envelope fluctuates by in this record, without any relaxation:
    /// `(cv2, noise_var)`, the squared CV that the band-pass's ripple leaves on a pure sine of
    /// this length, frequency and rate (mean of the cosine and the sine phase, after the same
    /// edges), and the variance the white noise measured between [`NOISE_BAND`] times the
    /// frequency puts through the band (`2 S * 2 band f` for the two-sided density `S`; its
    /// in-phase part moves the envelope of a large sine by as much). See
    /// [`RelaxationOptions::floor_factor`].
    fn envelope_floor(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        opts: &RelaxationOptions,
    ) -> Result<(f64, f64), SpectralError> {
        let rate = self.rate_hz();
        let (lo, hi) = (NOISE_BAND.0 * frequency_hz, NOISE_BAND.1 * frequency_hz);
        let noise_psd = self.noise_density(x, lo, hi).unwrap_or(0.0);
        let noise_var = 4.0 * noise_psd * opts.band.clamp(0.01, 0.99) * frequency_hz;
        let n = x.len();
        let per = check_inputs(x, rate, frequency_hz)?;
        let edge = (opts.edge_periods * per).ceil() as usize;
        if n <= 2 * edge + 2 {
            return Ok((0.0, noise_var));
        }
        // one allocation per limit-cycle window, outside any inner loop
        let mut sine = vec![0.0; n];
        let mut cv2 = 0.0;
        for phase in [0.0, 0.5 * PI] {
            let w = 2.0 * PI * frequency_hz / rate;
            sine.iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = (w * i as f64 + phase).cos());
            let env = &self.band_envelope(&sine, frequency_hz, opts.band)?[edge..n - edge];
            let mean = env.iter().sum::<f64>() / env.len() as f64;
            let var = env.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / env.len() as f64;
            cv2 += 0.5 * var / (mean * mean);
        }
        Ok((cv2, noise_var))
    }

    /// The envelope of the band `(1 +- band) frequency_hz` of `x` (`band` clamped to 0.01..0.99).
    fn band_envelope(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        band: f64,
    ) -> Result<&[f64], SpectralError> {
        let b = band.clamp(0.01, 0.99);
        self.envelope(
            x,
            Some((frequency_hz * (1.0 - b), frequency_hz * (1.0 + b))),
        )
    }

    /// [`envelope_relaxation_whittle`] of `x` (experimental): the envelope as for
    /// [`Self::envelope_relaxation`], the noise density measured between [`NOISE_BAND`] times
    /// the frequency (zero where that band is past the Nyquist frequency).
    pub fn envelope_relaxation_whittle(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        opts: &RelaxationOptions,
    ) -> Result<EnvelopeRelaxation, SpectralError> {
        let rate = self.rate_hz();
        let (lo, hi) = (NOISE_BAND.0 * frequency_hz, NOISE_BAND.1 * frequency_hz);
        let noise = self.noise_density(x, lo, hi).unwrap_or(0.0);
        let env = self.band_envelope(x, frequency_hz, opts.band)?;
        envelope_relaxation_whittle(env, rate, frequency_hz, noise, opts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The detrending basis is orthonormal on the grid, and degree `d` spans the polynomials
    /// of degree `d` (a cubic is removed exactly by the basis up to 3, not by the one up to 2).
    #[test]
    fn the_polynomial_basis_is_orthonormal_and_removes_a_cubic() {
        let n = 501;
        let basis = orthonormal_polynomials(n, 3);
        for (i, u) in basis.iter().enumerate() {
            for (j, v) in basis.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (dot(u, v) - want).abs() < 1e-12,
                    "<{i}, {j}> = {}",
                    dot(u, v)
                );
            }
        }
        let cubic: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / 100.0;
                2.0 - t + 0.3 * t * t - 0.05 * t * t * t
            })
            .collect();
        let residual_norm = |upto: usize| {
            let mut r = cubic.clone();
            for u in &basis[..=upto] {
                let c = dot(u, &cubic);
                r.iter_mut().zip(u).for_each(|(a, b)| *a -= c * b);
            }
            dot(&r, &r).sqrt()
        };
        assert!(residual_norm(3) < 1e-9, "{}", residual_norm(3));
        assert!(residual_norm(2) > 1e-3, "{}", residual_norm(2));
    }

    /// A reproducible test signal: an AR(1) (`phi` near 1 for a slow relaxation) plus a decaying
    /// oscillation, its mean removed (xorshift noise, so the test needs no seed crate).
    fn test_signal(n: usize, phi: f64, seed: u64) -> Vec<f64> {
        let mut s = seed.max(1);
        let mut noise = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut a = 0.0;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                a = phi * a + noise();
                let t = i as f64 / 200.0;
                a + 3.0 * (-0.05 * t).exp() * (2.0 * PI * 10.4 * t).sin() + 0.2
            })
            .collect();
        let mean = x.iter().sum::<f64>() / n as f64;
        x.iter().map(|v| v - mean).collect()
    }

    /// The FFT autocovariance equals the direct sum at every lag to 1e-9 of the lag-0 value (the
    /// scale of the sequence: a relative error at a lag where it crosses zero means nothing),
    /// on short records, an odd length, and one record long enough for [`autocovs`] to take the
    /// FFT path.
    #[test]
    fn the_fft_autocovariance_equals_the_direct_sum() {
        for (n, phi, seed) in [
            (7, 0.5, 1),
            (1000, 0.9, 2),
            (4097, 0.99, 3),
            (20_000, 0.999, 4),
        ] {
            let e = test_signal(n, phi, seed);
            let max_lag = n / 4;
            let fft = autocov_fft(&e, max_lag);
            let r0 = autocov(&e, 0);
            for (k, got) in fft.iter().enumerate() {
                let want = autocov(&e, k);
                assert!(
                    (got - want).abs() <= 1e-9 * r0,
                    "n {n}, lag {k}: fft {got}, direct {want}"
                );
            }
        }
        // Above the threshold: every lag up to n/4 on a 40 000-sample record is 4e8 > 1.3e8.
        let e = test_signal(40_000, 0.995, 5);
        let lags: Vec<usize> = (0..=e.len() / 4).collect();
        assert!(lags.len() * e.len() > DIRECT_AUTOCOV_MAX_WORK);
        let r0 = autocov(&e, 0);
        for (&k, got) in lags.iter().zip(autocovs(&e, &lags)) {
            let want = autocov(&e, k);
            assert!(
                (got - want).abs() <= 1e-9 * r0,
                "lag {k}: fft {got}, direct {want}"
            );
        }
    }

    /// Below the threshold the direct sum is kept bit for bit (the daemon's windows and the
    /// benchmarks scored on them).
    #[test]
    fn short_records_keep_the_direct_sum_bit_for_bit() {
        let e = test_signal(4000, 0.99, 6);
        let lags: Vec<usize> = (10..=1000).step_by(5).collect();
        assert!(lags.len() * e.len() <= DIRECT_AUTOCOV_MAX_WORK);
        for (&k, got) in lags.iter().zip(autocovs(&e, &lags)) {
            assert_eq!(got.to_bits(), autocov(&e, k).to_bits(), "lag {k}");
        }
    }
}
