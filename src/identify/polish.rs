//! The Levenberg-Marquardt polish of a DE winner.

use super::fitness::Fitness;
use crate::de::Objective;
use std::cell::{Cell, RefCell};

/// What [`polish`] found.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Polished {
    /// The polished point (`None` when the residuals cannot be computed at the start or the
    /// minimisation failed).
    pub x: Option<Vec<f64>>,
    /// Integrations charged: every residual vector the minimisation asked for, including the
    /// ones answered from [`Residuals`]' memory, so that the search's evaluation budget and the
    /// reported counts do not depend on the reuse (docs/benchmarks.md, "Tracking between
    /// windows").
    pub spent: usize,
    /// Integrations actually performed (at most `spent`).
    pub integrated: usize,
    /// The residuals at the start point, when they could be computed.
    pub start: Option<Vec<f64>>,
    /// The residuals at the polished point, when the last integration was at that point.
    pub end: Option<Vec<f64>>,
}

/// A point and its residuals (`None`: the integration did not complete).
type Remembered = (Vec<f64>, Option<Vec<f64>>);

/// A point, its residuals and their sum of squares.
type Scored = (Vec<f64>, Vec<f64>, f64);

/// The residuals of `fit` at a point, remembering the last point computed.
///
/// Why: MINPACK's loop asks for the residuals at a point and, when the step is accepted, for the
/// Jacobian at the same point, whose forward differences need those residuals again; the polish's
/// caller also needs the start and end points' training cost. Each is a full integration at the
/// polish tolerance (most of a tracked window's cost). An integration is deterministic, so a
/// remembered vector is bit for bit the one a new integration would give.
struct Residuals<'f, 'a> {
    fit: &'f Fitness<'a>,
    /// The last point integrated and its residuals (`None` when it did not complete).
    last: RefCell<Option<Remembered>>,
    /// The point with the smallest sum of squares seen by [`Residuals::at`], its residuals and
    /// that sum: what the polish returns when the budget stops the minimisation mid-iteration
    /// (the crate's own point is then an untried trial step).
    best: RefCell<Option<Scored>>,
    /// Integrations that may be charged in all (`spent` never exceeds it).
    budget: usize,
    /// Whether a request was refused because the budget was spent.
    exhausted: Cell<bool>,
    spent: Cell<usize>,
    integrated: Cell<usize>,
}

impl<'f, 'a> Residuals<'f, 'a> {
    fn new(fit: &'f Fitness<'a>, budget: usize) -> Self {
        Residuals {
            fit,
            last: RefCell::new(None),
            best: RefCell::new(None),
            budget,
            exhausted: Cell::new(false),
            spent: Cell::new(0),
            integrated: Cell::new(0),
        }
    }

    /// Whether `n` more integrations may be charged; when not, the budget counts as exhausted
    /// (the minimisation stops at its next request).
    fn affords(&self, n: usize) -> bool {
        let ok = self.spent.get() + n <= self.budget;
        if !ok {
            self.exhausted.set(true);
        }
        ok
    }

    /// The residuals at `x` (charged one integration), from memory when `x` is bit for bit the
    /// last point; `None` also when the budget is spent.
    fn at(&self, x: &[f64]) -> Option<Vec<f64>> {
        if !self.affords(1) {
            return None;
        }
        self.spent.set(self.spent.get() + 1);
        if let Some(r) = self.remembered(x) {
            return r;
        }
        self.integrated.set(self.integrated.get() + 1);
        let r = self.fit.residuals(x);
        if let Some(r) = &r {
            let ssq: f64 = r.iter().map(|v| v * v).sum();
            let mut best = self.best.borrow_mut();
            // NaN never replaces a point (the comparison is false).
            if best.as_ref().is_none_or(|b| ssq < b.2) {
                *best = Some((x.to_vec(), r.clone(), ssq));
            }
        }
        *self.last.borrow_mut() = Some((x.to_vec(), r.clone()));
        r
    }

