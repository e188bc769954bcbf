//! Accuracy of the integrators against analytic solutions.

use crate::ode_common;

use approx::{assert_abs_diff_eq, assert_relative_eq};
use gatewatch::ode::{integrate, Method, Options, Outcome, System};
use ode_common::*;
use std::f64::consts::PI;
use std::ops::ControlFlow;

/// Free damped oscillator, zeta = 0.05, w = 1, 3, 10, 20 periods, 400 outputs: the largest
/// position error (amplitude 1) stays below 5 * rtol for rtol = 1e-3, 1e-6, 1e-9 (atol =
/// rtol / 1000), and it decreases by at least 100x per 1000x tighter tolerance.
fn tolerance_proportionality(method: Method) {
    for &w in &[1.0, 3.0, 10.0] {
        let sys = Oscillator::new(0.05, w);
        let times = linspace(0.0, 20.0 * 2.0 * PI / w, 400);
        let mut previous = f64::INFINITY;
        for &tol in &[1e-3, 1e-6, 1e-9] {
            let (outcome, got) = run(method, &sys, [1.0, 0.0], &times, &opts(tol, tol * 1e-3));
            assert!(
                outcome.is_complete(),
                "{method} w={w} tol={tol}: {outcome:?}"
            );
            let err = max_error(&times, &got, |t| sys.exact(t, 1.0, 0.0));
            assert!(
                err < 5.0 * tol,
                "{method} w={w} tol={tol:e}: max error {err:e} exceeds 5 tol"
            );
            assert!(
                err < previous / 100.0,
                "{method} w={w}: error {err:e} at tol {tol:e} is not much below {previous:e}"
            );
            previous = err;
        }
    }
}

#[test]
fn dopri5_error_scales_with_rtol() {
    tolerance_proportionality(Method::Dopri5);
}

#[test]
fn rosenbrock_error_scales_with_rtol() {
    tolerance_proportionality(Method::Rosenbrock);
}

/// `2.5 y'' + 0.35 y' + 0.3 y = 3 sin(2.2 t)`, `y(0) = 0`, `y'(0) = 0.25` on [0, 60], 500
/// samples, against particular + homogeneous solution (both components).
#[test]
fn forced_oscillator_matches_analytic_solution() {
    let sys = Forced::chapter();
    // Sanity of the analytic solution itself: initial conditions.
    assert_abs_diff_eq!(sys.exact(0.0, 0.0, 0.25)[0], 0.0, epsilon = 1e-14);
    assert_abs_diff_eq!(sys.exact(0.0, 0.0, 0.25)[1], 0.25, epsilon = 1e-14);
    let times = linspace(0.0, 60.0, 500);
    let cases = [
        (Method::Dopri5, 1e-8, 1e-7),
        (Method::Rosenbrock, 1e-8, 1e-7),
        (
            Method::Rk4,
            1e-3, // tolerances unused by RK4
            1e-6, // 4 substeps of 0.03 s: error ~ 1e-8
        ),
    ];
    for (method, tol, allowed) in cases {
        let o = Options {
            substeps: 4,
            ..opts(tol, tol * 1e-3)
        };
        let (outcome, got) = run(method, &sys, [0.0, 0.25], &times, &o);
        assert!(outcome.is_complete(), "{method}: {outcome:?}");
        for (&t, y) in times.iter().zip(&got) {
            let exact = sys.exact(t, 0.0, 0.25);
            assert_abs_diff_eq!(y[0], exact[0], epsilon = allowed);
            assert_abs_diff_eq!(y[1], exact[1], epsilon = allowed);
        }
    }
}

/// RK4 on y'' + y = 0, 500 samples over 30 s: doubling the substeps divides the error by ~16.
#[test]
fn rk4_is_fourth_order() {
    let sys = Oscillator::new(0.0, 1.0);
    let times = linspace(0.0, 30.0, 500);
    let err = |substeps| {
        let o = Options {
            substeps,
            ..Options::default()
        };
        let (outcome, got) = run(Method::Rk4, &sys, [1.0, 0.0], &times, &o);
        assert!(outcome.is_complete());
        max_error(&times, &got, |t| sys.exact(t, 1.0, 0.0))
    };
    let (e1, e2, e4) = (err(1), err(2), err(4));
    assert_relative_eq!(e1 / e2, 16.0, max_relative = 0.1);
    assert_relative_eq!(e2 / e4, 16.0, max_relative = 0.1);
}

