//! The coefficients' covariance at a least-squares optimum, and the delta method through it:
//! what turns a model-based figure (e.g. zeta0) into a figure with a 95 % interval.
//!
//! `Cov(c) = B Omega B * n/(n - rank)`, `B = (J^T J)^+`, `J` the Jacobian of the prediction at
//! the sample times w.r.t. the coefficients (central differences), and `Omega` the Newey-West
//! (Bartlett-weighted) sum of the scores' autocovariances `sum_i r_i r_(i+k) J_i^T J_(i+k)` over
//! lags up to the residuals' correlation length ([`bandwidth`]). With white residuals this is
//! the textbook `sigma^2 (J^T J)^-1`. Why not the textbook alone: the turbulent forcing that a
//! free-vibration fit treats as measurement error is narrow-band at the gate's own frequency,
//! exactly where the Jacobian's columns oscillate, so its errors add up coherently over many
//! cycles; a white-noise formula (or an inflation by the autocorrelation up to its first zero
//! crossing, a quarter period) is then too confident by an order of magnitude (the forcing
//! propagated through the fitted model instead of estimated from the residuals:
//! `identify::forcing`, opt-in as `model_interval = "forcing"`). Why a
//! pseudo-inverse: a scale group (`model::scaling`) leaves one direction of the coefficients
//! undetermined, and a scale-free figure (zeta0) does not depend on it; a figure that does
//! depend on an undetermined direction gets no standard deviation ([`Covariance::std_dev_of`]
//! is `None`).

use super::predict::{output_of, predict, trajectory};
use super::problem::Output;
use super::InitialValues;
use crate::data::TimeSeries;
use crate::model::Model;
use nalgebra::{DMatrix, DVector};

/// Relative tolerance of the integrations behind the Jacobian. Value: the difference steps are
/// 1e-4 relative, so the solver's error (about `rtol`) stays five orders below the differences.
pub const COVARIANCE_RTOL: f64 = 1e-9;

/// Relative step of the central differences (of the Jacobian and of a figure's gradient).
/// Value: large against the solver's error at [`COVARIANCE_RTOL`], small against the
/// curvature of an oscillator's response in its damping and stiffness.
pub const DIFFERENCE_STEP: f64 = 1e-4;

/// Singular values of the column-normalised Jacobian below this fraction of the largest count
/// as zero (an undetermined direction). Value: the differenced Jacobian itself is only good to
/// about `COVARIANCE_RTOL / DIFFERENCE_STEP` = 1e-5 relative, so an exactly undetermined
/// direction (a scale group) shows a singular value of that order, not zero; anything ten times
/// above is taken as determined (`J^T J` conditioned up to 1e8) and widens the interval.
const SINGULAR_CUTOFF: f64 = 1e-4;

/// A gradient whose component along an undetermined direction exceeds this fraction of its
/// norm has no standard deviation. Value: above the error of an undetermined direction
/// computed from the differenced Jacobian (about 1e-5), far below a real dependence (of order
/// one).
const NULL_TOLERANCE: f64 = 1e-3;

/// What [`Covariance::build`] puts between the pseudo-inverses.
pub(super) struct Middle {
    /// `Omega`, in the column-normalised coordinates.
    pub omega: DMatrix<f64>,
    /// A factor on the sandwich (Newey-West's `n / (n - rank)`).
    pub factor: f64,
    /// Lags of the residuals' autocorrelation `Omega` counts (0 when it is a model's).
    pub bandwidth: usize,
    /// The two-sided 95 % critical value that goes with it.
    pub critical_95: f64,
}

