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
        .map(|(s, &t)| output.value(model, t, s, coefficients))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The restoring force is `R` at `yd = 0`: on the worked example's equation it is `k*y`
    /// exactly, while the support force adds the damping force `(c1 + c2*yd^2)*yd`.
    #[test]
    fn the_restoring_force_leaves_out_the_terms_in_yd() {
        let model = Model::parse("19.14*ydd + (c1 + c2*yd^2)*yd + c3*y = 0", &[]).unwrap();
        let c = [-12.18, 447.3, 81360.0];
        let times: Vec<f64> = (0..400).map(|i| i as f64 / 200.0).collect();
        let init = InitialValues {
            y0: 0.3368e-3,
            v0: 5.8e-3,
        };
        let states = trajectory(&model, &times, &c, init, 1e-9).unwrap();
        let restoring = output_of(&model, &times, &c, &states, Output::RestoringForce);
        let support = output_of(&model, &times, &c, &states, Output::Force);
        let mut largest_damping_force = 0.0_f64;
        for ((s, r), f) in states.iter().zip(&restoring).zip(&support) {
            assert_eq!(*r, c[2] * s[0]);
            let damping = (c[0] + c[1] * s[1] * s[1]) * s[1];
            assert!((f - r - damping).abs() <= 1e-9 * r.abs().max(1e-3));
            largest_damping_force = largest_damping_force.max(damping.abs());
        }
        // The two outputs differ by about 2 zeta0 of the force's amplitude (0.97 % here).
        let largest = restoring.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!(
            largest_damping_force > 0.005 * largest,
            "{largest_damping_force} of {largest}"
        );
        assert!(Output::RestoringForce.is_force() && !Output::Displacement.is_force());
    }
}
