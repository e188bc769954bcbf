//! The training objective.

use super::config::Search;
use super::problem::Problem;
use super::problem::{Initial, Output};
use super::split::initial_from_data;
use super::stats::magnitude;
use super::InitialValues;
use crate::de::Objective;
use crate::model::{Bound, Model};
use crate::ode::{self, Method, Options};
use std::ops::ControlFlow;

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
            max_rhs_evals: 100 * substeps.max(2) * n + 50_000,
            initial_step: None,
        };
        let data_scale = magnitude(&series.y);
        let fail_base = match output {
            Output::Displacement => bound + data_scale,
            // Forces of a completing candidate are not bounded by the state bound; failures are
            // made dominant by a base far above any plausible force error instead.
            Output::Force => 1e12 * data_scale,
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
        }
    }

    /// The same objective with another solver and tolerance.
    pub fn with_tolerance(&self, method: Method, rtol: f64) -> Fitness<'a> {
        let mut f = self.clone();
        f.method = method;
        f.opts.rtol = rtol;
        f.opts.atol = rtol * 1e-3 * f.y_scale;
        f
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

    /// Integrates the model for `x` over the horizon and hands `(index, output)` to `each`.
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
            let value = match self.output {
                Output::Displacement => s[0],
                Output::Force => self.model.residual(times[i], s[0], s[1], coeffs),
            };
            each(i, value)
        })
    }

    /// Prediction minus data at each training sample of the horizon; `None` when the
    /// integration does not complete.
    pub fn residuals(&self, x: &[f64]) -> Option<Vec<f64>> {
        let mut buf = self.workspace();
        let mut out = Vec::with_capacity(self.n_train);
        let o = self.run(x, &mut buf, |i, v| {
            if self.is_train[i] {
                out.push(v - self.y[i]);
            }
            ControlFlow::Continue(())
        });
        (o.is_complete() && out.iter().all(|v| v.is_finite())).then_some(out)
    }

    /// Splits a DE vector into physical coefficients and initial conditions.
    pub fn unpack(&self, x: &[f64]) -> (Vec<f64>, InitialValues) {
        let mut buf = self.workspace();
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

impl Objective for Fitness<'_> {
    /// The physical coefficient vector, reused for every evaluation.
    type Workspace = Vec<f64>;

    fn dimension(&self) -> usize {
        self.model.n_coeffs()
            + if matches!(self.initial, Initial::Fit) {
                2
            } else {
                0
            }
    }

    fn workspace(&self) -> Vec<f64> {
        vec![0.0; self.dimension()]
    }

    fn cost(&self, x: &[f64], bound: f64, ws: &mut Vec<f64>) -> f64 {
        let limit = bound * self.n_train as f64;
        let (mut sum, mut reached) = (0.0, 0usize);
        let mut abandoned = false;
        let outcome = self.run(x, ws, |i, v| {
            if self.is_train[i] {
                let e = (v - self.y[i]).abs();
                if !e.is_finite() {
                    return ControlFlow::Break(());
                }
                sum += e;
                reached += 1;
                if sum > limit {
                    abandoned = true;
                    return ControlFlow::Break(());
                }
            }
            ControlFlow::Continue(())
        });
        if abandoned {
            return f64::INFINITY;
        }
        let n = self.n_train as f64;
        if outcome.is_complete() {
            sum / n
        } else {
            let missing = (self.n_train - reached.min(self.n_train)) as f64;
            self.fail_base * (1.0 + missing / n) + sum / n
        }
    }
}