/// On the same grid RK4 with 2 substeps beats dopri5 at the default rtol 1e-3.
#[test]
fn rk4_with_substeps_beats_loose_dopri5_on_the_sample_grid() {
    let sys = Oscillator::new(0.0, 1.0);
    let times = linspace(0.0, 30.0, 500);
    let exact = |t| sys.exact(t, 1.0, 0.0);
    let (_, rk4) = run(Method::Rk4, &sys, [1.0, 0.0], &times, &Options::default());
    let (_, dp) = run(Method::Dopri5, &sys, [1.0, 0.0], &times, &opts(1e-3, 1e-6));
    let (e_rk4, e_dp) = (
        max_error(&times, &rk4, exact),
        max_error(&times, &dp, exact),
    );
    assert!(e_rk4 < e_dp, "rk4 {e_rk4:e} vs dopri5 {e_dp:e}");
    assert!(e_rk4 < 1e-6, "rk4 error {e_rk4:e}");
}

/// Negative damping (zeta = -0.05, w = 2): the amplitude grows ~20x over 30 s; every method
/// follows the analytic solution to a relative accuracy of 1e-5 of the final amplitude.
#[test]
fn growing_oscillator() {
    let sys = Oscillator::new(-0.05, 2.0);
    let times = linspace(0.0, 30.0, 300);
    let amplitude = (0.05 * 2.0 * 30.0_f64).exp();
    for method in METHODS {
        let o = Options {
            substeps: 8,
            ..opts(1e-8, 1e-10)
        };
        let (outcome, got) = run(method, &sys, [1.0, 0.0], &times, &o);
        assert!(outcome.is_complete(), "{method}: {outcome:?}");
        let err = max_error(&times, &got, |t| sys.exact(t, 1.0, 0.0));
        assert!(err < 1e-5 * amplitude, "{method}: error {err:e}");
        assert_relative_eq!(
            got.last().unwrap()[0],
            sys.exact(30.0, 1.0, 0.0)[0],
            max_relative = 1e-5
        );
    }
}

/// Irregular output times (clustered, several inside one step, some far apart): every state is
/// delivered at exactly the requested time.
#[test]
fn output_at_irregular_times() {
    let sys = Oscillator::new(0.05, 3.0);
    let mut times: Vec<f64> = (0..60)
        .map(|i| 12.0 * (i as f64 / 59.0).powf(1.7) + 0.013 * ((i * 7919) % 13) as f64)
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    times.insert(1, times[0] + 1e-7);
    for method in METHODS {
        let o = Options {
            substeps: 16,
            ..opts(1e-9, 1e-12)
        };
        let (outcome, got) = run(method, &sys, [1.0, 0.0], &times, &o);
        assert!(outcome.is_complete(), "{method}: {outcome:?}");
        assert_eq!(got.len(), times.len());
        // RK4's steps follow the grid: up to 0.34 s / 16 with w = 3, global error ~ 1e-7..1e-6.
        let tol = if method == Method::Rk4 { 3e-6 } else { 1e-7 };
        for (&t, y) in times.iter().zip(&got) {
            let exact = sys.exact(t, 1.0, 0.0);
            let (e0, e1) = ((y[0] - exact[0]).abs(), (y[1] - exact[1]).abs());
            assert!(
                e0 < tol && e1 < 3.0 * tol,
                "{method} t={t}: errors {e0:e} {e1:e}"
            );
        }
    }
}

/// The first output is y0 itself; a time grid not starting at 0 works (the system is
/// autonomous, so the solution is the shifted one).
#[test]
fn first_output_is_the_initial_state_and_t0_may_be_nonzero() {
    let sys = Oscillator::new(0.05, 1.0);
    let times: Vec<f64> = linspace(100.0, 110.0, 50);
    for method in METHODS {
        let (outcome, got) = run(method, &sys, [0.3, -0.2], &times, &opts(1e-9, 1e-12));
        assert!(outcome.is_complete());
        assert_eq!(got[0], [0.3, -0.2]);
        let exact = sys.exact(10.0, 0.3, -0.2);
        let tol = if method == Method::Rk4 { 1e-5 } else { 1e-7 };
        assert_abs_diff_eq!(got[49][0], exact[0], epsilon = tol);
    }
}

/// Van der Pol with mu = 1000 from (2, 0) over [0, 3000] (almost two relaxation periods of
/// ~1614): Rodas4 completes in a few hundred steps, with the first zero crossing near the
/// half period (3 - 2 ln 2) mu / 2 ~ 807; dopri5 runs into its step limit.
#[test]
fn van_der_pol_stiff() {
    let vdp = VanDerPol { mu: 1000.0 };
    let times = linspace(0.0, 3000.0, 3001);
    let o = opts(1e-4, 1e-6);
    let (stiff, got) = run(Method::Rosenbrock, &vdp, [2.0, 0.0], &times, &o);
    assert!(stiff.is_complete(), "{stiff:?}");
    let steps = stiff.stats.accepted + stiff.stats.rejected;
    assert!(steps < 1_000, "Rodas4 needed {steps} steps");
    let cross = got.iter().position(|y| y[0] < 0.0).unwrap() as f64;
    assert_abs_diff_eq!(cross, 807.0, epsilon = 5.0);
    assert!(got.iter().all(|y| y[0].abs() < 2.02));

    let limit = Options {
        max_steps: 50 * steps,
        ..o
    };
    let (explicit, _) = run(Method::Dopri5, &vdp, [2.0, 0.0], &times, &limit);
    match explicit.failure {
        Some(gatewatch::ode::Failure::StepLimit { t }) => {
            assert!(t > 0.0 && t < 3000.0);
            assert!(explicit.reached < times.len());
            assert!(times[explicit.reached - 1] <= t);
            assert!(t < times[explicit.reached]);
        }
        other => panic!("expected StepLimit, got {other:?}"),
    }
    assert_eq!(
        explicit.stats.accepted + explicit.stats.rejected,
        50 * steps
    );
}

