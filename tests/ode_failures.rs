//! Failure reports: where, why, and how many times were delivered.

use crate::ode_common;

use approx::assert_abs_diff_eq;
use gatewatch::ode::{integrate, Failure, Method, Options, System};
use ode_common::*;
use std::ops::ControlFlow;

/// `y' = y^2`, `y(0) = 1`: `y = 1 / (1 - t)` blows up at t = 1.
struct Riccati;
impl System<1> for Riccati {
    fn rhs(&self, _t: f64, y: &[f64; 1], dy: &mut [f64; 1]) {
        dy[0] = y[0] * y[0];
    }
}

/// `y' = -y`, but NaN for t > 1.5.
struct NanAfter;
impl System<1> for NanAfter {
    fn rhs(&self, t: f64, y: &[f64; 1], dy: &mut [f64; 1]) {
        dy[0] = if t > 1.5 { f64::NAN } else { -y[0] };
    }
}

fn run1<S: System<1>>(
    method: Method,
    sys: &S,
    y0: f64,
    times: &[f64],
    o: &Options,
) -> gatewatch::ode::Outcome {
    let mut delivered = 0;
    let outcome = integrate(method, sys, [y0], times, o, |i, y| {
        assert_eq!(i, delivered);
        assert!(y[0].is_finite());
        delivered += 1;
        ControlFlow::Continue(())
    });
    assert_eq!(outcome.reached, delivered);
    outcome
}

#[test]
fn blow_up_is_reported_near_the_singularity() {
    let times = linspace(0.0, 2.0, 21);
    for method in [Method::Dopri5, Method::Rosenbrock] {
        let outcome = run1(method, &Riccati, 1.0, &times, &opts(1e-6, 1e-9));
        let t = match outcome.failure {
            Some(Failure::BlowUp { t, value }) => {
                assert!(value > 1e12);
                t
            }
            Some(Failure::StepSizeUnderflow { t, .. }) => t,
            other => panic!("{method}: expected BlowUp or StepSizeUnderflow, got {other:?}"),
        };
        assert_abs_diff_eq!(t, 1.0, epsilon = 1e-6);
        // 0.0, 0.1, ..., 0.9 delivered; the numerical pole lags the exact one by ~1e-7, so
        // t = 1.0 itself may still be delivered (with a huge value), 1.1 never.
        assert!(
            (10..=11).contains(&outcome.reached),
            "{method}: {outcome:?}"
        );
    }
    // RK4 has no error control: it overshoots the pole but must stop shortly after it.
    let o = Options {
        substeps: 10,
        ..Options::default()
    };
    let outcome = run1(Method::Rk4, &Riccati, 1.0, &times, &o);
    match outcome.failure {
        Some(Failure::BlowUp { t, .. }) | Some(Failure::NonFinite { t }) => {
            assert!(t > 0.9 && t < 1.3, "t = {t}");
        }
        other => panic!("rk4: expected BlowUp/NonFinite, got {other:?}"),
    }
    assert!(outcome.reached >= 10 && outcome.reached < 14);
}

#[test]
fn a_lower_bound_is_respected() {
    let times = linspace(0.0, 2.0, 21);
    let o = Options {
        bound: 100.0,
        ..opts(1e-6, 1e-9)
    };
    for method in METHODS {
        let outcome = run1(method, &Riccati, 1.0, &times, &o);
        match outcome.failure {
            // y = 100 at t = 0.99
            Some(Failure::BlowUp { t, value }) => {
                assert!(value > 100.0);
                assert!(t > 0.98 && t <= 1.0, "{method}: t = {t}");
            }
            other => panic!("{method}: expected BlowUp, got {other:?}"),
        }
        assert_eq!(outcome.reached, 10, "{method}");
    }
}

#[test]
fn nan_is_reported_as_non_finite_where_it_starts() {
    let times = linspace(0.0, 3.0, 31);
    for method in [Method::Dopri5, Method::Rosenbrock] {
        let outcome = run1(method, &NanAfter, 1.0, &times, &opts(1e-6, 1e-9));
        match outcome.failure {
            Some(Failure::NonFinite { t }) => {
                assert!(t <= 1.5 && t > 1.5 - 1e-6, "{method}: t = {t}")
            }
            other => panic!("{method}: expected NonFinite, got {other:?}"),
        }
        // 0.0 .. 1.4 certainly, 1.5 only if a step ended exactly there.
        assert!(
            (15..=16).contains(&outcome.reached),
            "{method}: {outcome:?}"
        );
        assert!(outcome.stats.rejected > 0);
    }
    let outcome = run1(Method::Rk4, &NanAfter, 1.0, &times, &Options::default());
    // The step from 1.5 is the first to evaluate f beyond 1.5.
    assert_eq!(outcome.failure, Some(Failure::NonFinite { t: 1.5 }));
    assert_eq!(outcome.reached, 16);
}

#[test]
fn non_finite_initial_state_or_derivative() {
    let times = linspace(0.0, 1.0, 5);
    for method in METHODS {
        let outcome = run1(method, &Riccati, f64::NAN, &times, &Options::default());
        assert_eq!(outcome.failure, Some(Failure::NonFinite { t: 0.0 }));
        assert_eq!(outcome.reached, 0);
        let outcome = run1(method, &Riccati, 1e300, &times, &Options::default());
        assert!(matches!(outcome.failure, Some(Failure::BlowUp { t, .. }) if t == 0.0));
        assert_eq!(outcome.reached, 0);
    }
}

