//! `zeta0` from the drift of the envelope: how fast the amplitude changes at each amplitude
//! (`docs/damping.md`, "The limit cycle", transitional windows).
//!
//! # Why
//! The envelope's relaxation ([`super::envelope_relaxation`]) needs a window that sits on a
//! saturated cycle; it refuses a window that catches the end of a growth or the shrinking
//! cycle of a recovery (the envelope's CV is too large), and there the free-vibration model
//! read about zero with narrow intervals at a true -1 to -2 % (`bench warning`, onset and
//! recovery). Such a window is where the envelope's *drift* is best seen: it visits a range of
//! amplitudes, and first-order stochastic averaging (Roberts and Spanos) gives the amplitude
//! `A` of `m ydd + c(yd) yd + k y = F(t)` under white forcing as
//!
//! ```text
//! dA = [ -w A zeta_eq(A) + q / (4 w^2 A) ] dt + s dW,   s^2 = q / (2 w^2)
//! ```
//!
//! and by Ito's lemma the two noise-induced drifts cancel in `ln A`:
//!
//! ```text
//! d ln A = -w zeta_eq(A) dt + (s / A) dW,   zeta_eq(A) = zeta0 + b A^p.
//! ```
//!
//! So the increments of `ln A` over a short step, regressed on `A^p` at the step's start, have
//! the intercept `-w zeta0` and the slope `-w b`, whatever the window's regime (growth,
//! saturation, decay, or a noise-driven linear gate, where `b = 0`): nothing assumes a
//! stationary window. The noise of an increment has variance `s^2 dt / A^2`, so each weighs
//! `A^2` (weighted least squares).
//!
//! # Assumptions
//! Those of first-order averaging (small damping, nearly harmonic motion), white forcing,
//! `zeta0` constant over the window (a drifting one gives about its value at the window's
//! mean amplitude), the exponent `p` of the amplitude dependence (2 for cubic velocity damping,
//! as in [`super::RelaxationOptions::exponent`]), and an envelope far above the sensor noise
//! (the noise adds to the band-passed envelope and flattens its drift at small amplitudes).
//! The band-pass in front of the envelope correlates neighbouring increments: the standard error
//! is inflated by the residuals' lag-1 autocorrelation (AR(1) variance factor). On a held cycle
//! the amplitudes barely vary, the intercept and the slope are confounded, and the interval is
//! (honestly) wide: there the relaxation estimator is the better one.

use super::SpectralError;
use std::f64::consts::PI;

/// Options of [`envelope_drift`]; lengths in periods.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftOptions {
    /// Envelope samples discarded at each end, periods (the band-pass's end effects).
    pub edge_periods: f64,
    /// The step of the increments, periods. One period: far shorter than the envelope's
    /// correlation time at the damping an alert cares about (`1 / (zeta w)`, 8 periods at 2 %),
    /// so the drift is nearly constant over a step, and long enough that the band-passed
    /// envelope's own smoothing (about `1 / (2 pi band f)`, 0.6 periods at a band of 25 %)
    /// correlates only neighbouring steps.
    pub step_periods: f64,
    /// The exponent `p` of the damping's amplitude dependence (2: cubic velocity damping).
    pub exponent: f64,
    /// Fewest increments for an estimate.
    pub min_increments: usize,
    /// Two-sided confidence level of the interval.
    pub confidence: f64,
}

impl Default for DriftOptions {
    fn default() -> Self {
        DriftOptions {
            edge_periods: 5.0,
            step_periods: 1.0,
            exponent: 2.0,
            min_increments: 20,
            confidence: 0.95,
        }
    }
}

/// `zeta0` from the envelope's drift, with the regression behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeDrift {
    /// Damping ratio at rest.
    pub zeta0: f64,
    /// Interval of [`DriftOptions::confidence`].
    pub zeta0_interval: (f64, f64),
    /// Standard error of `zeta0`.
    pub zeta0_stderr: f64,
    /// `b` of `zeta_eq(A) = zeta0 + b A^p`, per (signal unit)^p.
    pub amplitude_slope: f64,
    /// Smallest and largest envelope value the regression used (signal units).
    pub amplitude_range: (f64, f64),
    /// Increments in the regression.
    pub increments: usize,
}

