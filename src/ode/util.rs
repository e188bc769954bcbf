//! Helpers shared by the integrators: finiteness and bound checks, the minimum step, Hairer's
//! initial step selection and the early-return bookkeeping. Everything is `#[inline]` and works
//! on stack arrays.

#![allow(clippy::needless_range_loop)] // indexed loops over N mirror the formulas

use super::{Failure, Options, Outcome, Stats, System};
use std::ops::ControlFlow;

/// Relative step-size floor: a step below `UNDERFLOW * max(|t0|, |t_end|)` cannot move `t` by
/// more than a few ulps and is reported as [`Failure::StepSizeUnderflow`].
pub(super) const UNDERFLOW: f64 = 16.0 * f64::EPSILON;

/// Factor applied to the step after a trial step produced a non-finite value (the largest
/// decrease the error controllers allow).
pub(super) const NONFINITE_SHRINK: f64 = 0.2;

/// Whether every component is finite.
#[inline(always)]
pub(super) fn all_finite<const N: usize>(y: &[f64; N]) -> bool {
    let mut ok = true;
    for v in y {
        ok &= v.is_finite();
    }
    ok
}

/// `max_i |y_i|` (for finite input).
#[inline(always)]
pub(super) fn norm_inf<const N: usize>(y: &[f64; N]) -> f64 {
    let mut m = 0.0_f64;
    for v in y {
        m = m.max(v.abs());
    }
    m
}

/// `None` when `y` is finite and within `bound`; otherwise the failure at `t`.
#[inline(always)]
pub(super) fn check_state<const N: usize>(y: &[f64; N], t: f64, bound: f64) -> Option<Failure> {
    if !all_finite(y) {
        return Some(Failure::NonFinite { t });
    }
    let m = norm_inf(y);
    if m > bound {
        Some(Failure::BlowUp { t, value: m })
    } else {
        None
    }
}

/// The smallest step allowed on `[t0, t_end]` (see [`UNDERFLOW`]).
#[inline(always)]
pub(super) fn min_step(t0: f64, t_end: f64) -> f64 {
    UNDERFLOW * t0.abs().max(t_end.abs()).max(f64::MIN_POSITIVE)
}

/// An early return.
#[inline(always)]
pub(super) fn stop(reached: usize, stats: Stats, failure: Failure) -> Outcome {
    Outcome {
        reached,
        stats,
        failure: Some(failure),
    }
}

/// Delivers to `observe` every output time in `(t, tnew]` from `*next` on, after an accepted
/// step of an adaptive integrator: `ynew` at `tnew`, `dense(s, 1 - s)` before it, where
/// `s = (tout - t) * inv_h`. `Some` is the outcome to return: an observer's `Break` at its time,
/// or success once the last time is delivered. One loop for every integrator's dense output.
#[inline(always)]
pub(super) fn deliver<const N: usize, F, D>(
    times: &[f64],
    next: &mut usize,
    (t, tnew, inv_h): (f64, f64, f64),
    ynew: &[f64; N],
    stats: Stats,
    observe: &mut F,
    dense: D,
) -> Option<Outcome>
where
    F: FnMut(usize, &[f64; N]) -> ControlFlow<()>,
    D: Fn(f64, f64) -> [f64; N],
{
    let n_out = times.len();
    while *next < n_out && times[*next] <= tnew {
        let tout = times[*next];
        let flow = if tout == tnew {
            observe(*next, ynew)
        } else {
            let s = (tout - t) * inv_h;
            observe(*next, &dense(s, 1.0 - s))
        };
        *next += 1;
        if flow.is_break() {
            return Some(stop(*next, stats, Failure::Stopped { t: tout }));
        }
    }
    (*next == n_out).then_some(Outcome {
        reached: n_out,
        stats,
        failure: None,
    })
}

/// The user's initial step if it is usable (positive and finite), clipped to `hmax`.
#[inline(always)]
pub(super) fn user_initial_step(opts: &Options, hmax: f64) -> Option<f64> {
    opts.initial_step
        .filter(|h| h.is_finite() && *h > 0.0)
        .map(|h| h.min(hmax))
}

/// Hairer's `HINIT` (Hairer, Norsett & Wanner, *Solving ODEs I*, 2nd ed., sec. II.4, and the
/// routine of the same name in `dopri5.f`): a first guess from `|y0|/|f0|`, one explicit Euler
/// step to estimate the second derivative, and `h = (0.01 / max(|f'|, |f|))^(1/order)`.
/// Costs exactly one right-hand-side evaluation. Always returns a positive finite step
/// `<= hmax`, even when the trial evaluation is not finite.
#[inline]
pub(super) fn hinit<const N: usize, S: System<N> + ?Sized>(
    sys: &S,
    t0: f64,
    y0: &[f64; N],
    f0: &[f64; N],
    hmax: f64,
    order: i32,
    opts: &Options,
) -> f64 {
    let (probe, y1) = hinit_probe(y0, f0, hmax, opts);
    let mut f1 = [0.0; N];
    sys.rhs(t0 + probe.h, &y1, &mut f1);
    hinit_finish(&probe, f0, &f1, hmax, order)
}

/// The first half of [`hinit`], before its one evaluation (shared with the lane integrators, so
/// that a lane chooses the same step as the scalar method, bit for bit).
#[derive(Debug, Clone, Copy)]
pub(super) struct HinitProbe<const N: usize> {
    /// The trial step: the evaluation is `f(t0 + h, y1)`.
    pub h: f64,
    sk: [f64; N],
    dnf: f64,
}

