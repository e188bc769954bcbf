//! Classical fixed-step fourth-order Runge-Kutta on the output grid.
//!
//! Between consecutive output times `times[i-1]` and `times[i]` it takes `Options::substeps`
//! (at least 1) equal steps `h = (times[i] - times[i-1]) / substeps` of the classical RK4
//! tableau (Kutta 1901; Hairer, Norsett & Wanner, *Solving ODEs I*, Table II.1.2), so every
//! output lands exactly on a step and no interpolation is needed. Step times are computed as
//! `times[i-1] + j*h` (no accumulated rounding). There is no error control: on the DE's
//! uniformly sampled, mildly nonlinear models this is the cheapest method for a given accuracy.
//!
//! Failures: the state after every step is checked; a non-finite state gives
//! [`Failure::NonFinite`] at the start of that step (the last time the state was finite), a
//! component above `Options::bound` gives [`Failure::BlowUp`] at the end of the step. Before
//! each step, [`Failure::StepLimit`] if `accepted == max_steps` and [`Failure::WorkLimit`] if the
//! step's 4 evaluations would exceed `max_rhs_evals`. [`Failure::StepSizeUnderflow`] never
//! occurs (the step is fixed by the grid).
//!
//! Right-hand-side accounting (exact): `rhs_evals = 4 * accepted`, `rejected = 0`.

#![allow(clippy::needless_range_loop)] // indexed loops over N mirror the formulas

use super::util::{all_finite, norm_inf, stop};
use super::{Failure, Options, Outcome, Stats, System};
use std::ops::ControlFlow;

pub(super) fn integrate<const N: usize, S, F>(
    sys: &S,
    y0: [f64; N],
    times: &[f64],
    opts: &Options,
    mut observe: F,
) -> Outcome
where
    S: System<N> + ?Sized,
    F: FnMut(usize, &[f64; N]) -> ControlFlow<()>,
{
    let mut stats = Stats::default();
    let n_out = times.len();
    if n_out == 0 {
        return Outcome {
            reached: 0,
            stats,
            failure: None,
        };
    }
    let t0 = times[0];
    if let Some(f) = super::util::check_state(&y0, t0, opts.bound) {
        return stop(0, stats, f);
    }
    if observe(0, &y0).is_break() {
        return stop(1, stats, Failure::Stopped { t: t0 });
    }
    let m = opts.substeps.max(1);
    let mf = m as f64;
    let mut y = y0;
    let (mut k1, mut k2, mut k3, mut k4) = ([0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    let mut ys = [0.0; N];
    for out in 1..n_out {
        let ta = times[out - 1];
        let tb = times[out];
        let h = (tb - ta) / mf;
        let h2 = 0.5 * h;
        let h6 = h / 6.0;
        for j in 0..m {
            let t = if j == 0 { ta } else { ta + j as f64 * h };
            if stats.accepted >= opts.max_steps {
                return stop(out, stats, Failure::StepLimit { t });
            }
            if stats.rhs_evals + 4 > opts.max_rhs_evals {
                return stop(out, stats, Failure::WorkLimit { t });
            }
            let tn = if j + 1 == m {
                tb
            } else {
                ta + (j + 1) as f64 * h
            };
            let tm = t + h2;
            sys.rhs(t, &y, &mut k1);
            for i in 0..N {
                ys[i] = y[i] + h2 * k1[i];
            }
            sys.rhs(tm, &ys, &mut k2);
            for i in 0..N {
                ys[i] = y[i] + h2 * k2[i];
            }
            sys.rhs(tm, &ys, &mut k3);
            for i in 0..N {
                ys[i] = y[i] + h * k3[i];
            }
            sys.rhs(tn, &ys, &mut k4);
            for i in 0..N {
                ys[i] = y[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
            }
            stats.rhs_evals += 4;
            stats.accepted += 1;
            if !all_finite(&ys) {
                return stop(out, stats, Failure::NonFinite { t });
            }
            let mag = norm_inf(&ys);
            if mag > opts.bound {
                return stop(out, stats, Failure::BlowUp { t: tn, value: mag });
            }
            y = ys;
        }
        if observe(out, &y).is_break() {
            return stop(out + 1, stats, Failure::Stopped { t: tb });
        }
    }
    Outcome {
        reached: n_out,
        stats,
        failure: None,
    }
}