/// Estimates `zeta0` from the envelope `env` (e.g. [`super::SpectralAnalyzer::envelope`] of a
/// band around `frequency_hz`) sampled at `rate_hz`. See the module documentation.
pub fn envelope_drift(
    env: &[f64],
    rate_hz: f64,
    frequency_hz: f64,
    opts: &DriftOptions,
) -> Result<EnvelopeDrift, SpectralError> {
    if !(rate_hz > 0.0 && frequency_hz > 0.0 && frequency_hz < rate_hz / 2.0) {
        return Err(SpectralError::Invalid(format!(
            "rate {rate_hz} Hz, frequency {frequency_hz} Hz"
        )));
    }
    if !(opts.step_periods > 0.0 && opts.exponent > 0.0 && opts.min_increments >= 3) {
        return Err(SpectralError::Invalid(format!("drift options {opts:?}")));
    }
    super::check_finite(env)?;
    let per = rate_hz / frequency_hz;
    let edge = (opts.edge_periods * per).ceil() as usize;
    let step = ((opts.step_periods * per).round() as usize).max(1);
    if env.len() <= 2 * edge + step * opts.min_increments {
        return Err(SpectralError::TooShort(format!(
            "{} envelope samples: need {} increments of {step} samples after {edge} edge \
             samples at each end",
            env.len(),
            opts.min_increments
        )));
    }
    let x = &env[edge..env.len() - edge];
    if x.iter().any(|&a| a <= 0.0) {
        return Err(SpectralError::NoResult("the envelope reaches zero".into()));
    }
    let dt = step as f64 / rate_hz;
    // the regressor scaled by its mean for conditioning: u = (A / mean A)^p
    let mean_a = x.iter().sum::<f64>() / x.len() as f64;
    let u_at = |i: usize| (x[i] / mean_a).powf(opts.exponent);
    let w_at = |i: usize| (x[i] / mean_a).powi(2);
    let y_at = |i: usize| (x[i + step] / x[i]).ln() / dt;
    // Instrumental variables: the envelope at a step's start carries the band-passed noise
    // whose own mean reversion the increment sees (regression on it reads a fast relaxation
    // of the noise as damping: about zero on a held cycle at a true -2 %); the envelope one
    // step EARLIER is correlated with the amplitude but not with that noise. Normal equations
    // (Z'WX) theta = Z'Wy with Z = [1, u(i - step)], X = [1, u(i)].
    let starts = (step..x.len() - step).step_by(step);
    let n = starts.len();
    let (mut sw, mut sz, mut su, mut szu, mut sy, mut szy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in starts.clone() {
        let (w, u, z, y) = (w_at(i), u_at(i), u_at(i - step), y_at(i));
        sw += w;
        sz += w * z;
        su += w * u;
        szu += w * z * u;
        sy += w * y;
        szy += w * z * y;
    }
    // [[sw, su], [sz, szu]] theta = [sy, szy]
    let det = sw * szu - su * sz;
    if det.abs() <= 1e-9 * sw * szu.abs() || !det.is_finite() {
        return Err(SpectralError::NoResult(
            "the envelope visits a single amplitude: no drift to regress".into(),
        ));
    }
    let intercept = (szu * sy - su * szy) / det;
    let slope = (sw * szy - sz * sy) / det;
    // residuals: weighted variance and the lag-1 autocorrelation of the standardised ones
    let (mut rss, mut lag1, mut r2, mut prev) = (0.0, 0.0, 0.0, None::<f64>);
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    let (mut szz, mut sz1) = (0.0, 0.0);
    for i in starts {
        let (w, u, z) = (w_at(i), u_at(i), u_at(i - step));
        let r = y_at(i) - intercept - slope * u;
        rss += w * r * r;
        let zr = w.sqrt() * r;
        if let Some(p) = prev {
            lag1 += p * zr;
        }
        r2 += zr * zr;
        prev = Some(zr);
        szz += w * z * z;
        sz1 += w * z;
        lo = lo.min(x[i]);
        hi = hi.max(x[i]);
    }
    let sigma2 = rss / (n - 2) as f64;
    let rho = if r2 > 0.0 {
        (lag1 / r2).clamp(0.0, 0.9)
    } else {
        0.0
    };
    // IV covariance sigma^2 (Z'WX)^-1 (Z'WZ) (X'WZ)^-1, its intercept entry, AR(1)-inflated
    let inv = [[szu / det, -su / det], [-sz / det, sw / det]];
    let zwz = [[sw, sz1], [sz1, szz]];
    let row = [
        inv[0][0] * zwz[0][0] + inv[0][1] * zwz[1][0],
        inv[0][0] * zwz[0][1] + inv[0][1] * zwz[1][1],
    ];
    let var_intercept =
        sigma2 * (row[0] * inv[0][0] + row[1] * inv[0][1]) * (1.0 + rho) / (1.0 - rho);
    let w = 2.0 * PI * frequency_hz;
    let zeta0 = -intercept / w;
    let se = var_intercept.sqrt() / w;
    if !(zeta0.is_finite() && se.is_finite()) {
        return Err(SpectralError::NoResult(
            "the drift regression failed".into(),
        ));
    }
    let q = super::normal_quantile(0.5 + opts.confidence / 2.0);
    Ok(EnvelopeDrift {
        zeta0,
        zeta0_interval: (zeta0 - q * se, zeta0 + q * se),
        zeta0_stderr: se,
        amplitude_slope: -slope / w / mean_a.powf(opts.exponent),
        amplitude_range: (lo, hi),
        increments: n,
    })
}

impl super::SpectralAnalyzer {
    /// [`envelope_drift`] of `x` (the analyzer's length and rate): the envelope of the band
    /// `(1 +- band) frequency_hz`, then the drift regression.
    pub fn envelope_drift(
        &mut self,
        x: &[f64],
        frequency_hz: f64,
        band: f64,
        opts: &DriftOptions,
    ) -> Result<EnvelopeDrift, SpectralError> {
        let b = band.clamp(0.01, 0.99);
        let rate = self.rate_hz();
        let env = self.envelope(
            x,
            Some((frequency_hz * (1.0 - b), frequency_hz * (1.0 + b))),
        )?;
        envelope_drift(env, rate, frequency_hz, opts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The envelope of a growth that saturates, `dA/dt = -w A (zeta0 + b A^2)` integrated
    /// finely (no noise): the regression recovers zeta0 and b.
    #[test]
    fn a_clean_growth_to_saturation_gives_back_zeta0_and_the_amplitude_slope() {
        let (rate, f) = (200.0, 10.0);
        let w = 2.0 * PI * f;
        let (zeta0, b) = (-0.02, 0.02 / 4.0); // saturates at A = 2
        let mut a = 0.2;
        let env: Vec<f64> = (0..2000)
            .map(|_| {
                let out = a;
                for _ in 0..10 {
                    a += -w * a * (zeta0 + b * a * a) / (10.0 * rate);
                }
                out
            })
            .collect();
        let d = envelope_drift(&env, rate, f, &DriftOptions::default()).unwrap();
        assert!((d.zeta0 - zeta0).abs() < 0.002, "{d:?}");
        assert!((d.amplitude_slope / b - 1.0).abs() < 0.15, "{d:?}");
        assert!(d.zeta0_interval.0 < d.zeta0 && d.zeta0 < d.zeta0_interval.1);
        assert!(
            d.amplitude_range.0 < 0.5 && d.amplitude_range.1 > 1.9,
            "{d:?}"
        );
    }

    /// Bad input is refused with a reason, never a panic or a NaN.
    #[test]
    fn bad_input_is_refused() {
        let opts = DriftOptions::default();
        let flat = vec![1.0; 2000];
        assert!(matches!(
            envelope_drift(&flat, 200.0, 10.0, &opts),
            Err(SpectralError::NoResult(_))
        ));
        assert!(matches!(
            envelope_drift(&flat[..100], 200.0, 10.0, &opts),
            Err(SpectralError::TooShort(_))
        ));
        assert!(matches!(
            envelope_drift(&flat, 200.0, 150.0, &opts),
            Err(SpectralError::Invalid(_))
        ));
        let mut zero = flat.clone();
        zero[1000] = 0.0;
        assert!(envelope_drift(&zero, 200.0, 10.0, &opts).is_err());
        let mut nan = flat;
        nan[10] = f64::NAN;
        assert!(envelope_drift(&nan, 200.0, 10.0, &opts).is_err());
    }
}
