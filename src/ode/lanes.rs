//! Lockstep integration of `L` independent systems (lanes) of the same equation.
//!
//! A DE generation integrates dozens of candidates of one model over the same sample grid. Side
//! by side, in structure-of-arrays form (`[[f64; L]; N]`: state component `i` of lane `l` at
//! `y[i][l]`), the stage arithmetic of `L` candidates is one vector operation, and the compiled
//! model is dispatched once per stage for all of them (see `model::BoundLanes`).
//!
//! Each lane follows exactly the scalar method's operations in the same order, so its outcome
//! (observed states, statistics, failure) is bit-identical to [`super::integrate`] on that
//! lane alone; the tests check this. A lane that fails or is stopped by its observer is masked:
//! its outcome is fixed, its slot keeps being computed (on a neutral state) but never observed,
//! and the others go on. When every lane is done the call returns.
//!
//! - [`rk4`]: the fixed grid keeps all lanes at the same time, so the observer sees all live
//!   lanes of an output index at once (a force output can be computed for all of them in one
//!   pass of the model).
//! - [`dopri5`]: every lane has its own time, step and controller; each iteration attempts one
//!   step on every live lane, and a lane's outputs are delivered as soon as it passes them.

#![allow(clippy::needless_range_loop)] // indexed loops over N and L mirror the formulas

use super::util::stop;
use super::{Failure, Options, Outcome, Stats};

pub use super::dopri5_lanes::dopri5;

/// `L` first-order systems `dy/dt = f(t, y)` with `N` states each, evaluated together.
pub trait LaneSystem<const L: usize, const N: usize> {
    /// Writes `f(t[l], y[.][l])` into `dy[.][l]` for every lane `l`.
    fn rhs(&self, t: &[f64; L], y: &[[f64; L]; N], dy: &mut [[f64; L]; N]);
}

/// Lane `l` of a structure-of-arrays state.
#[inline(always)]
pub(super) fn lane<const L: usize, const N: usize>(y: &[[f64; L]; N], l: usize) -> [f64; N] {
    std::array::from_fn(|i| y[i][l])
}

/// Writes `v` into lane `l`.
#[inline(always)]
pub(super) fn set_lane<const L: usize, const N: usize>(
    y: &mut [[f64; L]; N],
    l: usize,
    v: &[f64; N],
) {
    for i in 0..N {
        y[i][l] = v[i];
    }
}

/// An outcome not decided yet (overwritten when the lane finishes).
pub(super) const PENDING: Outcome = Outcome {
    reached: 0,
    stats: Stats {
        rhs_evals: 0,
        jacobian_evals: 0,
        lu_decompositions: 0,
        accepted: 0,
        rejected: 0,
    },
    failure: None,
};