/// The covariance of the coefficients at a least-squares optimum.
#[derive(Debug, Clone)]
pub struct Covariance {
    /// `Cov(c)` in the coefficients' units (pseudo-inverse: zero along undetermined directions).
    pub matrix: DMatrix<f64>,
    /// Residual variance `RSS / (n - rank)`.
    pub sigma2: f64,
    /// Lags of the residuals' autocorrelation counted in `Omega` ([`bandwidth`]).
    pub bandwidth: usize,
    /// Rank of the Jacobian (number of determined directions).
    pub rank: usize,
    /// Residuals used, `n`.
    pub samples: usize,
    /// The two-sided 95 % critical value that goes with `matrix` ([`Covariance::critical_value_95`]).
    critical_95: f64,
    /// Undetermined directions, in the coefficients' units (unit vectors after normalising
    /// each coefficient by its Jacobian column's norm, see [`Covariance::std_dev_of`]).
    null: Vec<DVector<f64>>,
    /// Norm of each Jacobian column (the normalisation of `null`).
    column_norms: Vec<f64>,
}

impl Covariance {
    /// From the Jacobian `jac` (`n x p`, row `i` the derivatives of prediction `i`) and the
    /// residuals at the optimum. `None` when there is nothing to estimate: non-finite entries,
    /// no determined direction, or no more residuals than determined directions.
    pub fn from_jacobian(jac: &DMatrix<f64>, residuals: &[f64]) -> Option<Covariance> {
        let bandwidth = bandwidth(residuals);
        let n = residuals.len();
        Covariance::build(jac, residuals, |scaled, rank, _| {
            // Omega in the normalised coordinates: Bartlett weights keep it positive
            // semi-definite.
            let p = scaled.ncols();
            let mut omega = DMatrix::zeros(p, p);
            for k in 0..=bandwidth {
                let w = 1.0 - k as f64 / (bandwidth + 1) as f64;
                let mut gamma = DMatrix::zeros(p, p);
                for i in 0..n - k {
                    let rr = residuals[i] * residuals[i + k];
                    for a in 0..p {
                        let sa = scaled[(i, a)] * rr;
                        for b in 0..p {
                            gamma[(a, b)] += sa * scaled[(i + k, b)];
                        }
                    }
                }
                if k == 0 {
                    omega += gamma;
                } else {
                    omega += (&gamma + gamma.transpose()) * w;
                }
            }
            let dof = n as f64 / (n - rank) as f64;
            let critical = fixed_b_critical_value_95((bandwidth + 1) as f64 / n as f64);
            Some(Middle {
                omega,
                factor: dof,
                bandwidth,
                critical_95: critical,
            })
        })
    }

    /// The sandwich `B Omega B * factor` with `B = (J^T J)^+` in the column-normalised
    /// coordinates and the [`Middle`] from `middle(scaled_jacobian, rank, B)`. `None` as [`Covariance::from_jacobian`].
    pub(super) fn build(
        jac: &DMatrix<f64>,
        residuals: &[f64],
        middle: impl FnOnce(&DMatrix<f64>, usize, &DMatrix<f64>) -> Option<Middle>,
    ) -> Option<Covariance> {
        let (n, p) = jac.shape();
        if n != residuals.len() || p == 0 || n <= p {
            return None;
        }
        if jac.iter().chain(residuals).any(|v| !v.is_finite()) {
            return None;
        }
        // Column normalisation: coefficients of very different units (kg, N s/m, N/m) would
        // otherwise look singular to a cutoff on raw singular values.
        let column_norms: Vec<f64> = (0..p)
            .map(|j| {
                let norm = jac.column(j).norm();
                if norm > 0.0 {
                    norm
                } else {
                    1.0
                }
            })
            .collect();
        let mut scaled = jac.clone();
        for (j, norm) in column_norms.iter().enumerate() {
            scaled.column_mut(j).unscale_mut(*norm);
        }
        let svd = crate::linalg::svd(scaled.clone(), false, true)?;
        let v_t = svd.v_t?;
        let s_max = svd.singular_values.max();
        if s_max.is_nan() || s_max <= 0.0 {
            return None;
        }
        let mut rank = 0;
        let mut pinv = DMatrix::zeros(p, p);
        let mut null = Vec::new();
        for (i, &s) in svd.singular_values.iter().enumerate() {
            let v = v_t.row(i).transpose();
            if s > SINGULAR_CUTOFF * s_max {
                rank += 1;
                pinv += &v * v.transpose() / (s * s);
            } else {
                null.push(v);
            }
        }
        if n <= rank {
            return None;
        }
        let rss: f64 = residuals.iter().map(|r| r * r).sum();
        let sigma2 = rss / (n - rank) as f64;
        let Middle {
            omega,
            factor,
            bandwidth,
            critical_95,
        } = middle(&scaled, rank, &pinv)?;
        // Back to the coefficients' units: x_j = norm_j * c_j, so Cov(c) = D^-1 Cov(x) D^-1.
        let mut matrix = &pinv * omega * &pinv * factor;
        for (j, norm) in column_norms.iter().enumerate() {
            matrix.row_mut(j).unscale_mut(*norm);
            matrix.column_mut(j).unscale_mut(*norm);
        }
        (matrix.iter().all(|v| v.is_finite()) && critical_95.is_finite()).then_some(Covariance {
            matrix,
            sigma2,
            bandwidth,
            rank,
            samples: n,
            critical_95,
            null,
            column_norms,
        })
    }

