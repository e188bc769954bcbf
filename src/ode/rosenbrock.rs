//! Rodas4: a stiffly accurate, L-stable Rosenbrock method of order 4 with an embedded order-3
//! error estimate and a third-order dense output.
//!
//! Coefficients: Hairer & Wanner's `RODAS` (`ROCOE`, `METH = 1`), E. Hairer, G. Wanner,
//! *Solving Ordinary Differential Equations II: Stiff and Differential-Algebraic Problems*,
//! 2nd ed., Springer 1996, sec. IV.7 (Table 7.2 and the code `rodas.f`). Each step solves
//! six linear systems with the one matrix `E = I/(h*gamma) - J`, `gamma = 1/4`:
//!
//! `E k_i = f(t + c_i h, y + sum_j a_ij k_j) + sum_j (c_ij/h) k_j + h d_i f_t`,
//!
//! `ynew = y + a5.. + k5 + k6` (stiffly accurate); the embedded solution is `ynew - k6`, so the
//! local error estimate is `k6`.
//!
//! - Error norm `err = sqrt(1/N * sum_i (k6_i / sc_i)^2)`, `sc_i = atol + rtol * max(|y_i|,
//!   |ynew_i|)`; accept when `err <= 1`.
//! - Step control as in `rodas.f`: `hnew = h / clamp(err^(1/4) / 0.9, 1/6, 5)` (so
//!   `0.2 <= hnew/h <= 6`), with Gustafsson's predictive controller after the first accepted
//!   step, no growth right after a rejection, `h <= t_end - t0`.
//! - The Jacobian comes from [`System::jacobian`] (once per accepted point; rejected steps reuse
//!   it and only refactorise). `f_t` is a forward difference (one extra evaluation) unless
//!   [`System::is_autonomous`]. The LU factorisation with partial pivoting is done here on a
//!   stack `nalgebra::SMatrix<f64, N, N>`: nalgebra's own `lu()` needs `DimMin` bounds that a
//!   generic `const N` cannot satisfy.
//! - Output at requested times by the method's continuous extension (`CONTRO` in `rodas.f`);
//!   steps are not cut at output times, only the last step ends exactly at the last time.
//! - Initial step: Hairer's `HINIT` (order 4) unless `Options::initial_step` is given.
//!
//! Failures: a non-finite stage, new state or error estimate, or an exactly singular `E`,
//! counts as a rejected step and shrinks `h` by 5 ([`Failure::NonFinite`] at the last accepted
//! time if that persists down to the underflow floor). A non-finite `f(t, y)`, Jacobian or `f_t`
//! at an accepted point does not depend on `h` and fails at once with [`Failure::NonFinite`].
//!
//! Right-hand-side accounting (exact), with `c = sys.jacobian_cost()` and `a = 0` if the system
//! is autonomous, else 1:
//! `rhs_evals = [hinit] + jacobian_evals * (1 + c + a) + 5 * (accepted + rejected)`, and
//! `lu_decompositions = accepted + rejected`.

#![allow(clippy::needless_range_loop)] // indexed loops over N mirror the formulas

use super::util::{
    all_finite, begin, deliver, hinit, norm_inf, stop, user_initial_step, NONFINITE_SHRINK,
};
use super::{Failure, Options, Outcome, Stats, System};
use nalgebra::SMatrix;
use std::ops::ControlFlow;

