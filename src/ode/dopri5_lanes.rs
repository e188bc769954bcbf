//! Dormand-Prince 5(4) for `L` lanes in lockstep, each lane with its own step-size controller.
//!
//! The stages of every live lane are computed together (one model dispatch per stage for all
//! lanes); the error norms too. What differs between lanes (accept or reject, the next step,
//! outputs passed, failures) is decided lane by lane with the scalar method's formulas
//! (`super::dopri5`), so each lane's result is bit-identical to the scalar integration. Lanes
//! never wait for each other: a lane that rejects its step simply attempts a smaller one in the
//! next iteration while the others advance, and a lane that finishes or fails is masked (parked
//! on a zero state with a zero step, computed but never observed).

#![allow(clippy::needless_range_loop)] // indexed loops over N and L mirror the formulas

use super::dopri5::*;
use super::lanes::{lane, set_lane, LaneSystem, PENDING};
use super::util::{
    all_finite, check_state, hinit_finish, hinit_probe, min_step, norm_inf, stop,
    user_initial_step, NONFINITE_SHRINK,
};
use super::{Failure, Options, Outcome, Stats};
use std::ops::ControlFlow;

/// Dormand-Prince 5(4) for `L` lanes, as [`super::Method::Dopri5`] per lane (same steps, same
/// outputs, same statistics and failures, bit for bit).
///
/// `y0[i][l]` is lane `l`'s initial state; `live[l]` says which lanes to integrate (a lane not
/// live on entry keeps a default outcome, `reached 0` without failure, and is never observed).
/// `observe(lane, index, state)` receives each lane's outputs in order; `Break` stops that lane.
// Inlined into its caller, so that the caller's observer (the fitness's per-sample tally)
// inlines into the dense-output loop: left to LLVM's heuristics it once became a call per
// sample and the batched fitness 20 % slower (docs/benchmarks.md, "Lanes without the overhead").
#[inline(always)]
pub fn dopri5<const L: usize, const N: usize, S, F>(
    sys: &S,
    y0: &[[f64; L]; N],
    mut live: [bool; L],
    times: &[f64],
    opts: &Options,
    mut observe: F,
) -> [Outcome; L]
where
    S: LaneSystem<L, N> + ?Sized,
    F: FnMut(usize, usize, &[f64; N]) -> ControlFlow<()>,
{
    let mut out = [PENDING; L];
    let mut stats = [Stats::default(); L];
    let n_out = times.len();
    if n_out == 0 {
        return out;
    }
    let t0 = times[0];
    let zero = [[0.0; L]; N];
    let mut y = *y0;
    // The common start (`util::begin`), lane by lane.
    for l in 0..L {
        if !live[l] {
            continue;
        }
        let s = lane(&y, l);
        if let Some(f) = check_state(&s, t0, opts.bound) {
            out[l] = stop(0, stats[l], f);
            live[l] = false;
        } else if observe(l, 0, &s).is_break() {
            out[l] = stop(1, stats[l], Failure::Stopped { t: t0 });
            live[l] = false;
        } else if n_out == 1 {
            out[l] = Outcome {
                reached: 1,
                stats: stats[l],
                failure: None,
            };
            live[l] = false;
        }
    }
    if !live.iter().any(|b| *b) {
        return out;
    }
    let t_end = times[n_out - 1];
    let hmax = t_end - t0;
    let finish_all = |out: &mut [Outcome; L], live: &mut [bool; L], stats: &[Stats; L], f| {
        for l in 0..L {
            if live[l] {
                out[l] = stop(1, stats[l], f);
                live[l] = false;
            }
        }
    };
    if hmax.is_nan() || hmax <= 0.0 || hmax.is_infinite() {
        let f = Failure::StepSizeUnderflow { t: t0, h: hmax };
        finish_all(&mut out, &mut live, &stats, f);
        return out;
    }
    let hmin = min_step(t0, t_end);
    if opts.max_rhs_evals < 1 {
        finish_all(&mut out, &mut live, &stats, Failure::WorkLimit { t: t0 });
        return out;
    }
    let park = |y: &mut [[f64; L]; N], live: &[bool; L]| {
        for l in 0..L {
            if !live[l] {
                set_lane(y, l, &[0.0; N]);
            }
        }
    };
    park(&mut y, &live);
    let mut k1 = zero;
    sys.rhs(&[t0; L], &y, &mut k1);
    for l in 0..L {
        if live[l] {
            stats[l].rhs_evals += 1;
            if !all_finite(&lane(&k1, l)) {
                out[l] = stop(1, stats[l], Failure::NonFinite { t: t0 });
                live[l] = false;
            }
        }
    }
    park(&mut k1, &live);
    let mut h = [0.0; L];
    match user_initial_step(opts, hmax) {
        Some(h0) => h = [h0; L],
        None => {
            // Every live lane has spent exactly one evaluation.
            if 2 > opts.max_rhs_evals {
                finish_all(&mut out, &mut live, &stats, Failure::WorkLimit { t: t0 });
                return out;
            }
            let mut t1 = [t0; L];
            let mut y1 = zero;
            let mut probes = [None; L];
            for l in 0..L {
                if live[l] {
                    let (probe, v) = hinit_probe(&lane(&y, l), &lane(&k1, l), hmax, opts);
                    t1[l] = t0 + probe.h;
                    set_lane(&mut y1, l, &v);
                    probes[l] = Some(probe);
                }
            }
            let mut f1 = zero;
            sys.rhs(&t1, &y1, &mut f1);
            for l in 0..L {
                if let Some(probe) = &probes[l] {
                    stats[l].rhs_evals += 1;
                    h[l] = hinit_finish(probe, &lane(&k1, l), &lane(&f1, l), hmax, 5);
                }
            }
        }
    }

    let mut t = [t0; L];
    let mut next = [1usize; L];
    let mut ln_facold = [LN_ERR_MIN; L];
    let mut reject = [false; L];
    let mut nonfinite = [false; L];
    let mut last = [false; L];
    let (mut k2, mut k3, mut k4, mut k5, mut k6, mut k7) = (zero, zero, zero, zero, zero, zero);
    let (mut ys, mut ynew) = (zero, zero);
    let (mut tc, mut tnew) = ([0.0; L], [0.0; L]);

    loop {
        // Per-lane checks before the attempt (the scalar loop's head).
        for l in 0..L {
            if !live[l] {
                h[l] = 0.0;
                continue;
            }
            let s = &stats[l];
            let f = if s.accepted + s.rejected >= opts.max_steps {
                Some(Failure::StepLimit { t: t[l] })
            } else if s.rhs_evals + 6 > opts.max_rhs_evals {
                Some(Failure::WorkLimit { t: t[l] })
            } else if h[l].is_nan() || h[l] < hmin {
                Some(if nonfinite[l] {
                    Failure::NonFinite { t: t[l] }
                } else {
                    Failure::StepSizeUnderflow { t: t[l], h: h[l] }
                })
            } else {
                None
            };
            if let Some(f) = f {
                out[l] = stop(next[l], stats[l], f);
                live[l] = false;
                h[l] = 0.0;
                continue;
            }
            last[l] = t[l] + 1.01 * h[l] >= t_end;
            if last[l] {
                h[l] = t_end - t[l];
            }
        }
        if !live.iter().any(|b| *b) {
            return out;
        }
        park(&mut y, &live);
        park(&mut k1, &live);

        // --- the six new stages of every lane (k1 is known: FSAL) ---
        for i in 0..N {
            for l in 0..L {
                ys[i][l] = y[i][l] + h[l] * A21 * k1[i][l];
            }
        }
        for l in 0..L {
            tc[l] = t[l] + C2 * h[l];
        }
        sys.rhs(&tc, &ys, &mut k2);
        for i in 0..N {
            for l in 0..L {
                ys[i][l] = y[i][l] + h[l] * (A31 * k1[i][l] + A32 * k2[i][l]);
            }
        }
        for l in 0..L {
            tc[l] = t[l] + C3 * h[l];
        }
        sys.rhs(&tc, &ys, &mut k3);
        for i in 0..N {
            for l in 0..L {
                ys[i][l] = y[i][l] + h[l] * (A41 * k1[i][l] + A42 * k2[i][l] + A43 * k3[i][l]);
            }
        }
        for l in 0..L {
            tc[l] = t[l] + C4 * h[l];
        }
        sys.rhs(&tc, &ys, &mut k4);
        for i in 0..N {
            for l in 0..L {
                ys[i][l] = y[i][l]
                    + h[l] * (A51 * k1[i][l] + A52 * k2[i][l] + A53 * k3[i][l] + A54 * k4[i][l]);
            }
        }
        for l in 0..L {
            tc[l] = t[l] + C5 * h[l];
        }
        sys.rhs(&tc, &ys, &mut k5);
        for i in 0..N {
            for l in 0..L {
                ys[i][l] = y[i][l]
                    + h[l]
                        * (A61 * k1[i][l]
                            + A62 * k2[i][l]
                            + A63 * k3[i][l]
                            + A64 * k4[i][l]
                            + A65 * k5[i][l]);
            }
        }
        for l in 0..L {
            tnew[l] = if last[l] { t_end } else { t[l] + h[l] };
        }
        sys.rhs(&tnew, &ys, &mut k6);
        for i in 0..N {
            for l in 0..L {
                ynew[i][l] = y[i][l]
                    + h[l]
                        * (A71 * k1[i][l]
                            + A73 * k3[i][l]
                            + A74 * k4[i][l]
                            + A75 * k5[i][l]
                            + A76 * k6[i][l]);
            }
        }
        sys.rhs(&tnew, &ynew, &mut k7);

        // --- error estimates, all lanes ---
        let mut err = [0.0; L];
        let mut finite = [true; L];
        for i in 0..N {
            for l in 0..L {
                let e = h[l]
                    * (E1 * k1[i][l]
                        + E3 * k3[i][l]
                        + E4 * k4[i][l]
                        + E5 * k5[i][l]
                        + E6 * k6[i][l]
                        + E7 * k7[i][l]);
                let sk = opts.atol + opts.rtol * y[i][l].abs().max(ynew[i][l].abs());
                err[l] += (e / sk) * (e / sk);
                finite[l] &= ynew[i][l].is_finite() & k7[i][l].is_finite() & k2[i][l].is_finite();
            }
        }

        // --- each lane's decision (the scalar controller) ---
        for l in 0..L {
            if !live[l] {
                continue;
            }
            stats[l].rhs_evals += 6;
            let e = (err[l] / N as f64).sqrt();
            if !(finite[l] && e.is_finite()) {
                stats[l].rejected += 1;
                reject[l] = true;
                nonfinite[l] = true;
                h[l] *= NONFINITE_SHRINK;
                continue;
            }
            let ln_err = e.ln();
            if e > 1.0 {
                stats[l].rejected += 1;
                reject[l] = true;
                nonfinite[l] = false;
                h[l] /= ((EXPO1 * ln_err).exp() / SAFE).min(FACC1);
                continue;
            }
            // --- accepted ---
            stats[l].accepted += 1;
            let fac = ((EXPO1 * ln_err - BETA * ln_facold[l]).exp() / SAFE).clamp(FACC2, FACC1);
            let mut hnew = h[l] / fac;
            ln_facold[l] = ln_err.max(LN_ERR_MIN);
            let yl = lane(&y, l);
            let ynl = lane(&ynew, l);
            let m = norm_inf(&ynl);
            if m > opts.bound {
                out[l] = stop(
                    next[l],
                    stats[l],
                    Failure::BlowUp {
                        t: tnew[l],
                        value: m,
                    },
                );
                live[l] = false;
                continue;
            }
            if times[next[l]] <= tnew[l] {
                match deliver(
                    &mut observe,
                    l,
                    times,
                    &mut next[l],
                    h[l],
                    t[l],
                    tnew[l],
                    &yl,
                    &ynl,
                    [&k1, &k3, &k4, &k5, &k6, &k7],
                ) {
                    Delivered::More => {}
                    Delivered::Stopped(tout) => {
                        out[l] = stop(next[l], stats[l], Failure::Stopped { t: tout });
                        live[l] = false;
                        continue;
                    }
                    Delivered::Done => {
                        out[l] = Outcome {
                            reached: n_out,
                            stats: stats[l],
                            failure: None,
                        };
                        live[l] = false;
                        continue;
                    }
                }
            }
            hnew = hnew.min(hmax);
            if reject[l] {
                hnew = hnew.min(h[l]);
            }
            reject[l] = false;
            nonfinite[l] = false;
            t[l] = tnew[l];
            set_lane(&mut y, l, &ynl);
            set_lane(&mut k1, l, &lane(&k7, l));
            h[l] = hnew;
        }
    }
}