#[test]
fn observer_can_stop() {
    let sys = Oscillator::new(0.05, 2.0);
    let times = linspace(0.0, 10.0, 50);
    for method in METHODS {
        let mut seen = Vec::new();
        let outcome = integrate(
            method,
            &sys,
            [1.0, 0.0],
            &times,
            &Options::default(),
            |i, _| {
                seen.push(i);
                if i == 5 {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        );
        assert_eq!(outcome.failure, Some(Failure::Stopped { t: times[5] }));
        assert_eq!(outcome.reached, 6);
        assert_eq!(seen, vec![0, 1, 2, 3, 4, 5]);
        // Stopping at the initial state costs nothing.
        let outcome = integrate(
            method,
            &sys,
            [1.0, 0.0],
            &times,
            &Options::default(),
            |_, _| ControlFlow::Break(()),
        );
        assert_eq!(outcome.failure, Some(Failure::Stopped { t: 0.0 }));
        assert_eq!((outcome.reached, outcome.stats.rhs_evals), (1, 0));
    }
}

#[test]
fn work_limit() {
    let sys = Oscillator::new(0.05, 2.0);
    let times = linspace(0.0, 100.0, 500);
    for method in METHODS {
        let o = Options {
            max_rhs_evals: 200,
            ..opts(1e-8, 1e-10)
        };
        let (outcome, _) = run(method, &sys, [1.0, 0.0], &times, &o);
        match outcome.failure {
            Some(Failure::WorkLimit { t }) => {
                assert!(t >= times[outcome.reached - 1] && t < times[outcome.reached]);
            }
            other => panic!("{method}: expected WorkLimit, got {other:?}"),
        }
        assert!(outcome.stats.rhs_evals <= 200);
        assert_eq!(outcome.stats.rhs_evals, sys.calls.get());
        assert!(outcome.stats.rhs_evals > 150, "{method}: stopped too early");
        assert!(outcome.reached > 1 && outcome.reached < times.len());
        sys.calls.set(0);
    }
}

#[test]
fn step_limit() {
    let sys = Oscillator::new(0.05, 2.0);
    let times = linspace(0.0, 100.0, 500);
    for method in METHODS {
        let o = Options {
            max_steps: 30,
            ..opts(1e-8, 1e-10)
        };
        let (outcome, _) = run(method, &sys, [1.0, 0.0], &times, &o);
        match outcome.failure {
            Some(Failure::StepLimit { t }) => {
                assert!(t >= times[outcome.reached - 1] && t < times[outcome.reached]);
            }
            other => panic!("{method}: expected StepLimit, got {other:?}"),
        }
        assert_eq!(outcome.stats.accepted + outcome.stats.rejected, 30);
    }
}

/// A chattering `sign()` term, `y' = -sign(y)` from y = 1: the solution reaches 0 at t = 1 and
/// then has no classical continuation. With a tight tolerance the adaptive methods cannot step
/// across and must stop near t = 1 with a bounded amount of work (step-size underflow, or the
/// step limit); fixed-step RK4 just chatters through with its grid steps.
#[test]
fn chattering_rhs_stops_with_bounded_work() {
    struct Sign;
    impl System<1> for Sign {
        fn rhs(&self, _t: f64, y: &[f64; 1], dy: &mut [f64; 1]) {
            dy[0] = -y[0].signum();
        }
    }
    let times = linspace(0.0, 5.0, 11);
    for method in [Method::Dopri5, Method::Rosenbrock] {
        let o = Options {
            max_steps: 20_000,
            ..opts(1e-10, 1e-14)
        };
        let outcome = run1(method, &Sign, 1.0, &times, &o);
        let t = match outcome.failure {
            Some(Failure::StepSizeUnderflow { t, h }) => {
                assert!(h < 1e-12, "{method}: h = {h:e}");
                t
            }
            Some(Failure::StepLimit { t }) => t,
            other => panic!("{method}: expected underflow or step limit, got {other:?}"),
        };
        assert_abs_diff_eq!(t, 1.0, epsilon = 1e-3);
        // 0 and 0.5; 1.0 itself only if a step happened to end at or beyond it.
        assert!((2..=3).contains(&outcome.reached), "{method}: {outcome:?}");
        assert!(outcome.stats.accepted + outcome.stats.rejected <= 20_000);
    }
    let outcome = run1(Method::Rk4, &Sign, 1.0, &times, &Options::default());
    assert!(outcome.is_complete());
}

#[test]
fn options_validate() {
    assert!(Options::default().validate().is_ok());
    let bad = [
        Options {
            rtol: 0.0,
            ..Options::default()
        },
        Options {
            atol: f64::NAN,
            ..Options::default()
        },
        Options {
            substeps: 0,
            ..Options::default()
        },
        Options {
            max_steps: 0,
            ..Options::default()
        },
        Options {
            bound: -1.0,
            ..Options::default()
        },
        Options {
            initial_step: Some(0.0),
            ..Options::default()
        },
    ];
    for o in bad {
        assert!(o.validate().is_err(), "{o:?}");
    }
}

/// A NaN last time (a caller bug) must not make the adaptive methods loop on NaN steps.
#[test]
fn nan_time_stops_at_once() {
    let times = [0.0, 0.5, f64::NAN];
    for method in [Method::Dopri5, Method::Rosenbrock] {
        let outcome = run1(method, &NanAfter, 1.0, &times, &Options::default());
        assert!(
            matches!(outcome.failure, Some(Failure::StepSizeUnderflow { t, .. }) if t == 0.0),
            "{method}: {outcome:?}"
        );
        assert_eq!(outcome.stats.accepted + outcome.stats.rejected, 0);
    }
}