const GAMMA: f64 = 0.25;
const C2: f64 = 0.386;
const C3: f64 = 0.21;
const C4: f64 = 0.63;
const D1: f64 = 0.25;
const D2: f64 = -0.1043;
const D3: f64 = 0.1035;
const D4: f64 = -0.03620000000000023;
const A21: f64 = 1.544;
const A31: f64 = 0.9466785280815826;
const A32: f64 = 0.2557011698983284;
const A41: f64 = 3.314825187068521;
const A42: f64 = 2.896124015972201;
const A43: f64 = 0.9986419139977817;
const A51: f64 = 1.221224509226641;
const A52: f64 = 6.019134481288629;
const A53: f64 = 12.53708332932087;
const A54: f64 = -0.687886036105895;
const C21: f64 = -5.6688;
const C31: f64 = -2.430093356833875;
const C32: f64 = -0.2063599157091915;
const C41: f64 = -0.1073529058151375;
const C42: f64 = -9.594562251023355;
const C43: f64 = -20.47028614809616;
const C51: f64 = 7.496443313967647;
const C52: f64 = -10.24680431464352;
const C53: f64 = -33.99990352819905;
const C54: f64 = 11.7089089320616;
const C61: f64 = 8.083246795921522;
const C62: f64 = -7.981132988064893;
const C63: f64 = -31.52159432874371;
const C64: f64 = 16.31930543123136;
const C65: f64 = -6.058818238834054;
const D21: f64 = 10.12623508344586;
const D22: f64 = -7.487995877610167;
const D23: f64 = -34.80091861555747;
const D24: f64 = -7.992771707568823;
const D25: f64 = 1.025137723295662;
const D31: f64 = -0.6762803392801253;
const D32: f64 = 6.087714651680015;
const D33: f64 = 16.43084320892478;
const D34: f64 = 24.76722511418386;
const D35: f64 = -6.594389125716872;

const SAFE: f64 = 0.9;
/// `1 / (smallest hnew/h)`.
const FAC1: f64 = 5.0;
/// `1 / (largest hnew/h)`.
const FAC2: f64 = 1.0 / 6.0;

/// An LU factorisation with partial pivoting, `P E = L U`, stored in place (unit lower part
/// below the diagonal), on the stack.
struct Lu<const N: usize> {
    lu: SMatrix<f64, N, N>,
    perm: [usize; N],
}

impl<const N: usize> Lu<N> {
    /// Factorises `fac * I - jac`; `None` when a pivot is exactly zero or not finite.
    #[inline(always)]
    fn new(jac: &[[f64; N]; N], fac: f64) -> Option<Self> {
        let mut a = SMatrix::<f64, N, N>::zeros();
        for i in 0..N {
            for j in 0..N {
                a[(i, j)] = -jac[i][j];
            }
            a[(i, i)] += fac;
        }
        let mut perm = [0usize; N];
        for k in 0..N {
            let mut p = k;
            let mut best = a[(k, k)].abs();
            for i in k + 1..N {
                let v = a[(i, k)].abs();
                if v > best {
                    best = v;
                    p = i;
                }
            }
            perm[k] = p;
            if best == 0.0 || !best.is_finite() {
                return None;
            }
            if p != k {
                a.swap_rows(p, k);
            }
            let inv = 1.0 / a[(k, k)];
            for i in k + 1..N {
                let l = a[(i, k)] * inv;
                a[(i, k)] = l;
                for j in k + 1..N {
                    let u = a[(k, j)];
                    a[(i, j)] -= l * u;
                }
            }
        }
        Some(Lu { lu: a, perm })
    }