/// What [`deliver`] did.
enum Delivered {
    /// Outputs in the step delivered; more remain.
    More,
    /// The observer stopped the lane at this output time.
    Stopped(f64),
    /// The last output was delivered.
    Done,
}

/// Delivers lane `l`'s output times in `(t, tnew]` by the continuous extension, exactly as the
/// scalar method does (`k` = k1, k3, k4, k5, k6, k7 of the step).
#[allow(clippy::too_many_arguments)]
#[inline]
fn deliver<const L: usize, const N: usize, F>(
    observe: &mut F,
    l: usize,
    times: &[f64],
    next: &mut usize,
    h: f64,
    t: f64,
    tnew: f64,
    y: &[f64; N],
    ynew: &[f64; N],
    k: [&[[f64; L]; N]; 6],
) -> Delivered
where
    F: FnMut(usize, usize, &[f64; N]) -> ControlFlow<()>,
{
    let n_out = times.len();
    // Indexed in place: copying the lane out (`lane`) went through a call and a store that the
    // next vector load could not forward from (docs/benchmarks.md, "Dormand-Prince's lane
    // bookkeeping").
    let [k1, k3, k4, k5, k6, k7] = k;
    let mut r1 = [0.0; N];
    let mut r2 = [0.0; N];
    let mut r3 = [0.0; N];
    let mut r4 = [0.0; N];
    if times[*next] < tnew {
        for i in 0..N {
            let ydiff = ynew[i] - y[i];
            let bspl = h * k1[i][l] - ydiff;
            r1[i] = ydiff;
            r2[i] = bspl;
            r3[i] = ydiff - h * k7[i][l] - bspl;
            r4[i] = h
                * (D1 * k1[i][l]
                    + D3 * k3[i][l]
                    + D4 * k4[i][l]
                    + D5 * k5[i][l]
                    + D6 * k6[i][l]
                    + D7 * k7[i][l]);
        }
    }
    let inv_h = 1.0 / h;
    while *next < n_out && times[*next] <= tnew {
        let tout = times[*next];
        let flow = if tout == tnew {
            observe(l, *next, ynew)
        } else {
            let s = (tout - t) * inv_h;
            let s1 = 1.0 - s;
            let mut yo = [0.0; N];
            for i in 0..N {
                yo[i] = y[i] + s * (r1[i] + s1 * (r2[i] + s * (r3[i] + s1 * r4[i])));
            }
            observe(l, *next, &yo)
        };
        *next += 1;
        if flow.is_break() {
            return Delivered::Stopped(tout);
        }
    }
    if *next == n_out {
        Delivered::Done
    } else {
        Delivered::More
    }
}