    /// The two-sided 95 % critical value for a figure's `t` statistic under this covariance.
    /// Newey-West ([`Covariance::from_jacobian`]): [`fixed_b_critical_value_95`] at
    /// `b = (bandwidth + 1) / n`, the share of the record the sum spans (1.96 for white
    /// residuals, 2.72 where they stay coherent over a quarter of the window, the cap of
    /// [`bandwidth`]). Under a forcing model (`identify::forcing`): 1.96.
    pub fn critical_value_95(&self) -> f64 {
        self.critical_95
    }

    /// Standard deviation of a figure `f(c)` with gradient `gradient` (delta method: `sqrt(g^T
    /// Cov g)`). `None` when the gradient has the wrong length, is not finite, or depends on a
    /// direction the data do not determine.
    pub fn std_dev_of(&self, gradient: &[f64]) -> Option<f64> {
        let p = self.matrix.nrows();
        if gradient.len() != p || gradient.iter().any(|g| !g.is_finite()) {
            return None;
        }
        let g = DVector::from_column_slice(gradient);
        // The gradient in the normalised coordinates x_j = norm_j * c_j is g_j / norm_j.
        let g_x = DVector::from_iterator(p, (0..p).map(|j| g[j] / self.column_norms[j]));
        let g_norm = g_x.norm();
        if self
            .null
            .iter()
            .any(|v| v.dot(&g_x).abs() > NULL_TOLERANCE * g_norm)
        {
            return None;
        }
        let var = g.dot(&(&self.matrix * &g));
        (var.is_finite() && var >= 0.0).then(|| var.sqrt())
    }
}

/// The 97.5 % quantile of `|t|`'s fixed-b limit for the Bartlett kernel with bandwidth `b` as a
/// share of the record: `1.96 + 2.9694 b + 0.4160 b^2 - 0.5324 b^3`, Kiefer and Vogelsang's
/// (2005, Econometric Theory 21) fit to the simulated limit, for `0 < b <= 1` (`b` is clamped to
/// that range). Why not 1.96: the Newey-West sum over a bandwidth that is a fixed share of the
/// record is biased low and itself random (the residuals are demeaned by the fit, and the long
/// lags are few), so a normal quantile is too small exactly where the forcing makes the
/// residuals coherent over a quarter of the window. The lock gate's burst windows read by the
/// model covered their truth in 19 of 24 windows with 1.96 (`bench warning`, docs/damping.md).
/// Written here, not taken from a crate: it is one polynomial, and no Rust crate carries
/// fixed-b values. Checked against a simulation (`fixed_b_values_match_a_simulation`).
pub fn fixed_b_critical_value_95(b: f64) -> f64 {
    let b = if b.is_nan() { 1.0 } else { b.clamp(0.0, 1.0) };
    1.959_964 + b * (2.9694 + b * (0.4160 - 0.5324 * b))
}