/// Every method reports exactly the right-hand-side evaluations it made, and the documented
/// formulas hold exactly.
#[test]
fn stats_accounting() {
    let times = linspace(0.0, 20.0, 200);
    for method in METHODS {
        for initial_step in [None, Some(0.01)] {
            let sys = Oscillator::new(0.05, 2.0);
            let o = Options {
                initial_step,
                substeps: 3,
                ..opts(1e-6, 1e-9)
            };
            let (outcome, _) = run(method, &sys, [1.0, 0.0], &times, &o);
            assert!(outcome.is_complete());
            let s = outcome.stats;
            assert_eq!(s.rhs_evals, sys.calls.get(), "{method}: counted vs made");
            let hinit = usize::from(initial_step.is_none());
            let steps = s.accepted + s.rejected;
            match method {
                Method::Dopri5 => {
                    assert_eq!(s.rhs_evals, 1 + hinit + 6 * steps);
                    assert_eq!((s.jacobian_evals, s.lu_decompositions), (0, 0));
                }
                Method::Rk4 => {
                    assert_eq!(s.accepted, 3 * (times.len() - 1));
                    assert_eq!(s.rejected, 0);
                    assert_eq!(s.rhs_evals, 4 * s.accepted);
                }
                Method::Rosenbrock => {
                    // default finite-difference Jacobian: N + 1 = 3; non-autonomous: f_t, 1.
                    assert_eq!(
                        s.rhs_evals,
                        hinit + s.jacobian_evals * (1 + 3 + 1) + 5 * steps
                    );
                    assert_eq!(s.jacobian_evals, s.accepted);
                    assert_eq!(s.lu_decompositions, steps);
                }
            }
        }
    }
}

/// An analytic Jacobian with `jacobian_cost() == 0` and `is_autonomous() == true` changes the
/// Rosenbrock accounting accordingly, and gives the same accuracy.
#[test]
fn rosenbrock_with_analytic_jacobian() {
    struct Analytic(Oscillator);
    impl System<2> for Analytic {
        fn rhs(&self, t: f64, y: &[f64; 2], dy: &mut [f64; 2]) {
            self.0.rhs(t, y, dy)
        }
        fn jacobian(&self, _t: f64, _y: &[f64; 2], jac: &mut [[f64; 2]; 2]) {
            let (z, w) = (self.0.zeta, self.0.w);
            *jac = [[0.0, 1.0], [-w * w, -2.0 * z * w]];
        }
        fn jacobian_cost(&self) -> usize {
            0
        }
        fn is_autonomous(&self) -> bool {
            true
        }
    }
    let sys = Analytic(Oscillator::new(0.05, 2.0));
    let times = linspace(0.0, 20.0, 200);
    let (outcome, got) = run(
        Method::Rosenbrock,
        &sys,
        [1.0, 0.0],
        &times,
        &opts(1e-7, 1e-10),
    );
    assert!(outcome.is_complete());
    let s = outcome.stats;
    assert_eq!(s.rhs_evals, sys.0.calls.get());
    assert_eq!(
        s.rhs_evals,
        1 + s.jacobian_evals + 5 * (s.accepted + s.rejected)
    );
    let err = max_error(&times, &got, |t| sys.0.exact(t, 1.0, 0.0));
    assert!(err < 5e-7, "error {err:e}");
}

/// Empty `times`: nothing happens. One time: only y0 is delivered, no evaluation.
#[test]
fn empty_and_single_time() {
    let sys = Oscillator::new(0.05, 2.0);
    for method in METHODS {
        let mut calls = 0;
        let outcome: Outcome = integrate(
            method,
            &sys,
            [1.0, 0.0],
            &[],
            &Options::default(),
            |_, _| {
                calls += 1;
                ControlFlow::Continue(())
            },
        );
        assert_eq!((outcome.reached, calls), (0, 0));
        assert!(outcome.is_complete());
        let (outcome, got) = run(method, &sys, [1.0, 0.0], &[3.0], &Options::default());
        assert!(outcome.is_complete());
        assert_eq!(outcome.reached, 1);
        assert_eq!(got, vec![[1.0, 0.0]]);
        assert_eq!(outcome.stats.rhs_evals, 0);
    }
    assert_eq!(sys.calls.get(), 0);
}
