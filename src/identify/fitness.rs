//! The training objective.

use super::config::Search;
use super::problem::Problem;
use super::problem::{Initial, Output};
use super::split::initial_from_data;
use super::stats::magnitude;
use super::InitialValues;
use crate::de::Objective;
use crate::model::{Bound, BoundLanes, Model};
use crate::ode::{self, lanes, Method, Options, Outcome};
use std::ops::ControlFlow;

/// Default number of trials the fitness integrates in lockstep ([`super::Search::lanes`]): 8
/// lanes of `f64` fill two AVX registers or four SSE2 registers, and a population of 50 leaves
/// one partly filled batch per generation (docs/design.md, "A generation in lanes").
pub const LANES: usize = 8;

/// The training objective of section 8.3 with the corrected penalty (see the module docs).
///
/// The DE works on `x`; the model's coefficients (and fitted initial conditions) are `x[j] *
/// scale[j]`, so that a problem in physical units (kg, N s/m, N/m) is searched on numbers of
/// order one.
#[derive(Debug, Clone)]
pub struct Fitness<'a> {
    model: &'a Model,
    pub(super) t: &'a [f64],
    y: &'a [f64],
    is_train: Vec<bool>,
    n_train: usize,
    /// Only the first `horizon` samples are integrated and compared.
    horizon: usize,
    initial: Initial,
    output: Output,
    /// Physical value of each DE coordinate per unit.
    scales: Vec<f64>,
    method: Method,
    opts: Options,
    /// Largest magnitude of the displacement (scales tolerances and bounds).
    y_scale: f64,
    /// Largest per-sample error of a completing candidate: blow-up bound + data magnitude.
    fail_base: f64,
    /// Candidates integrated in lockstep by [`Objective::cost_batch`] (1, 4 or 8; 1 = one by
    /// one). Costs are identical either way.
    lanes: usize,
}

/// The work cap on right-hand-side evaluations of one integration over `n` samples with
/// `substeps` RK4 steps per sample interval: about 25 times what a well-behaved candidate needs.
fn max_rhs_evals(substeps: usize, n: usize) -> usize {
    100 * substeps.max(2) * n + 50_000
}

impl<'a> Fitness<'a> {
    /// The objective of `problem` on the samples flagged in `is_train`, integrated with the
    /// search's solver, tolerance and substeps. Initial conditions from the data are taken
    /// here ([`super::initial_from_data`]); the displacement's magnitude is the problem's, or
    /// the data's largest magnitude.
    pub fn new(problem: &Problem<'a>, is_train: Vec<bool>, search: &Search) -> Fitness<'a> {
        let (model, series, output) = (problem.model, problem.series, problem.output);
        let initial = match problem.initial {
            Initial::FromData => {
                let (y0, v0) = initial_from_data(series);
                Initial::Known { y0, v0 }
            }
            other => other,
        };
        let y_scale = problem.y_scale.unwrap_or_else(|| magnitude(&series.y));
        let (method, rtol, substeps) = (search.solver, search.rtol, search.substeps);
        let scales = problem.scales.clone();
        let n = series.len();
        let n_train = is_train.iter().filter(|b| **b).count().max(1);
        // The problem checked the scales' length; empty means all 1.
        let scales = if scales.is_empty() {
            vec![1.0; problem.dimension()]
        } else {
            scales
        };
        // The blow-up bound applies to displacement and velocity alike; velocities of a fast
        // oscillator exceed displacements by its angular frequency, hence the generous factor.
        let bound = 1e6 * y_scale;
        let opts = Options {
            rtol,
            atol: rtol * 1e-3 * y_scale,
            substeps,
            bound,
            // Work caps: about 25 times what a well-behaved candidate needs.
            max_steps: 50 * n + 10_000,
            max_rhs_evals: max_rhs_evals(substeps, n),
            initial_step: None,
        };
        let data_scale = magnitude(&series.y);
        let fail_base = match output {
            Output::Displacement => bound + data_scale,
            // Forces of a completing candidate are not bounded by the state bound; failures are
            // made dominant by a base far above any plausible force error instead.
            Output::Force | Output::RestoringForce => 1e12 * data_scale,
        };
        Fitness {
            model,
            t: &series.t,
            y: &series.y,
            is_train,
            n_train,
            horizon: n,
            initial,
            output,
            scales,
            method,
            opts,
            y_scale,
            fail_base,
            lanes: search.lanes,
        }
    }

    /// Whether `cost` (of [`Self::cost`]) is a completed integration's error rather than the
    /// penalty of a failed one (at least the failure base) or an abandoned one (infinite).
    pub fn integrated(&self, cost: f64) -> bool {
        cost.is_finite() && cost < self.fail_base
    }

    /// The same objective with `lanes` candidates per lockstep batch (1, 4 or 8; any other
    /// value means 1).
    pub fn with_lanes(&self, lanes: usize) -> Fitness<'a> {
        let mut f = self.clone();
        f.lanes = lanes;
        f
    }