/// The residuals' correlation length in samples: the largest lag up to `n / 4` whose
/// autocorrelation exceeds `4 / sqrt(n)` in magnitude (0 when none does). Why this threshold:
/// an autocorrelation of white residuals has a standard error of about `1 / sqrt(n)`, so four
/// of them are rarely crossed by chance (a few percent over all lags of a 2000-sample window),
/// while a narrow-band residual's oscillating autocorrelation keeps crossing it until its
/// envelope has decayed, which is the length its errors stay coherent over.
pub fn bandwidth(residuals: &[f64]) -> usize {
    let n = residuals.len();
    if n < 8 {
        return 0;
    }
    let mean = residuals.iter().sum::<f64>() / n as f64;
    let r0: f64 = residuals.iter().map(|r| (r - mean) * (r - mean)).sum();
    if r0.is_nan() || r0 <= 0.0 {
        return 0;
    }
    let threshold = 4.0 / (n as f64).sqrt();
    let mut last = 0;
    for k in 1..=n / 4 {
        let rk: f64 = residuals[..n - k]
            .iter()
            .zip(&residuals[k..])
            .map(|(a, b)| (a - mean) * (b - mean))
            .sum();
        if (rk / r0).abs() > threshold {
            last = k;
        }
    }
    last
}

/// Central-difference steps for coefficients `c` whose DE scales are `scales` (empty: 1):
/// `DIFFERENCE_STEP` relative, and relative to a thousandth of the scale for a coefficient
/// at or near zero.
pub fn difference_steps(c: &[f64], scales: &[f64]) -> Vec<f64> {
    c.iter()
        .enumerate()
        .map(|(j, cj)| {
            let scale = scales.get(j).copied().unwrap_or(1.0).abs();
            DIFFERENCE_STEP * cj.abs().max(1e-3 * scale).max(f64::MIN_POSITIVE)
        })
        .collect()
}

/// The Newey-West covariance at `optimum` (the prediction by Dormand-Prince at
/// [`COVARIANCE_RTOL`], its Jacobian by central differences of `optimum.steps`). The initial
/// conditions are held fixed, or, with `optimum.initial_steps`, counted as two more unknowns after the
/// coefficients (the covariance is then `(p + 2) x (p + 2)`, a figure's gradient has two more
/// entries, zero for a figure of the coefficients alone). `None` when an integration fails or
/// [`Covariance::from_jacobian`] has nothing to estimate. Costs `2p + 1` integrations, 4 more
/// with the initial conditions.
pub fn covariance(optimum: &Optimum<'_>) -> Option<Covariance> {
    let at = jacobian(optimum)?;
    Covariance::from_jacobian(&at.jacobian, &at.residuals)
}

/// A least-squares optimum as a covariance needs it: the model's prediction of `output` from
/// `init` with `coefficients`, fitted to all samples of `series`.
#[derive(Debug, Clone, Copy)]
pub struct Optimum<'a> {
    /// The model.
    pub model: &'a Model,
    /// The data it was fitted to.
    pub series: &'a TimeSeries,
    /// The fitted coefficients.
    pub coefficients: &'a [f64],
    /// The initial conditions of the fit.
    pub init: InitialValues,
    /// What the fit compared with the data.
    pub output: Output,
    /// Central-difference steps of the coefficients ([`difference_steps`]).
    pub steps: &'a [f64],
    /// The steps of `y0` and `v0` when the initial conditions count as two more unknowns.
    pub initial_steps: Option<(f64, f64)>,
}

/// What a least-squares optimum gives the covariance: the Jacobian of the prediction, the
/// residuals and the model's states at the sample times.
#[derive(Debug, Clone)]
pub(super) struct AtOptimum {
    /// `n x (p [+ 2])`, row `i` the derivatives of prediction `i`.
    pub jacobian: DMatrix<f64>,
    /// `data - prediction`.
    pub residuals: Vec<f64>,
    /// `[y, yd]` of the fitted trajectory at every sample time.
    pub states: Vec<[f64; 2]>,
}

