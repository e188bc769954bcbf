//! The 95 % interval of a model-based zeta0: the coefficients' covariance at the least-squares
//! optimum ([`identify::covariance`]) through the delta method on `zeta0 = C0 / (2 sqrt(K0 M0))`
//! (see `docs/damping.md`, "zeta0_interval").

use super::linearisation::Linearization;
use crate::data::TimeSeries;
use crate::identify::{self, InitialValues, Output};
use crate::model::Model;

/// Two-sided 95 % normal quantile.
const Z95: f64 = 1.959_963_984_540_054;

/// A fitted model as the interval needs it: the model, its coefficients, their DE scales (for
/// the difference steps), the initial conditions and the output that was fitted.
#[derive(Debug, Clone, Copy)]
pub struct FittedModel<'a> {
    /// The model.
    pub model: &'a Model,
    /// Its fitted coefficients `c1..cN`.
    pub coefficients: &'a [f64],
    /// The DE scales of the coefficients (empty: 1).
    pub scales: &'a [f64],
    /// The initial conditions of the fit (held fixed).
    pub initial: InitialValues,
    /// What the fit compared with the data.
    pub output: Output,
}

/// `zeta0 +- 1.96 sd` for the model linearised at `(t0, 0, 0)` with the difference steps of
/// [`Linearization::of`] set by `y_scale` and `v_scale`. `None` (never NaN) when the model has
/// no zeta0, an integration fails, or the covariance cannot say anything about zeta0 (a
/// singular Jacobian along a direction zeta0 depends on).
pub fn zeta0_interval(
    fit: &FittedModel<'_>,
    data: &TimeSeries,
    t0: f64,
    y_scale: f64,
    v_scale: f64,
) -> Option<(f64, f64)> {
    let zeta0 = |c: &[f64]| Linearization::of(fit.model, c, t0, y_scale, v_scale).zeta0();
    let z = zeta0(fit.coefficients)?;
    let steps = identify::difference_steps(fit.coefficients, fit.scales);
    // Gradient first: it costs no integration, and a model without zeta0 nearby needs none.
    let mut c = fit.coefficients.to_vec();
    let mut gradient = Vec::with_capacity(c.len());
    for (j, h) in steps.iter().enumerate() {
        c[j] = fit.coefficients[j] + h;
        let plus = zeta0(&c)?;
        c[j] = fit.coefficients[j] - h;
        let minus = zeta0(&c)?;
        c[j] = fit.coefficients[j];
        gradient.push((plus - minus) / (2.0 * h));
    }
    let cov = identify::covariance(
        fit.model,
        data,
        fit.coefficients,
        fit.initial,
        fit.output,
        &steps,
    )?;
    let sd = cov.std_dev_of(&gradient)?;
    let (lo, hi) = (z - Z95 * sd, z + Z95 * sd);
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}