    /// The same objective with another solver and tolerance.
    pub fn with_tolerance(&self, method: Method, rtol: f64) -> Fitness<'a> {
        let mut f = self.clone();
        f.method = method;
        f.opts.rtol = rtol;
        f.opts.atol = rtol * 1e-3 * f.y_scale;
        f
    }

    /// The same objective integrated with `method` at relative tolerance `rtol` (adaptive
    /// solvers) and `substeps` RK4 steps per sample interval (RK4; at least 1). The work caps
    /// follow the substeps, as in [`Fitness::new`].
    pub fn with_solver(&self, method: Method, rtol: f64, substeps: usize) -> Fitness<'a> {
        let mut f = self.with_tolerance(method, rtol);
        f.opts.substeps = substeps.max(1);
        f.opts.max_rhs_evals = max_rhs_evals(f.opts.substeps, self.t.len());
        f
    }

    /// The solver's relative tolerance.
    pub fn rtol(&self) -> f64 {
        self.opts.rtol
    }

    /// The same objective on the first `samples` samples only (at least 2).
    pub fn with_horizon(&self, samples: usize) -> Fitness<'a> {
        let mut f = self.clone();
        f.horizon = samples.clamp(2, self.t.len());
        f.n_train = f.is_train[..f.horizon]
            .iter()
            .filter(|b| **b)
            .count()
            .max(1);
        f
    }

    /// The same objective with the initial conditions fitted too, starting from the known ones:
    /// returns it and the DE vector `x` extended by the initial conditions.
    pub fn with_fitted_initial(&self, x: &[f64], v_scale: f64) -> (Fitness<'a>, Vec<f64>) {
        let mut f = self.clone();
        let mut x = x.to_vec();
        if let Initial::Known { y0, v0 } = self.initial {
            f.initial = Initial::Fit;
            f.scales.extend_from_slice(&[self.y_scale, v_scale]);
            x.extend_from_slice(&[y0 / self.y_scale, v0 / v_scale]);
        }
        (f, x)
    }

    /// The physical coefficients and initial conditions of a DE vector, written into `buf`.
    fn physical<'b>(&self, x: &[f64], buf: &'b mut [f64]) -> (&'b [f64], f64, f64) {
        for ((b, xi), s) in buf.iter_mut().zip(x).zip(&self.scales) {
            *b = xi * s;
        }
        let nc = self.model.n_coeffs();
        let (y0, v0) = match self.initial {
            Initial::Known { y0, v0 } => (y0, v0),
            _ => (buf[nc], buf[nc + 1]),
        };
        (&buf[..nc], y0, v0)
    }

    /// Integrates the model for `x` over the horizon and hands `(index, output)` of every
    /// training sample to `each` (the output at a test sample is never used by the fitness, and
    /// a force output costs a model evaluation).
    fn run(
        &self,
        x: &[f64],
        buf: &mut [f64],
        mut each: impl FnMut(usize, f64) -> ControlFlow<()>,
    ) -> ode::Outcome {
        let (coeffs, y0, v0) = self.physical(x, buf);
        let sys = Bound {
            model: self.model,
            coeffs,
        };
        let times = &self.t[..self.horizon];
        ode::integrate(self.method, &sys, [y0, v0], times, &self.opts, |i, s| {
            if !self.is_train[i] {
                return ControlFlow::Continue(());
            }
            each(i, self.output.value(self.model, times[i], s, coeffs))
        })
    }

    /// Prediction minus data at each training sample of the horizon; `None` when the
    /// integration does not complete.
    pub fn residuals(&self, x: &[f64]) -> Option<Vec<f64>> {
        let mut buf = vec![0.0; self.dimension()];
        let mut out = Vec::with_capacity(self.n_train);
        let o = match self.output {
            Output::Displacement => self.run(x, &mut buf, |i, v| {
                if self.is_train[i] {
                    out.push(v - self.y[i]);
                }
                ControlFlow::Continue(())
            }),
            Output::Force | Output::RestoringForce => {
                // The states first, the model's force at them afterwards, 8 samples at a time.
                let mut states = Vec::with_capacity(self.n_train);
                let (coeffs, y0, v0) = self.physical(x, &mut buf);
                let sys = Bound {
                    model: self.model,
                    coeffs,
                };
                let times = &self.t[..self.horizon];
                let o = ode::integrate(self.method, &sys, [y0, v0], times, &self.opts, |i, s| {
                    if self.is_train[i] {
                        states.push((i, s[0], s[1]));
                    }
                    ControlFlow::Continue(())
                });
                self.force_residuals(coeffs, &states, &mut out);
                o
            }
        };
        (o.is_complete() && out.iter().all(|v| v.is_finite())).then_some(out)
    }

    /// Appends `R(t_i, y, yd) - data_i` for every `(i, y, yd)` of `states`, the model evaluated
    /// on 8 samples at once (one coefficient vector in every lane).
    ///
    /// Why: a force output is one model evaluation per training sample, and evaluated as the
    /// integrator passes each sample it is a scalar interpreter call per sample (the lane
    /// integrators pass a sample at a different moment in every lane). Deferred, the samples
    /// share the lane evaluator, whose lanes equal the scalar evaluator bit for bit.
    fn force_residuals(&self, coeffs: &[f64], states: &[(usize, f64, f64)], out: &mut Vec<f64>) {
        const W: usize = 8;
        let c: Vec<[f64; W]> = coeffs.iter().map(|v| [*v; W]).collect();
        for chunk in states.chunks(W) {
            let (mut t, mut y, mut yd) = ([0.0; W], [0.0; W], [0.0; W]);
            for l in 0..W {
                // A short last chunk repeats its last sample in the unused lanes.
                let (i, a, b) = chunk[l.min(chunk.len() - 1)];
                (t[l], y[l], yd[l]) = (self.t[i], a, b);
            }
            let v = self
                .model
                .residual_lanes(&t, &y, &self.output.force_yd_lanes(&yd), &c);
            for (l, &(i, _, _)) in chunk.iter().enumerate() {
                out.push(v[l] - self.y[i]);
            }
        }
    }

    /// [`Fitness::residuals`] of each point in `xs` (rows of [`Objective::dimension`] values),
    /// the points integrated up to 8 at a time in lockstep by the lane integrators: the same
    /// vectors bit for bit (each lane performs its scalar integration's operations in the same
    /// order), in less time. The Levenberg-Marquardt polish's forward-difference Jacobian is such
    /// a batch: `d` integrations of nearby points at the polish tolerance, most of a full
    /// window's cost (docs/benchmarks.md, "Where a cold window's CPU goes").
    pub fn residuals_batch(&self, xs: &[f64]) -> Vec<Option<Vec<f64>>> {
        let d = self.dimension().max(1);
        let rows = xs.len() / d;
        let mut out = Vec::with_capacity(rows);
        if rows < 2 || matches!(self.method, Method::Rosenbrock) {
            out.extend(xs.chunks_exact(d).map(|x| self.residuals(x)));
            return out;
        }
        for chunk in xs[..rows * d].chunks(LANES * d) {
            if chunk.len() <= 4 * d {
                self.residuals_lanes::<4>(chunk, &mut out);
            } else {
                self.residuals_lanes::<LANES>(chunk, &mut out);
            }
        }
        out
    }

    /// Loads the first `n` points (rows of `xs`) into the lanes: their scaled coefficients into
    /// `c`, and returns their initial states and which lanes are live. Padding lanes repeat the
    /// first point, so they compute on ordinary numbers.
    fn load_lanes<const L: usize>(
        &self,
        xs: &[f64],
        n: usize,
        c: &mut [[f64; L]],
    ) -> ([[f64; L]; 2], [bool; L]) {
        let d = self.dimension();
        let nc = self.model.n_coeffs();
        let mut y0 = [[0.0; L]; 2];
        let mut live = [false; L];
        for l in 0..L {
            let x = &xs[(if l < n { l } else { 0 }) * d..][..d];
            live[l] = l < n;
            for (k, ck) in c.iter_mut().enumerate() {
                ck[l] = x[k] * self.scales[k];
            }
            (y0[0][l], y0[1][l]) = match self.initial {
                Initial::Known { y0, v0 } => (y0, v0),
                _ => (x[nc] * self.scales[nc], x[nc + 1] * self.scales[nc + 1]),
            };
        }
        (y0, live)
    }

    /// [`Fitness::residuals`] of up to `L` points (rows of `xs`) in lockstep, appended to `out`.
    fn residuals_lanes<const L: usize>(&self, xs: &[f64], out: &mut Vec<Option<Vec<f64>>>) {
        let d = self.dimension();
        let n = xs.len() / d;
        let nc = self.model.n_coeffs();
        let mut c = vec![[0.0; L]; nc];
        let (y0, live) = self.load_lanes(xs, n, &mut c);
        let mut res: Vec<Vec<f64>> = (0..n).map(|_| Vec::with_capacity(self.n_train)).collect();
        // Dormand-Prince with a force output: each lane's states, the forces afterwards.
        let defer = !matches!(self.method, Method::Rk4) && self.output.is_force();
        let mut states: Vec<Vec<(usize, f64, f64)>> = (0..if defer { n } else { 0 })
            .map(|_| Vec::with_capacity(self.n_train))
            .collect();
        let c: &[[f64; L]] = &c;
        let sys = BoundLanes {
            model: self.model,
            coeffs: c,
        };
        let times = &self.t[..self.horizon];
        let outcomes = match self.method {
            Method::Rk4 => lanes::rk4(&sys, &y0, live, times, &self.opts, |i, s, live| {
                if !self.is_train[i] {
                    return;
                }
                let v = match self.output {
                    Output::Displacement => s[0],
                    Output::Force | Output::RestoringForce => self.model.residual_lanes(
                        &[times[i]; L],
                        &s[0],
                        &self.output.force_yd_lanes(&s[1]),
                        c,
                    ),
                };
                for (l, r) in res.iter_mut().enumerate() {
                    if live[l] {
                        r.push(v[l] - self.y[i]);
                    }
                }
            }),
            _ => lanes::dopri5(&sys, &y0, live, times, &self.opts, |l, i, s| {
                if !self.is_train[i] {
                    return ControlFlow::Continue(());
                }
                match self.output {
                    Output::Displacement => res[l].push(s[0] - self.y[i]),
                    Output::Force | Output::RestoringForce => states[l].push((i, s[0], s[1])),
                }
                ControlFlow::Continue(())
            }),
        };
        if defer {
            let mut coeffs = vec![0.0; nc];
            for (l, (r, st)) in res.iter_mut().zip(&states).enumerate() {
                for (b, ck) in coeffs.iter_mut().zip(c) {
                    *b = ck[l];
                }
                self.force_residuals(&coeffs, st, r);
            }
        }
        for (r, o) in res.into_iter().zip(&outcomes) {
            out.push((o.is_complete() && r.iter().all(|v| v.is_finite())).then_some(r));
        }
    }

    /// The training cost of a point from its [`Fitness::residuals`]: bit for bit
    /// `cost(x, f64::INFINITY, ..)` when `r` is `residuals(x)` (the same absolute errors summed
    /// in the same order over the same count), without integrating again.
    pub fn cost_of_residuals(&self, r: &[f64]) -> f64 {
        r.iter().fold(0.0, |sum, e| sum + e.abs()) / self.n_train as f64
    }

    /// Splits a DE vector into physical coefficients and initial conditions.
    pub fn unpack(&self, x: &[f64]) -> (Vec<f64>, InitialValues) {
        let mut buf = vec![0.0; self.dimension()];
        let (c, y0, v0) = self.physical(x, &mut buf);
        (c.to_vec(), InitialValues { y0, v0 })
    }

    /// The DE vector of physical coefficients (the inverse of [`Fitness::unpack`] for the
    /// coefficients; fitted initial conditions are not included).
    pub fn pack(&self, coefficients: &[f64]) -> Vec<f64> {
        coefficients
            .iter()
            .zip(&self.scales)
            .map(|(c, s)| c / s)
            .collect()
    }
}