/// Fixed-step RK4 on the output grid for `L` lanes, as [`super::Method::Rk4`] (same steps, same
/// checks, same statistics, bit for bit per lane).
///
/// `y0[i][l]` is lane `l`'s initial state. `live[l]` says which lanes to integrate (a lane not
/// live on entry gets a default outcome: `reached 0`, no failure, and is never observed).
/// `observe(index, y, live)` is called at every output time with the live lanes' states; it
/// clears `live[l]` to stop lane `l` there (the scalar observer's `Break`). Returns each lane's
/// outcome.
pub fn rk4<const L: usize, const N: usize, S, F>(
    sys: &S,
    y0: &[[f64; L]; N],
    mut live: [bool; L],
    times: &[f64],
    opts: &Options,
    mut observe: F,
) -> [Outcome; L]
where
    S: LaneSystem<L, N> + ?Sized,
    F: FnMut(usize, &[[f64; L]; N], &mut [bool; L]),
{
    let mut out = [PENDING; L];
    let n_out = times.len();
    if n_out == 0 {
        return out;
    }
    let mut stats = Stats::default();
    let t0 = times[0];
    let mut y = *y0;
    for l in 0..L {
        if live[l] {
            if let Some(f) = super::util::check_state(&lane(&y, l), t0, opts.bound) {
                out[l] = stop(0, stats, f);
                live[l] = false;
            }
        }
    }
    // Lanes that are not live compute on a zero state, which stays finite.
    let park = |y: &mut [[f64; L]; N], live: &[bool; L]| {
        for l in 0..L {
            if !live[l] {
                set_lane(y, l, &[0.0; N]);
            }
        }
    };
    park(&mut y, &live);
    if !live.iter().any(|b| *b) {
        return out;
    }
    let before = live;
    observe(0, &y, &mut live);
    for l in 0..L {
        if before[l] && !live[l] {
            out[l] = stop(1, stats, Failure::Stopped { t: t0 });
        }
    }
    let m = opts.substeps.max(1);
    let mf = m as f64;
    let zero = [[0.0; L]; N];
    let (mut k1, mut k2, mut k3, mut k4, mut ys) = (zero, zero, zero, zero, zero);
    for o in 1..n_out {
        if !live.iter().any(|b| *b) {
            return out;
        }
        if live != [true; L] {
            park(&mut y, &live);
        }
        let ta = times[o - 1];
        let tb = times[o];
        let h = (tb - ta) / mf;
        let h2 = 0.5 * h;
        let h6 = h / 6.0;
        for j in 0..m {
            let t = if j == 0 { ta } else { ta + j as f64 * h };
            // The caps are the same for every live lane: they have taken the same steps.
            let cap = if stats.accepted >= opts.max_steps {
                Some(Failure::StepLimit { t })
            } else if stats.rhs_evals + 4 > opts.max_rhs_evals {
                Some(Failure::WorkLimit { t })
            } else {
                None
            };
            if let Some(f) = cap {
                for l in 0..L {
                    if live[l] {
                        out[l] = stop(o, stats, f);
                    }
                }
                return out;
            }
            let tn = if j + 1 == m {
                tb
            } else {
                ta + (j + 1) as f64 * h
            };
            let tm = t + h2;
            sys.rhs(&[t; L], &y, &mut k1);
            for i in 0..N {
                for l in 0..L {
                    ys[i][l] = y[i][l] + h2 * k1[i][l];
                }
            }
            sys.rhs(&[tm; L], &ys, &mut k2);
            for i in 0..N {
                for l in 0..L {
                    ys[i][l] = y[i][l] + h2 * k2[i][l];
                }
            }
            sys.rhs(&[tm; L], &ys, &mut k3);
            for i in 0..N {
                for l in 0..L {
                    ys[i][l] = y[i][l] + h * k3[i][l];
                }
            }
            sys.rhs(&[tn; L], &ys, &mut k4);
            for i in 0..N {
                for l in 0..L {
                    ys[i][l] = y[i][l] + h6 * (k1[i][l] + 2.0 * (k2[i][l] + k3[i][l]) + k4[i][l]);
                }
            }
            stats.rhs_evals += 4;
            stats.accepted += 1;
            // The scalar check per lane (`all_finite`, then `norm_inf > bound`) on the rare
            // lane that fails; for the others one vector test says the same: every component
            // finite and at most `bound` in magnitude (NaN fails `<=`, infinity fails `!=`).
            // Same outcomes as checking every lane, without a scalar loop over the lanes after
            // every step (docs/benchmarks.md, "Lanes without the overhead").
            let mut ok = [true; L];
            for i in 0..N {
                for l in 0..L {
                    let a = ys[i][l].abs();
                    ok[l] &= (a <= opts.bound) & (a != f64::INFINITY);
                }
            }
            let mut failing = false;
            for l in 0..L {
                failing |= !ok[l] & live[l];
            }
            if failing {
                for l in 0..L {
                    if ok[l] || !live[l] {
                        continue;
                    }
                    let s = lane(&ys, l);
                    let failure = if !super::util::all_finite(&s) {
                        Some(Failure::NonFinite { t })
                    } else {
                        let mag = super::util::norm_inf(&s);
                        (mag > opts.bound).then_some(Failure::BlowUp { t: tn, value: mag })
                    };
                    if let Some(f) = failure {
                        out[l] = stop(o, stats, f);
                        live[l] = false;
                    }
                }
            }
            y = ys;
            if live != [true; L] {
                park(&mut y, &live);
            }
        }
        let before = live;
        observe(o, &y, &mut live);
        for l in 0..L {
            if before[l] && !live[l] {
                out[l] = stop(o + 1, stats, Failure::Stopped { t: tb });
            }
        }
    }
    for l in 0..L {
        if live[l] {
            out[l] = Outcome {
                reached: n_out,
                stats,
                failure: None,
            };
        }
    }
    out
}
