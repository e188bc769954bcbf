//! Dormand-Prince 5(4) with Hairer's step control and dense output.
//!
//! The tableau, error coefficients, step-size controller and continuous extension are those of
//! Hairer's `DOPRI5` (E. Hairer, S. P. Norsett, G. Wanner, *Solving Ordinary Differential
//! Equations I*, 2nd ed., Springer 1993, sec. II.5 and II.6; J. R. Dormand, P. J. Prince,
//! "A family of embedded Runge-Kutta formulae", J. Comp. Appl. Math. 6, 1980):
//!
//! - seven stages, FSAL (the last stage of a step is the first of the next): 6 evaluations per
//!   step attempt;
//! - error norm `err = sqrt(1/N * sum_i (e_i / sc_i)^2)`, `sc_i = atol + rtol * max(|y_i|,
//!   |ynew_i|)`, `e = h * sum_j (b_j - bhat_j) k_j`; the step is accepted when `err <= 1`;
//! - PI (Lund) controller with `beta = 0.04`: `fac = err^(0.2 - 0.75 beta) / errold^beta`,
//!   `hnew = h / clamp(fac / 0.9, 1/10, 5)` (so `0.2 <= hnew/h <= 10`), no growth right after a
//!   rejection, `h <= t_end - t0`;
//! - initial step from Hairer's `HINIT` when `Options::initial_step` is `None` (one extra
//!   evaluation);
//! - output by the 4th-order continuous extension (Hairer's `CONTD5` coefficients), computed
//!   once per step that contains an output time: steps are never cut at output times, only the
//!   last step is stretched or shrunk (by at most 1 %) to end exactly at the last time, so that
//!   the right-hand side is never evaluated beyond it.
//!
//! Non-finite trial steps (a stage, the new state or the error is NaN/inf) count as rejected
//! steps and shrink `h` by 5; only when `h` falls below the underflow floor that way is
//! [`Failure::NonFinite`] reported, at the last accepted time.
//!
//! Right-hand-side accounting (exact): `rhs_evals = 1 + [hinit] + 6 * (accepted + rejected)`
//! for `times.len() >= 2` (`0` for fewer), where `[hinit]` is 1 when the initial step was
//! chosen automatically.

#![allow(clippy::needless_range_loop)] // indexed loops over N mirror the formulas

use super::util::{begin, deliver, hinit, norm_inf, stop, user_initial_step, NONFINITE_SHRINK};
use super::{Failure, Options, Outcome, Stats, System};
use std::ops::ControlFlow;

pub(super) const C2: f64 = 1.0 / 5.0;
pub(super) const C3: f64 = 3.0 / 10.0;
pub(super) const C4: f64 = 4.0 / 5.0;
pub(super) const C5: f64 = 8.0 / 9.0;
pub(super) const A21: f64 = 1.0 / 5.0;
pub(super) const A31: f64 = 3.0 / 40.0;
pub(super) const A32: f64 = 9.0 / 40.0;
pub(super) const A41: f64 = 44.0 / 45.0;
pub(super) const A42: f64 = -56.0 / 15.0;
pub(super) const A43: f64 = 32.0 / 9.0;
pub(super) const A51: f64 = 19372.0 / 6561.0;
pub(super) const A52: f64 = -25360.0 / 2187.0;
pub(super) const A53: f64 = 64448.0 / 6561.0;
pub(super) const A54: f64 = -212.0 / 729.0;
pub(super) const A61: f64 = 9017.0 / 3168.0;
pub(super) const A62: f64 = -355.0 / 33.0;
pub(super) const A63: f64 = 46732.0 / 5247.0;
pub(super) const A64: f64 = 49.0 / 176.0;
pub(super) const A65: f64 = -5103.0 / 18656.0;
pub(super) const A71: f64 = 35.0 / 384.0;
pub(super) const A73: f64 = 500.0 / 1113.0;
pub(super) const A74: f64 = 125.0 / 192.0;
pub(super) const A75: f64 = -2187.0 / 6784.0;
pub(super) const A76: f64 = 11.0 / 84.0;
pub(super) const E1: f64 = 71.0 / 57600.0;
pub(super) const E3: f64 = -71.0 / 16695.0;
pub(super) const E4: f64 = 71.0 / 1920.0;
pub(super) const E5: f64 = -17253.0 / 339200.0;
pub(super) const E6: f64 = 22.0 / 525.0;
pub(super) const E7: f64 = -1.0 / 40.0;
pub(super) const D1: f64 = -12715105075.0 / 11282082432.0;
pub(super) const D3: f64 = 87487479700.0 / 32700410799.0;
pub(super) const D4: f64 = -10690763975.0 / 1880347072.0;
pub(super) const D5: f64 = 701980252875.0 / 199316789632.0;
pub(super) const D6: f64 = -1453857185.0 / 822651844.0;
pub(super) const D7: f64 = 69997945.0 / 29380423.0;