    /// The remembered residuals when `x` is the last point (not charged).
    fn remembered(&self, x: &[f64]) -> Option<Option<Vec<f64>>> {
        let last = self.last.borrow();
        let (lx, r) = last.as_ref()?;
        let same = lx.len() == x.len() && lx.iter().zip(x).all(|(a, b)| a.to_bits() == b.to_bits());
        same.then(|| r.clone())
    }

    /// The columns of the forward-difference Jacobian at the points `xs` (rows of the
    /// dimension), integrated in lanes; a point the minimisation never revisits, so the memory is kept.
    fn columns(&self, xs: &[f64]) -> Vec<Option<Vec<f64>>> {
        let n = xs.len() / self.fit.dimension().max(1);
        if !self.affords(n) {
            return vec![None; n];
        }
        let r = self.fit.residuals_batch(xs);
        // Charged as one by one, which stops at the first failed column: the counts (and so the
        // budget's effect) are the same bit for bit; all n were integrated.
        let charged = r.iter().position(Option::is_none).map_or(n, |k| k + 1);
        self.spent.set(self.spent.get() + charged);
        self.integrated.set(self.integrated.get() + n);
        r
    }
}

/// The relative step of the forward-difference Jacobian for a solver at relative tolerance
/// `rtol`: 10 times the tolerance, never below 1e-6 (so 1e-6 at the library's 1e-8, as before).
///
/// Why: a column is `(r(x + h) - r(x)) / h`, and each residual carries the solver's error (about
/// `rtol`, and not smooth in `x`: the step-size sequence changes with it), so the column's noise
/// is about `rtol / h` relative. A fixed 1e-6 at the daemon's 1e-6 made that 100 %: many
/// refinements did not move and a steady gate's tracked mass drifted (docs/design.md, "Tracking
/// between windows"). At 10 times the tolerance the noise is about 10 %, which Gauss-Newton
/// steps tolerate, and the forward difference's truncation error (about `h`) stays far below.
/// Measured (docs/benchmarks.md, "A looser polish for noisy windows"): over 20 seeds of the
/// stable lab gate, factors 10, 30 and 100 gave tracked masses as close to the truth as the
/// refinement at 1e-8. With RK4 (the daemon's `polish_solver = "rk4"`) the residuals carry no
/// step-size noise; the step still follows the tolerance the polish is given (1e-5 at the
/// daemon's 1e-6), which is what the RK4 polish was measured with.
pub(super) fn fd_step(rtol: f64) -> f64 {
    (10.0 * rtol).max(1e-6)
}

/// Levenberg-Marquardt (MINPACK's algorithm, from the `levenberg-marquardt` crate) on the
/// simulation residuals of the training samples, from the DE winner `x0`, with a
/// forward-difference Jacobian. Returns the polished point (`None` when the residuals cannot be
/// computed at `x0`), the integrations charged (never more than `max_evaluations`, at least 1)
/// and the residuals
/// at the start and the end, which give the training cost there without another integration
/// ([`Fitness::cost_of_residuals`]).
///
/// Why least squares here: near the optimum the residuals are smooth in the coefficients, so a
/// Gauss-Newton method converges in a handful of iterations (a few dozen integrations), where a
/// simplex on the absolute error needs hundreds.
pub(super) fn polish(fine: &Fitness<'_>, x0: &[f64], max_evaluations: usize) -> Polished {
    polish_with(fine, x0, max_evaluations, false)
}

/// [`polish`] whose only limit is the budget (the crate's patience never binds first): the
/// tracked refinement's, where the budget is small and the minimisation should use all of it.
pub(super) fn polish_to_budget(fine: &Fitness<'_>, x0: &[f64], max_evaluations: usize) -> Polished {
    polish_with(fine, x0, max_evaluations, true)
}

