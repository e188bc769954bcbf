//! Ambient (noise-driven) damping: an AR(p) least-squares fit, its poles to damping ratios, and a
//! delta-method interval.

use super::{check_finite, SpectralError};
use nalgebra::{DMatrix, DVector};
use rustfft::num_complex::Complex;
use std::f64::consts::PI;

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
    /// Standard deviation of the one-step prediction residuals (NaN from SSI-COV, which has none).
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
pub(super) fn ar_roots(a: &[f64]) -> Vec<Complex<f64>> {
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
    // No roots when the Schur iteration does not converge (`crate::linalg`): no pole, no estimate.
    crate::linalg::complex_eigenvalues(c).unwrap_or_default()
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