/// Scratch space of one thread's evaluations, made once per run: the physical coefficients of
/// a scalar evaluation, and of a lane batch in structure-of-arrays form.
#[derive(Debug, Clone)]
pub struct FitnessWorkspace {
    buf: Vec<f64>,
    c4: Vec<[f64; 4]>,
    c8: Vec<[f64; 8]>,
}

/// The running error sum of one candidate, sample by sample, with the early abandonment.
#[derive(Debug, Clone, Copy)]
struct Tally {
    limit: f64,
    sum: f64,
    reached: usize,
    abandoned: bool,
}

impl Tally {
    fn new(bound: f64, n_train: usize) -> Tally {
        Tally {
            limit: bound * n_train as f64,
            sum: 0.0,
            reached: 0,
            abandoned: false,
        }
    }

    /// Adds the output `v` at sample `i`; `Break` when the candidate can stop.
    #[inline(always)]
    fn add(&mut self, f: &Fitness<'_>, i: usize, v: f64) -> ControlFlow<()> {
        if f.is_train[i] {
            let e = (v - f.y[i]).abs();
            if !e.is_finite() {
                return ControlFlow::Break(());
            }
            self.sum += e;
            self.reached += 1;
            if self.sum > self.limit {
                self.abandoned = true;
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    }

    /// The cost once the integration has ended with `outcome`.
    fn cost(&self, f: &Fitness<'_>, outcome: &Outcome) -> f64 {
        if self.abandoned {
            return f64::INFINITY;
        }
        let n = f.n_train as f64;
        if outcome.is_complete() {
            self.sum / n
        } else {
            let missing = (f.n_train - self.reached.min(f.n_train)) as f64;
            f.fail_base * (1.0 + missing / n) + self.sum / n
        }
    }
}

impl Fitness<'_> {
    /// The costs of up to `L` candidates (rows of `xs`) integrated in lockstep; each equals
    /// [`Objective::cost`] on that candidate bit for bit (the lane integrators and the lane model
    /// evaluator perform each lane's scalar operations in the same order). Lanes beyond the
    /// candidates are padding: not live, never observed.
    fn cost_lanes<const L: usize>(
        &self,
        xs: &[f64],
        bounds: &[f64],
        out: &mut [f64],
        c: &mut [[f64; L]],
        buf: &mut [f64],
    ) {
        let n = out.len();
        let nc = self.model.n_coeffs();
        let (y0, live) = self.load_lanes(xs, n, c);
        let mut tally: [Tally; L] =
            std::array::from_fn(|l| Tally::new(bounds[l.min(n - 1)], self.n_train));
        let c: &[[f64; L]] = c;
        let sys = BoundLanes {
            model: self.model,
            coeffs: c,
        };
        let times = &self.t[..self.horizon];
        let outcomes = match self.method {
            Method::Rk4 => lanes::rk4(&sys, &y0, live, times, &self.opts, |i, s, live| {
                if !self.is_train[i] {
                    return;
                }
                let v = match self.output {
                    Output::Displacement => s[0],
                    Output::Force | Output::RestoringForce => self.model.residual_lanes(
                        &[times[i]; L],
                        &s[0],
                        &self.output.force_yd_lanes(&s[1]),
                        c,
                    ),
                };
                for l in 0..L {
                    if live[l] && tally[l].add(self, i, v[l]).is_break() {
                        live[l] = false;
                    }
                }
            }),
            _ => lanes::dopri5(&sys, &y0, live, times, &self.opts, |l, i, s| {
                if !self.is_train[i] {
                    return ControlFlow::Continue(());
                }
                let v = match self.output {
                    Output::Displacement => s[0],
                    Output::Force | Output::RestoringForce => {
                        // The lanes reach a sample at different moments: lane by lane.
                        for (b, ck) in buf.iter_mut().zip(c) {
                            *b = ck[l];
                        }
                        self.model
                            .residual(times[i], s[0], self.output.force_yd(s[1]), &buf[..nc])
                    }
                };
                tally[l].add(self, i, v)
            }),
        };
        for l in 0..n {
            out[l] = tally[l].cost(self, &outcomes[l]);
        }
    }
}

impl Objective for Fitness<'_> {
    type Workspace = FitnessWorkspace;