fn polish_with(
    fine: &Fitness<'_>,
    x0: &[f64],
    max_evaluations: usize,
    budget_only: bool,
) -> Polished {
    use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
    use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};

    struct Problem<'r, 'f, 'a> {
        res: &'r Residuals<'f, 'a>,
        x: DVector<f64>,
    }
    impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, '_, '_> {
        type ResidualStorage = Owned<f64, Dyn>;
        type JacobianStorage = Owned<f64, Dyn, Dyn>;
        type ParameterStorage = Owned<f64, Dyn>;
        fn set_params(&mut self, x: &DVector<f64>) {
            self.x.copy_from(x);
        }
        fn params(&self) -> DVector<f64> {
            self.x.clone()
        }
        fn residuals(&self) -> Option<DVector<f64>> {
            self.res.at(self.x.as_slice()).map(DVector::from_vec)
        }
        fn jacobian(&self) -> Option<DMatrix<f64>> {
            // The crate asks for the Jacobian right after the residuals at the same point: this
            // is answered from memory.
            // A Jacobian is worth its d + 1 charged integrations only when a trial step can
            // follow it: otherwise stop here, at the current (accepted) point.
            if !self.res.affords(self.x.len() + 2) {
                return None;
            }
            let r0 = DVector::from_vec(self.res.at(self.x.as_slice())?);
            let d = self.x.len();
            // Large enough to stay above the solver's error, small enough for accuracy.
            let rel = fd_step(self.res.fit.rtol());
            let h = |j: usize| rel * self.x[j].abs().max(1e-3);
            // The d forward points, integrated together (`Fitness::residuals_batch`: the same
            // residuals as one by one, bit for bit).
            let mut points = Vec::with_capacity(d * d);
            for j in 0..d {
                points.extend_from_slice(self.x.as_slice());
                points[j * d + j] = self.x[j] + h(j);
            }
            let forward = self.res.columns(&points);
            let mut jac = DMatrix::zeros(r0.len(), d);
            for (j, rp) in forward.into_iter().enumerate() {
                // A failed column ends the minimisation at the current point (its caller then
                // judges that point).
                let rp = DVector::from_vec(rp?);
                jac.set_column(j, &((rp - &r0) / h(j)));
            }
            Some(jac)
        }
    }

    let d = x0.len();
    let res = Residuals::new(fine, max_evaluations.max(1));
    let problem = Problem {
        res: &res,
        x: DVector::from_column_slice(x0),
    };
    let start = problem.res.at(x0);
    let done = |x: Option<Vec<f64>>, start: Option<Vec<f64>>| {
        let end = x.as_deref().and_then(|x| res.remembered(x)).flatten();
        // When the budget stopped it, the best point seen and its residuals (the crate may hold
        // an untried or refused trial step).
        if res.exhausted.get() {
            if let Some((bx, br, _)) = res.best.borrow().clone() {
                return Polished {
                    x: Some(bx),
                    spent: res.spent.get(),
                    integrated: res.integrated.get(),
                    start,
                    end: Some(br),
                };
            }
        }
        Polished {
            x,
            spent: res.spent.get(),
            integrated: res.integrated.get(),
            start,
            end,
        }
    };
    if start.is_none() {
        return done(None, None);
    }
    // The patience from the real cost: the crate bounds residual evaluations (trial steps) by
    // patience * (d + 1), and each accepted step also costs a Jacobian (d + 1 charged
    // integrations here), hence the division. The floor is 1 (the crate's minimum): the former
    // floor of 4 let a 60-integration budget spend up to 4 * 6 * 7 = 168 with d = 5. The budget
    // itself is enforced by `Residuals` (a Jacobian is refused when a trial step could not
    // follow it, a residual request when nothing is left), so `max_evaluations` is a hard cap.
    let patience = if budget_only {
        // at most `max_evaluations` trial steps: never reached before the cap
        max_evaluations.max(1)
    } else {
        (max_evaluations / ((d + 1) * (d + 2))).max(1)
    };
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(patience)
        .with_ftol(1e-12)
        .with_xtol(1e-12)
        .minimize(problem);
    let ok = !report.termination.was_usage_issue() && report.objective_function.is_finite();
    let x = ok.then(|| problem.x.as_slice().to_vec());
    done(x, start)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::TimeSeries;
    use crate::de::Objective;
    use crate::identify::{Initial, Problem, Search};
    use crate::model::Model;
    use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
    use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};

    /// The polish as it was before the residuals were remembered: every request integrates.
    struct Plain<'f, 'a> {
        fit: &'f Fitness<'a>,
        x: DVector<f64>,
        evaluations: Cell<usize>,
    }
    impl LeastSquaresProblem<f64, Dyn, Dyn> for Plain<'_, '_> {
        type ResidualStorage = Owned<f64, Dyn>;
        type JacobianStorage = Owned<f64, Dyn, Dyn>;
        type ParameterStorage = Owned<f64, Dyn>;
        fn set_params(&mut self, x: &DVector<f64>) {
            self.x.copy_from(x);
        }
        fn params(&self) -> DVector<f64> {
            self.x.clone()
        }
        fn residuals(&self) -> Option<DVector<f64>> {
            self.evaluations.set(self.evaluations.get() + 1);
            self.fit.residuals(self.x.as_slice()).map(DVector::from_vec)
        }
        fn jacobian(&self) -> Option<DMatrix<f64>> {
            let r0 = self.residuals()?;
            let mut jac = DMatrix::zeros(r0.len(), self.x.len());
            let mut xp = self.x.clone();
            for j in 0..self.x.len() {
                let h = 1e-6 * self.x[j].abs().max(1e-3);
                xp[j] = self.x[j] + h;
                self.evaluations.set(self.evaluations.get() + 1);
                let rp = self.fit.residuals(xp.as_slice())?;
                jac.set_column(j, &((DVector::from_vec(rp) - &r0) / h));
                xp[j] = self.x[j];
            }
            Some(jac)
        }
    }

    fn plain(fit: &Fitness<'_>, x0: &[f64], max_evaluations: usize) -> (Option<Vec<f64>>, usize) {
        let d = x0.len();
        let p = Plain {
            fit,
            x: DVector::from_column_slice(x0),
            evaluations: Cell::new(0),
        };
        if p.residuals().is_none() {
            return (None, p.evaluations.get());
        }
        let patience = (max_evaluations / ((d + 1) * (d + 2))).max(1);
        let (p, report) = LevenbergMarquardt::new()
            .with_patience(patience)
            .with_ftol(1e-12)
            .with_xtol(1e-12)
            .minimize(p);
        let ok = !report.termination.was_usage_issue() && report.objective_function.is_finite();
        (ok.then(|| p.x.as_slice().to_vec()), p.evaluations.get())
    }

    /// A decaying oscillation the test model cannot fit exactly: a few LM iterations.
    fn decaying_series() -> TimeSeries {
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.02).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|t| (-0.05 * t).exp() * (3.0 * t).cos() + 0.01 * (7.0 * t).sin())
            .collect();
        TimeSeries::new(t, y).unwrap()
    }

    #[test]
    fn remembered_residuals_give_the_plain_polish_bit_for_bit_with_fewer_integrations() {
        let model = Model::parse("ydd + (c1 + c2*y^2)*yd + c3*y = 0", &[]).unwrap();
        let series = decaying_series();
        let problem = Problem::new(&model, &series)
            .unwrap()
            .with_initial(Initial::Known { y0: 1.0, v0: 0.0 })
            .unwrap();
        let is_train: Vec<bool> = (0..series.len()).map(|i| i % 2 == 0).collect();
        let fit = Fitness::new(&problem, is_train, &Search::default())
            .with_tolerance(crate::ode::Method::Dopri5, 1e-8);
        // Budgets of 20 and 40 end on the patience right after an accepted step, whose
        // residuals are then the last integrated (`end` known); 60 and 300 end on a refused
        // trial step (`end` unknown). Both are checked below.
        for (x0, budget, end_known) in [
            (vec![0.2, 0.1, 8.0], 20, true),
            (vec![0.2, 0.1, 8.0], 60, false),
            (vec![0.0, 0.0, 10.0], 40, true),
            (vec![0.0, 0.0, 10.0], 300, false),
        ] {
            let (want, want_spent) = plain(&fit, &x0, budget);
            let got = polish(&fit, &x0, budget);
            let bits = |x: &Option<Vec<f64>>| {
                x.as_ref()
                    .map(|x| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            };
            assert!(want.is_some());
            assert_eq!(bits(&got.x), bits(&want), "{x0:?}");
            // charged as before, integrated less: the start point once, the residuals at each
            // accepted point once
            assert_eq!(got.spent, want_spent, "{x0:?}");
            assert!(got.integrated < got.spent, "{got:?}");
            // the remembered residuals are the ones a new integration gives
            assert_eq!(got.start, fit.residuals(&x0));
            // (the end's are known only when the last integration was at the polished point,
            // not at a refused trial step)
            assert_eq!(got.end.is_some(), end_known, "{x0:?}, budget {budget}");
            if let Some(end) = &got.end {
                let x = got.x.as_ref().unwrap();
                assert_eq!(Some(end.clone()), fit.residuals(x));
                // and give the training cost bit for bit
                let cost = fit.cost(x, f64::INFINITY, &mut fit.workspace());
                assert_eq!(fit.cost_of_residuals(end).to_bits(), cost.to_bits());
            }
            let start = got.start.clone().unwrap();
            let cost0 = fit.cost(&x0, f64::INFINITY, &mut fit.workspace());
            assert_eq!(fit.cost_of_residuals(&start).to_bits(), cost0.to_bits());
        }
    }

    #[test]
    fn the_budget_is_a_hard_cap_and_the_best_point_is_returned() {
        let model = Model::parse("ydd + (c1 + c2*y^2)*yd + c3*y = 0", &[]).unwrap();
        let series = decaying_series();
        let problem = Problem::new(&model, &series)
            .unwrap()
            .with_initial(Initial::Known { y0: 1.0, v0: 0.0 })
            .unwrap();
        let is_train: Vec<bool> = (0..series.len()).map(|i| i % 2 == 0).collect();
        let fit = Fitness::new(&problem, is_train, &Search::default())
            .with_tolerance(crate::ode::Method::Dopri5, 1e-8);
        let x0 = [0.0, 0.0, 10.0];
        let cost = |x: &[f64]| fit.cost(x, f64::INFINITY, &mut fit.workspace());
        // Unbounded, this start takes more than 30 integrations (42 measured), all of which the
        // old patience floor of 4 allowed under a budget of 20 (up to 4 * 4 * 5 + 2 = 82 with
        // d = 3).
        let free = polish(&fit, &x0, 10_000);
        assert!(free.spent > 30, "{}", free.spent);
        let mut last = cost(&x0);
        for budget in [1, 2, 5, 6, 7, 12, 20, 30, 45, 60] {
            let got = polish(&fit, &x0, budget);
            assert!(
                got.spent <= budget,
                "budget {budget}: {} charged",
                got.spent
            );
            assert!(got.integrated <= got.spent);
            let x = got.x.expect("a point");
            // the best point seen, with its residuals: never worse than the start, and (with
            // deterministic steps) no worse than with a smaller budget
            let c = cost(&x);
            assert!(
                c <= cost(&x0) && c <= last * (1.0 + 1e-12),
                "budget {budget}: {c} > {last}"
            );
            last = c;
            // (known when the budget stopped it, or the last integration was at the point)
            if let Some(end) = got.end {
                assert_eq!(fit.cost_of_residuals(&end).to_bits(), c.to_bits());
            }
        }
    }

    #[test]
    fn a_start_that_cannot_be_integrated_is_reported_without_a_point() {
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let t: Vec<f64> = (0..100).map(|i| i as f64 * 0.05).collect();
        let y: Vec<f64> = t.iter().map(|t| t.cos()).collect();
        let series = TimeSeries::new(t, y).unwrap();
        let problem = Problem::new(&model, &series).unwrap();
        let fit = Fitness::new(&problem, vec![true; 100], &Search::default());
        let got = polish(&fit, &[f64::NAN, 1.0], 60);
        assert_eq!(
            (got.x, got.spent, got.integrated, got.start),
            (None, 1, 1, None)
        );
    }
}