    /// Solves `E x = b` in place.
    #[inline(always)]
    fn solve(&self, b: &mut [f64; N]) {
        for k in 0..N {
            b.swap(k, self.perm[k]);
        }
        for i in 1..N {
            let mut s = b[i];
            for j in 0..i {
                s -= self.lu[(i, j)] * b[j];
            }
            b[i] = s;
        }
        for i in (0..N).rev() {
            let mut s = b[i];
            for j in i + 1..N {
                s -= self.lu[(i, j)] * b[j];
            }
            b[i] = s / self.lu[(i, i)];
        }
    }
}

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
    let autonomous = sys.is_autonomous();
    let jac_block = 1 + sys.jacobian_cost() + usize::from(!autonomous);

    let mut t = t0;
    let mut y = y0;
    let mut f0 = [0.0; N];
    // f(t0, y0) is the first evaluation of the first Jacobian block; it also feeds HINIT.
    if opts.max_rhs_evals < 1 {
        return stop(1, stats, Failure::WorkLimit { t });
    }
    sys.rhs(t, &y, &mut f0);
    stats.rhs_evals += 1;
    let mut have_f0 = true;
    if !all_finite(&f0) {
        return stop(1, stats, Failure::NonFinite { t });
    }
    let mut h = match user_initial_step(opts, hmax) {
        Some(h) => h,
        None => {
            if stats.rhs_evals + 1 > opts.max_rhs_evals {
                return stop(1, stats, Failure::WorkLimit { t });
            }
            stats.rhs_evals += 1;
            hinit(sys, t, &y, &f0, hmax, 4, opts)
        }
    };

    let mut next = 1;
    let mut reject = false;
    let mut nonfinite = false;
    let mut need_jac = true;
    let mut jac = [[0.0; N]; N];
    let mut fx = [0.0; N];
    let mut hacc = 0.0_f64;
    let mut erracc = 1.0_f64;
    let (mut k1, mut k2, mut k3, mut k4, mut k5, mut k6) =
        ([0.0; N], [0.0; N], [0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    let mut ys = [0.0; N];
    let mut dy = [0.0; N];

    loop {
        if stats.accepted + stats.rejected >= opts.max_steps {
            return stop(next, stats, Failure::StepLimit { t });
        }
        // Evaluations the Jacobian block still needs here (f(t0, y0) is already counted).
        let block = match (need_jac, have_f0) {
            (false, _) => 0,
            (true, true) => jac_block - 1,
            (true, false) => jac_block,
        };
        if stats.rhs_evals + block + 5 > opts.max_rhs_evals {
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
        if need_jac {
            if !have_f0 {
                sys.rhs(t, &y, &mut f0);
            }
            have_f0 = false;
            sys.jacobian(t, &y, &mut jac);
            stats.rhs_evals += block;
            stats.jacobian_evals += 1;
            let mut ok = all_finite(&f0);
            for row in &jac {
                ok &= all_finite(row);
            }
            if !autonomous {
                let delt = (f64::EPSILON * t.abs().max(1e-5)).sqrt();
                sys.rhs(t + delt, &y, &mut dy);
                for i in 0..N {
                    fx[i] = (dy[i] - f0[i]) / delt;
                }
                ok &= all_finite(&fx);
            }
            if !ok {
                return stop(next, stats, Failure::NonFinite { t });
            }
            need_jac = false;
        }

        let last = t + 1.0001 * h >= t_end;
        if last {
            h = t_end - t;
        }
        let tnew = if last { t_end } else { t + h };

        stats.lu_decompositions += 1;
        let Some(lu) = Lu::new(&jac, 1.0 / (h * GAMMA)) else {
            stats.rejected += 1;
            reject = true;
            nonfinite = true;
            h *= NONFINITE_SHRINK;
            continue;
        };
        let inv_h = 1.0 / h;
        let (hd1, hd2, hd3, hd4) = if autonomous {
            (0.0, 0.0, 0.0, 0.0)
        } else {
            (h * D1, h * D2, h * D3, h * D4)
        };

        // --- the six stages ---
        for i in 0..N {
            k1[i] = f0[i] + hd1 * fx[i];
        }
        lu.solve(&mut k1);
        for i in 0..N {
            ys[i] = y[i] + A21 * k1[i];
        }
        sys.rhs(t + C2 * h, &ys, &mut dy);
        for i in 0..N {
            k2[i] = dy[i] + inv_h * (C21 * k1[i]) + hd2 * fx[i];
        }
        lu.solve(&mut k2);
        for i in 0..N {
            ys[i] = y[i] + A31 * k1[i] + A32 * k2[i];
        }
        sys.rhs(t + C3 * h, &ys, &mut dy);
        for i in 0..N {
            k3[i] = dy[i] + inv_h * (C31 * k1[i] + C32 * k2[i]) + hd3 * fx[i];
        }
        lu.solve(&mut k3);
        for i in 0..N {
            ys[i] = y[i] + A41 * k1[i] + A42 * k2[i] + A43 * k3[i];
        }
        sys.rhs(t + C4 * h, &ys, &mut dy);
        for i in 0..N {
            k4[i] = dy[i] + inv_h * (C41 * k1[i] + C42 * k2[i] + C43 * k3[i]) + hd4 * fx[i];
        }
        lu.solve(&mut k4);
        for i in 0..N {
            ys[i] = y[i] + A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i];
        }
        sys.rhs(tnew, &ys, &mut dy);
        for i in 0..N {
            k5[i] = dy[i] + inv_h * (C51 * k1[i] + C52 * k2[i] + C53 * k3[i] + C54 * k4[i]);
        }
        lu.solve(&mut k5);
        // embedded (order 3) solution
        for i in 0..N {
            ys[i] += k5[i];
        }
        sys.rhs(tnew, &ys, &mut dy);
        for i in 0..N {
            k6[i] = dy[i]
                + inv_h * (C61 * k1[i] + C62 * k2[i] + C63 * k3[i] + C64 * k4[i] + C65 * k5[i]);
        }
        lu.solve(&mut k6);
        let mut ynew = [0.0; N];
        for i in 0..N {
            ynew[i] = ys[i] + k6[i];
        }
        stats.rhs_evals += 5;

        // --- error estimate ---
        let mut err = 0.0;
        let mut finite = true;
        for i in 0..N {
            let sk = opts.atol + opts.rtol * y[i].abs().max(ynew[i].abs());
            err += (k6[i] / sk) * (k6[i] / sk);
            finite &= ynew[i].is_finite() & k1[i].is_finite() & k2[i].is_finite();
            finite &= k3[i].is_finite() & k4[i].is_finite() & k5[i].is_finite();
        }
        let err = (err / N as f64).sqrt();
        if !(finite && err.is_finite()) {
            stats.rejected += 1;
            reject = true;
            nonfinite = true;
            h *= NONFINITE_SHRINK;
            continue;
        }
        let mut fac = (err.sqrt().sqrt() / SAFE).clamp(FAC2, FAC1);
        if err <= 1.0 {
            // --- accepted ---
            stats.accepted += 1;
            if stats.accepted > 1 {
                // Gustafsson's predictive controller.
                let facgus =
                    ((hacc / h) * (err * err / erracc).sqrt().sqrt() / SAFE).clamp(FAC2, FAC1);
                fac = fac.max(facgus);
            }
            hacc = h;
            erracc = err.max(1e-2);
            let mut hnew = h / fac;
            let m = norm_inf(&ynew);
            if m > opts.bound {
                return stop(next, stats, Failure::BlowUp { t: tnew, value: m });
            }
            if times[next] <= tnew {
                let mut r2 = [0.0; N];
                let mut r3 = [0.0; N];
                if times[next] < tnew {
                    for i in 0..N {
                        r2[i] = D21 * k1[i] + D22 * k2[i] + D23 * k3[i] + D24 * k4[i] + D25 * k5[i];
                        r3[i] = D31 * k1[i] + D32 * k2[i] + D33 * k3[i] + D34 * k4[i] + D35 * k5[i];
                    }
                }
                let dense = |s: f64, s1: f64| {
                    let mut yo = [0.0; N];
                    for i in 0..N {
                        yo[i] = y[i] * s1 + s * (ynew[i] + s1 * (r2[i] + s * r3[i]));
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
            need_jac = true;
            t = tnew;
            y = ynew;
            h = hnew;
        } else {
            // --- rejected: same Jacobian, new step size ---
            stats.rejected += 1;
            reject = true;
            nonfinite = false;
            h /= fac;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Lu;
    use approx::assert_relative_eq;

    /// `(fac I - J) x = b` solved by the in-place LU agrees with the product, including a
    /// matrix that needs row exchanges (zero leading pivot).
    #[test]
    fn lu_solves_with_pivoting() {
        let jac = [[1.0, 2.0, -1.0], [4.0, 0.5, 3.0], [-2.0, 1.0, 7.0]];
        for fac in [1.0, 1e-3, 1e3] {
            let lu = Lu::new(&jac, fac).unwrap();
            let b = [1.0, -2.0, 0.5];
            let mut x = b;
            lu.solve(&mut x);
            for i in 0..3 {
                let mut ax = fac * x[i];
                for j in 0..3 {
                    ax -= jac[i][j] * x[j];
                }
                assert_relative_eq!(ax, b[i], max_relative = 1e-12, epsilon = 1e-12);
            }
        }
        // fac I - J = [[0, 1], [1, 0]]: the first pivot is zero.
        let lu = Lu::new(&[[1.0, -1.0], [-1.0, 1.0]], 1.0).unwrap();
        let mut x = [3.0, 5.0];
        lu.solve(&mut x);
        assert_eq!(x, [5.0, 3.0]);
    }

    #[test]
    fn lu_reports_singular_and_non_finite() {
        assert!(Lu::new(&[[1.0, 0.0], [0.0, 2.0]], 1.0).is_none());
        assert!(Lu::new(&[[f64::NAN, 0.0], [0.0, 2.0]], 1.0).is_none());
    }
}