pub(super) const SAFE: f64 = 0.9;
pub(super) const BETA: f64 = 0.04;
pub(super) const EXPO1: f64 = 0.2 - BETA * 0.75;
/// `1 / (smallest hnew/h)`.
pub(super) const FACC1: f64 = 1.0 / 0.2;
/// `1 / (largest hnew/h)`.
pub(super) const FACC2: f64 = 1.0 / 10.0;
/// `ln(1e-4)`: the smallest error the PI controller remembers.
pub(super) const LN_ERR_MIN: f64 = -9.210340371976182;

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
    let (t0, t_end, hmax, hmin) = match begin(times, &y0, opts, &mut observe) {
        Ok(span) => span,
        Err(done) => return done,
    };

    let mut t = t0;
    let mut y = y0;
    let mut k1 = [0.0; N];
    if opts.max_rhs_evals < 1 {
        return stop(1, stats, Failure::WorkLimit { t });
    }
    sys.rhs(t, &y, &mut k1);
    stats.rhs_evals += 1;
    if !super::util::all_finite(&k1) {
        return stop(1, stats, Failure::NonFinite { t });
    }
    let mut h = match user_initial_step(opts, hmax) {
        Some(h) => h,
        None => {
            if stats.rhs_evals + 1 > opts.max_rhs_evals {
                return stop(1, stats, Failure::WorkLimit { t });
            }
            stats.rhs_evals += 1;
            hinit(sys, t, &y, &k1, hmax, 5, opts)
        }
    };

    let mut next = 1; // index of the next output time
                      // ln of the previous accepted error (Hairer's FACOLD, initially 1e-4); the controller works
                      // with logarithms so that a step costs one `ln` and one `exp` instead of two `powf`.
    let mut ln_facold: f64 = LN_ERR_MIN;
    let mut reject = false;
    let mut nonfinite = false; // the last rejection was a non-finite trial
    let (mut k2, mut k3, mut k4, mut k5, mut k6, mut k7) =
        ([0.0; N], [0.0; N], [0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    let mut ys = [0.0; N];
    let mut ynew = [0.0; N];

    loop {
        if stats.accepted + stats.rejected >= opts.max_steps {
            return stop(next, stats, Failure::StepLimit { t });
        }
        if stats.rhs_evals + 6 > opts.max_rhs_evals {
            return stop(next, stats, Failure::WorkLimit { t });
        }
        if h.is_nan() || h < hmin {
            let f = if nonfinite {
                Failure::NonFinite { t }
            } else {
                Failure::StepSizeUnderflow { t, h }
            };
            return stop(next, stats, f);
        }
        let last = t + 1.01 * h >= t_end;
        if last {
            h = t_end - t;
        }

        // --- the six new stages (k1 is known: FSAL) ---
        for i in 0..N {
            ys[i] = y[i] + h * A21 * k1[i];
        }
        sys.rhs(t + C2 * h, &ys, &mut k2);
        for i in 0..N {
            ys[i] = y[i] + h * (A31 * k1[i] + A32 * k2[i]);
        }
        sys.rhs(t + C3 * h, &ys, &mut k3);
        for i in 0..N {
            ys[i] = y[i] + h * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i]);
        }
        sys.rhs(t + C4 * h, &ys, &mut k4);
        for i in 0..N {
            ys[i] = y[i] + h * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i]);
        }
        sys.rhs(t + C5 * h, &ys, &mut k5);
        for i in 0..N {
            ys[i] =
                y[i] + h * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i] + A65 * k5[i]);
        }
        let tnew = if last { t_end } else { t + h };
        sys.rhs(tnew, &ys, &mut k6);
        for i in 0..N {
            ynew[i] =
                y[i] + h * (A71 * k1[i] + A73 * k3[i] + A74 * k4[i] + A75 * k5[i] + A76 * k6[i]);
        }
        sys.rhs(tnew, &ynew, &mut k7);
        stats.rhs_evals += 6;

        // --- error estimate ---
        let mut err = 0.0;
        let mut finite = true;
        for i in 0..N {
            let e =
                h * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i] + E7 * k7[i]);
            let sk = opts.atol + opts.rtol * y[i].abs().max(ynew[i].abs());
            err += (e / sk) * (e / sk);
            finite &= ynew[i].is_finite() & k7[i].is_finite() & k2[i].is_finite();
        }
        let err = (err / N as f64).sqrt();
        if !(finite && err.is_finite()) {
            stats.rejected += 1;
            reject = true;
            nonfinite = true;
            h *= NONFINITE_SHRINK;
            continue;
        }

        let ln_err = err.ln(); // -inf for err == 0, which the clamps below handle
        if err <= 1.0 {
            // --- accepted ---
            stats.accepted += 1;
            // fac = err^EXPO1 / facold^BETA / SAFE
            let fac = ((EXPO1 * ln_err - BETA * ln_facold).exp() / SAFE).clamp(FACC2, FACC1);
            let mut hnew = h / fac;
            ln_facold = ln_err.max(LN_ERR_MIN);
            let m = norm_inf(&ynew);
            if m > opts.bound {
                return stop(next, stats, Failure::BlowUp { t: tnew, value: m });
            }
            // Deliver every output time in (t, tnew].
            if times[next] <= tnew {
                // Dense-output coefficients, once per step.
                let mut r1 = [0.0; N];
                let mut r2 = [0.0; N];
                let mut r3 = [0.0; N];
                let mut r4 = [0.0; N];
                if times[next] < tnew {
                    for i in 0..N {
                        let ydiff = ynew[i] - y[i];
                        let bspl = h * k1[i] - ydiff;
                        r1[i] = ydiff;
                        r2[i] = bspl;
                        r3[i] = ydiff - h * k7[i] - bspl;
                        r4[i] = h
                            * (D1 * k1[i]
                                + D3 * k3[i]
                                + D4 * k4[i]
                                + D5 * k5[i]
                                + D6 * k6[i]
                                + D7 * k7[i]);
                    }
                }
                let inv_h = 1.0 / h;
                let dense = |s: f64, s1: f64| {
                    let mut yo = [0.0; N];
                    for i in 0..N {
                        yo[i] = y[i] + s * (r1[i] + s1 * (r2[i] + s * (r3[i] + s1 * r4[i])));
                    }
                    yo
                };
                let span = (t, tnew, inv_h);
                if let Some(done) =
                    deliver(times, &mut next, span, &ynew, stats, &mut observe, dense)
                {
                    return done;
                }
            }
            hnew = hnew.min(hmax);
            if reject {
                hnew = hnew.min(h);
            }
            reject = false;
            nonfinite = false;
            t = tnew;
            y = ynew;
            k1 = k7;
            h = hnew;
        } else {
            // --- rejected ---
            stats.rejected += 1;
            reject = true;
            nonfinite = false;
            h /= ((EXPO1 * ln_err).exp() / SAFE).min(FACC1);
        }
    }
}