/// The trial step of [`hinit`] and the state `y1 = y0 + h f0` to evaluate at `t0 + h`.
#[inline(always)]
pub(super) fn hinit_probe<const N: usize>(
    y0: &[f64; N],
    f0: &[f64; N],
    hmax: f64,
    opts: &Options,
) -> (HinitProbe<N>, [f64; N]) {
    let mut sk = [0.0; N];
    let mut dnf = 0.0;
    let mut dny = 0.0;
    for i in 0..N {
        sk[i] = opts.atol + opts.rtol * y0[i].abs();
        dnf += (f0[i] / sk[i]) * (f0[i] / sk[i]);
        dny += (y0[i] / sk[i]) * (y0[i] / sk[i]);
    }
    let mut h = if dnf <= 1e-10 || dny <= 1e-10 {
        1e-6
    } else {
        (dny / dnf).sqrt() * 0.01
    };
    h = h.min(hmax);
    let mut y1 = [0.0; N];
    for i in 0..N {
        y1[i] = y0[i] + h * f0[i];
    }
    (HinitProbe { h, sk, dnf }, y1)
}

/// The second half of [`hinit`], given `f1 = f(t0 + h, y1)`.
#[inline(always)]
pub(super) fn hinit_finish<const N: usize>(
    probe: &HinitProbe<N>,
    f0: &[f64; N],
    f1: &[f64; N],
    hmax: f64,
    order: i32,
) -> f64 {
    let (h, sk, dnf) = (probe.h, &probe.sk, probe.dnf);
    let mut der2 = 0.0;
    for i in 0..N {
        let d = (f1[i] - f0[i]) / sk[i];
        der2 += d * d;
    }
    der2 = der2.sqrt() / h;
    // f64::max ignores a NaN operand: a non-finite trial falls back on |f0|.
    let der12 = der2.abs().max(dnf.sqrt());
    let h1 = if der12 <= 1e-15 {
        (h * 1e-3).max(1e-6)
    } else {
        (0.01 / der12).powf(1.0 / f64::from(order))
    };
    let h = (100.0 * h).min(h1).min(hmax);
    if h.is_finite() && h > 0.0 {
        h
    } else {
        hmax.min(1e-6)
    }
}

/// The common start of the adaptive methods: an empty `times` returns at once; the initial state
/// is checked and delivered (index 0); a single time ends there; the span must be an increasing
/// finite interval. Returns `(t0, t_end, hmax, hmin)`, or the finished outcome.
pub(super) fn begin<const N: usize, F>(
    times: &[f64],
    y0: &[f64; N],
    opts: &Options,
    observe: &mut F,
) -> Result<(f64, f64, f64, f64), Outcome>
where
    F: FnMut(usize, &[f64; N]) -> ControlFlow<()>,
{
    let stats = Stats::default();
    let n_out = times.len();
    if n_out == 0 {
        return Err(Outcome {
            reached: 0,
            stats,
            failure: None,
        });
    }
    let t0 = times[0];
    if let Some(f) = check_state(y0, t0, opts.bound) {
        return Err(stop(0, stats, f));
    }
    if observe(0, y0).is_break() {
        return Err(stop(1, stats, Failure::Stopped { t: t0 }));
    }
    if n_out == 1 {
        return Err(Outcome {
            reached: 1,
            stats,
            failure: None,
        });
    }
    let t_end = times[n_out - 1];
    let hmax = t_end - t0;
    if hmax.is_nan() || hmax <= 0.0 || hmax.is_infinite() {
        // Not an increasing finite time span (a caller bug): no step is possible.
        return Err(stop(
            1,
            stats,
            Failure::StepSizeUnderflow { t: t0, h: hmax },
        ));
    }
    Ok((t0, t_end, hmax, min_step(t0, t_end)))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Decay;
    impl System<1> for Decay {
        fn rhs(&self, _t: f64, y: &[f64; 1], dy: &mut [f64; 1]) {
            dy[0] = -y[0];
        }
    }

    #[test]
    fn state_checks() {
        assert_eq!(check_state(&[1.0, -2.0], 0.5, 10.0), None);
        assert_eq!(
            check_state(&[1.0, -20.0], 0.5, 10.0),
            Some(Failure::BlowUp {
                t: 0.5,
                value: 20.0
            })
        );
        assert_eq!(
            check_state(&[f64::NAN, 0.0], 0.5, 10.0),
            Some(Failure::NonFinite { t: 0.5 })
        );
        assert!(min_step(0.0, 30.0) > 0.0 && min_step(0.0, 30.0) < 1e-12);
    }

    /// For y' = -y, HINIT gives a step of the order of (0.01)^(1/5) ~ 0.4 at order 5, positive
    /// and clipped to hmax.
    #[test]
    fn hinit_is_sane() {
        let o = Options::default();
        let h = hinit(&Decay, 0.0, &[1.0], &[-1.0], 10.0, 5, &o);
        assert!(h > 0.05 && h < 1.0, "h = {h}");
        let h = hinit(&Decay, 0.0, &[1.0], &[-1.0], 1e-3, 5, &o);
        assert_eq!(h, 1e-3);
        // A zero derivative falls back on the safe defaults.
        let h = hinit(&Decay, 0.0, &[0.0], &[0.0], 10.0, 5, &o);
        assert!(h > 0.0 && h.is_finite());
    }
}