    fn dimension(&self) -> usize {
        self.model.n_coeffs()
            + if matches!(self.initial, Initial::Fit) {
                2
            } else {
                0
            }
    }

    fn workspace(&self) -> FitnessWorkspace {
        let nc = self.model.n_coeffs();
        FitnessWorkspace {
            buf: vec![0.0; self.dimension()],
            c4: vec![[0.0; 4]; nc],
            c8: vec![[0.0; 8]; nc],
        }
    }

    fn cost(&self, x: &[f64], bound: f64, ws: &mut FitnessWorkspace) -> f64 {
        let mut tally = Tally::new(bound, self.n_train);
        let outcome = self.run(x, &mut ws.buf, |i, v| tally.add(self, i, v));
        tally.cost(self, &outcome)
    }

    fn batch_width(&self) -> usize {
        self.lane_width()
    }

    fn cost_batch(&self, xs: &[f64], bounds: &[f64], out: &mut [f64], ws: &mut FitnessWorkspace) {
        let d = self.dimension();
        let width = self.lane_width();
        let mut first = 0;
        while first < out.len() {
            let n = (out.len() - first).min(width);
            let (rows, b, o) = (
                &xs[first * d..(first + n) * d],
                &bounds[first..first + n],
                &mut out[first..first + n],
            );
            match width {
                8 => self.cost_lanes::<8>(rows, b, o, &mut ws.c8, &mut ws.buf),
                4 => self.cost_lanes::<4>(rows, b, o, &mut ws.c4, &mut ws.buf),
                _ => o[0] = self.cost(rows, b[0], ws),
            }
            first += n;
        }
    }
}

impl Fitness<'_> {
    /// The lane width actually used: the configured one for RK4 and Dormand-Prince, 1 for the
    /// stiff solver (no lane version) and for anything but 4 or 8.
    fn lane_width(&self) -> usize {
        match (self.method, self.lanes) {
            (Method::Rosenbrock, _) => 1,
            (_, w @ (4 | 8)) => w,
            _ => 1,
        }
    }
}
