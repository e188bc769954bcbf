//! The identified model's trajectory and prediction at the sample times.

use super::problem::Output;
use super::InitialValues;
use crate::data::TimeSeries;
use crate::model::{Bound, Model};
use crate::ode::{self, Method, Options};
use std::ops::ControlFlow;

/// The model's state `[y, yd]` at every sample time (Dormand-Prince at `rtol`), `None` on
/// failure.
pub fn trajectory(
    model: &Model,
    times: &[f64],
    coefficients: &[f64],
    init: InitialValues,
    rtol: f64,
) -> Option<Vec<[f64; 2]>> {
    let scale = init.y0.abs().max(init.v0.abs()).max(f64::MIN_POSITIVE);
    let opts = Options {
        rtol,
        atol: rtol * 1e-6 * scale,
        bound: 1e9 * scale,
        max_steps: 1_000_000,
        max_rhs_evals: 10_000_000,
        ..Options::default()
    };
    let mut out = vec![[0.0; 2]; times.len()];
    let sys = Bound {
        model,
        coeffs: coefficients,
    };
    let o = ode::integrate(
        Method::Dopri5,
        &sys,
        [init.y0, init.v0],
        times,
        &opts,
        |i, s| {
            out[i] = *s;
            ControlFlow::Continue(())
        },
    );
    o.is_complete().then_some(out)
}

/// The model's prediction of the data at every sample time: displacement, or support force
/// `R(t, y, yd)` (Dormand-Prince at `rtol`). `None` when the integration fails.
pub fn predict(
    model: &Model,
    series: &TimeSeries,
    coefficients: &[f64],
    init: InitialValues,
    rtol: f64,
    output: Output,
) -> Option<Vec<f64>> {
    let states = trajectory(model, &series.t, coefficients, init, rtol)?;
    Some(output_of(model, &series.t, coefficients, &states, output))
}

/// The prediction from a [`trajectory`] at `times`: what [`predict`] returns, for a caller that
/// needs both without integrating twice.
pub fn output_of(
    model: &Model,
    times: &[f64],
    coefficients: &[f64],
    states: &[[f64; 2]],
    output: Output,
) -> Vec<f64> {
    states
        .iter()
        .zip(times)
        .map(|(s, &t)| match output {
            Output::Displacement => s[0],
            Output::Force => model.residual(t, s[0], s[1], coefficients),
        })
        .collect()
}