/// The Jacobian, residuals and states of [`covariance`] (`2p + 1` integrations, 4 more with
/// `initial_steps`). `None` when an integration fails or `steps` has the wrong length.
pub(super) fn jacobian(optimum: &Optimum<'_>) -> Option<AtOptimum> {
    let Optimum {
        model,
        series,
        coefficients,
        init,
        output,
        steps,
        initial_steps,
    } = *optimum;
    let p = coefficients.len();
    if steps.len() != p {
        return None;
    }
    let at = |c: &[f64]| predict(model, series, c, init, COVARIANCE_RTOL, output);
    let states = trajectory(model, &series.t, coefficients, init, COVARIANCE_RTOL)?;
    let prediction = output_of(model, &series.t, coefficients, &states, output);
    let residuals: Vec<f64> = prediction
        .iter()
        .zip(&series.y)
        .map(|(m, y)| y - m)
        .collect();
    let extra = if initial_steps.is_some() { 2 } else { 0 };
    let mut jac = DMatrix::zeros(series.len(), p + extra);
    if let Some((hy, hv)) = initial_steps {
        let from = |init: InitialValues| {
            predict(model, series, coefficients, init, COVARIANCE_RTOL, output)
        };
        let y = |d: f64| InitialValues {
            y0: init.y0 + d,
            ..init
        };
        let v = |d: f64| InitialValues {
            v0: init.v0 + d,
            ..init
        };
        for (j, (plus, minus, h)) in [
            (from(y(hy))?, from(y(-hy))?, hy),
            (from(v(hv))?, from(v(-hv))?, hv),
        ]
        .into_iter()
        .enumerate()
        {
            for (i, (a, b)) in plus.iter().zip(&minus).enumerate() {
                jac[(i, p + j)] = (a - b) / (2.0 * h);
            }
        }
    }
    let mut c = coefficients.to_vec();
    for j in 0..p {
        let h = steps[j];
        c[j] = coefficients[j] + h;
        let plus = at(&c)?;
        c[j] = coefficients[j] - h;
        let minus = at(&c)?;
        c[j] = coefficients[j];
        for (i, (a, b)) in plus.iter().zip(&minus).enumerate() {
            jac[(i, j)] = (a - b) / (2.0 * h);
        }
    }
    Some(AtOptimum {
        jacobian: jac,
        residuals,
        states,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_line_matches_the_textbook_standard_errors() {
        // y = a + b x with known residuals: Cov = sigma^2 (X^T X)^-1 when they are uncorrelated
        // (ten residuals: no autocorrelation can exceed 4 / sqrt(10), so no lag is counted).
        let n = 10;
        let x: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let jac = DMatrix::from_fn(n, 2, |i, j| if j == 0 { 1.0 } else { x[i] });
        let residuals: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 0.1 } else { -0.1 })
            .collect();
        let cov = Covariance::from_jacobian(&jac, &residuals).unwrap();
        assert_eq!(cov.bandwidth, 0);
        let sigma2 = 0.1f64 * 0.1 * n as f64 / (n - 2) as f64;
        approx::assert_relative_eq!(cov.sigma2, sigma2, max_relative = 1e-12);
        let sxx: f64 = x.iter().map(|v| (v - 4.5) * (v - 4.5)).sum();
        // Var(b) = sigma^2 / Sxx.
        approx::assert_relative_eq!(cov.matrix[(1, 1)], sigma2 / sxx, max_relative = 1e-9);
        let sd_b = cov.std_dev_of(&[0.0, 1.0]).unwrap();
        approx::assert_relative_eq!(sd_b, (sigma2 / sxx).sqrt(), max_relative = 1e-9);
    }

    #[test]
    fn a_figure_on_an_undetermined_direction_has_no_standard_deviation() {
        // Columns 0 and 1 identical: only c0 + c1 is determined.
        let n = 20;
        let jac = DMatrix::from_fn(n, 3, |i, j| match j {
            0 | 1 => (i as f64 * 0.3).sin(),
            _ => (i as f64 * 0.7).cos(),
        });
        let residuals: Vec<f64> = (0..n).map(|i| 0.01 * ((i * 7) % 5) as f64 - 0.02).collect();
        let cov = Covariance::from_jacobian(&jac, &residuals).unwrap();
        assert_eq!(cov.rank, 2);
        // c0 alone depends on the undetermined c0 - c1: no interval, not NaN.
        assert_eq!(cov.std_dev_of(&[1.0, 0.0, 0.0]), None);
        // c0 + c1 is determined: a finite, positive standard deviation.
        let sd = cov.std_dev_of(&[1.0, 1.0, 0.0]).unwrap();
        assert!(sd.is_finite() && sd > 0.0, "{sd}");
        // Wrong length or non-finite gradient: None.
        assert_eq!(cov.std_dev_of(&[1.0, 1.0]), None);
        assert_eq!(cov.std_dev_of(&[f64::NAN, 1.0, 0.0]), None);
    }

    #[test]
    fn nothing_to_estimate_gives_none() {
        let zero = DMatrix::zeros(10, 2);
        assert!(Covariance::from_jacobian(&zero, &[0.1; 10]).is_none());
        let jac = DMatrix::from_fn(10, 2, |i, j| (i + j) as f64);
        assert!(Covariance::from_jacobian(&jac, &[0.1; 9]).is_none());
        let mut bad = vec![0.1; 10];
        bad[3] = f64::NAN;
        assert!(Covariance::from_jacobian(&jac, &bad).is_none());
        let short = DMatrix::from_fn(2, 2, |i, j| (i * 2 + j + 1) as f64);
        assert!(Covariance::from_jacobian(&short, &[0.1, 0.2]).is_none());
    }

    /// Seeded standard normal deviates (the simulator's generator).
    fn normals(seed: u64, n: usize) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    #[test]
    fn fixed_b_values_match_a_simulation() {
        // |t| of a mean with the Bartlett sum over M = b n lags, on white data: its 95th
        // percentile is the fixed-b critical value (the finite-n statistic converges to the
        // limit the polynomial was fitted to).
        let (n, reps) = (400, 10_000);
        let bs = [0.1, 0.25, 0.5];
        let lags: Vec<usize> = bs.iter().map(|b| (b * n as f64) as usize).collect();
        // |t| per draw and bandwidth: one draw, its autocovariances once, every bandwidth
        let mut t: Vec<Vec<f64>> = vec![Vec::with_capacity(reps); bs.len()];
        for r in 0..reps {
            let x = normals(r as u64 * 7919 + 1, n);
            let mean = x.iter().sum::<f64>() / n as f64;
            let u: Vec<f64> = x.iter().map(|v| v - mean).collect();
            let gamma: Vec<f64> = (0..lags[lags.len() - 1])
                .map(|k| {
                    u[..n - k]
                        .iter()
                        .zip(&u[k..])
                        .map(|(a, b)| a * b)
                        .sum::<f64>()
                        / n as f64
                })
                .collect();
            for (i, &m) in lags.iter().enumerate() {
                let omega = gamma[0]
                    + (1..m)
                        .map(|k| 2.0 * (1.0 - k as f64 / m as f64) * gamma[k])
                        .sum::<f64>();
                t[i].push(((n as f64).sqrt() * mean / omega.sqrt()).abs());
            }
        }
        for (b, mut t) in bs.into_iter().zip(t) {
            t.sort_by(f64::total_cmp);
            let simulated = t[reps * 95 / 100];
            let fitted = fixed_b_critical_value_95(b);
            assert!(
                (simulated - fitted).abs() < 0.12,
                "b {b}: simulated {simulated}, polynomial {fitted}"
            );
            // And far from the normal quantile the interval used before.
            assert!(fitted > 1.96 + 2.5 * b, "b {b}: {fitted}");
        }
        approx::assert_relative_eq!(fixed_b_critical_value_95(0.0), 1.959_964);
        assert_eq!(
            fixed_b_critical_value_95(f64::NAN),
            fixed_b_critical_value_95(1.0)
        );
    }

    #[test]
    fn coherent_residuals_are_covered_with_the_fixed_b_value() {
        // A sine's amplitude fitted through a narrow-band AR(2) response at the sine's own
        // frequency (what turbulent forcing leaves in a free-vibration fit): the residuals stay
        // coherent over a large share of the record, and the normal quantile covers the true
        // amplitude (zero) too rarely.
        let (n, reps, omega, r) = (1000, 1000, 0.3, 0.98);
        let jac = DMatrix::from_fn(n, 2, |i, j| {
            let phase = i as f64 * omega;
            if j == 0 {
                phase.sin()
            } else {
                phase.cos()
            }
        });
        let (mut normal, mut fixed_b, mut capped) = (0, 0, 0);
        for rep in 0..reps {
            let e = normals(rep as u64 * 104_729 + 3, n + 200);
            let (a1, a2) = (2.0 * r * omega.cos(), -r * r);
            let mut x = vec![0.0; n + 200];
            for i in 2..x.len() {
                x[i] = a1 * x[i - 1] + a2 * x[i - 2] + e[i];
            }
            let x = &x[200..];
            // Least squares of x on the two columns; residuals at the optimum.
            let beta = (jac.transpose() * &jac).try_inverse().unwrap()
                * jac.transpose()
                * DVector::from_column_slice(x);
            let fit = &jac * &beta;
            let residuals: Vec<f64> = x.iter().zip(fit.iter()).map(|(a, b)| a - b).collect();
            let cov = Covariance::from_jacobian(&jac, &residuals).unwrap();
            if cov.bandwidth == n / 4 {
                capped += 1;
            }
            let sd = cov.std_dev_of(&[1.0, 0.0]).unwrap();
            let t = beta[0].abs() / sd;
            normal += usize::from(t <= 1.959_964);
            fixed_b += usize::from(t <= cov.critical_value_95());
        }
        // Measured: the bandwidth at its cap in 336 of 1000, the fixed-b value covering 908
        // (91 %) and 1.96 covering 837 (84 %). Not 95 % either way: a Bartlett sum cut at the
        // correlation length still misses part of the long-run variance (docs/damping.md).
        let share = |k: usize| k as f64 / reps as f64;
        assert!(
            share(capped) > 0.25,
            "bandwidth capped in {capped} of {reps}"
        );
        assert!(
            share(fixed_b) >= 0.85,
            "fixed-b {fixed_b}, normal {normal} of {reps}"
        );
        assert!(
            share(normal) < share(fixed_b) - 0.04,
            "fixed-b {fixed_b}, normal {normal} of {reps}"
        );
    }

    #[test]
    fn narrow_band_residuals_widen_the_interval() {
        // A sine fitted with its amplitude as the coefficient: white residuals give the
        // textbook variance; residuals oscillating at the sine's own frequency (a forced
        // response the model treats as error) are coherent with the Jacobian and must give a
        // far larger one, not the white-noise figure.
        let n = 2000;
        let jac = DMatrix::from_fn(n, 1, |i, _| (i as f64 * 0.3).sin());
        let mut state = 12345u64;
        let white: Vec<f64> = (0..n)
            .map(|_| {
                // xorshift: deterministic white-ish residuals without a dependency.
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        let narrow: Vec<f64> = (0..n)
            .map(|i| 0.3 * (i as f64 * 0.3 + 0.4 * (i as f64 * 0.002).sin()).cos())
            .collect();
        let cov_white = Covariance::from_jacobian(&jac, &white).unwrap();
        let textbook = cov_white.sigma2 / jac.column(0).norm_squared();
        let var_white = cov_white.matrix[(0, 0)];
        assert!(
            (var_white / textbook - 1.0).abs() < 0.3,
            "white: {var_white} vs {textbook}, bandwidth {}",
            cov_white.bandwidth
        );
        let cov_narrow = Covariance::from_jacobian(&jac, &narrow).unwrap();
        let textbook = cov_narrow.sigma2 / jac.column(0).norm_squared();
        assert!(cov_narrow.bandwidth > 100, "{}", cov_narrow.bandwidth);
        assert!(
            cov_narrow.matrix[(0, 0)] > 10.0 * textbook,
            "{} vs {textbook}",
            cov_narrow.matrix[(0, 0)]
        );
    }
}
