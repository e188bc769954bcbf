//! The Levenberg-Marquardt polish of a DE winner.

use super::fitness::Fitness;

/// Levenberg-Marquardt (MINPACK's algorithm, from the `levenberg-marquardt` crate) on the
/// simulation residuals of the training samples, from the DE winner `x0`, with a
/// forward-difference Jacobian. Returns the polished point (`None` when the residuals cannot be
/// computed at `x0`) and the integrations spent (at most about `max_evaluations`).
///
/// Why least squares here: near the optimum the residuals are smooth in the coefficients, so a
/// Gauss-Newton method converges in a handful of iterations (a few dozen integrations), where a
/// simplex on the absolute error needs hundreds.
pub(super) fn polish(
    fine: &Fitness<'_>,
    x0: &[f64],
    max_evaluations: usize,
) -> (Option<Vec<f64>>, usize) {
    use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
    use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};
    use std::cell::Cell;

    struct Problem<'f, 'a> {
        fit: &'f Fitness<'a>,
        x: DVector<f64>,
        evaluations: Cell<usize>,
    }
    impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, '_> {
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
                // Large enough to stay above the solver's error, small enough for accuracy.
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

    let d = x0.len();
    let problem = Problem {
        fit: fine,
        x: DVector::from_column_slice(x0),
        evaluations: Cell::new(0),
    };
    if problem.residuals().is_none() {
        return (None, problem.evaluations.get());
    }
    // The crate bounds residual evaluations by patience * (d + 1); each also costs a Jacobian
    // (d + 1 integrations here), hence the division.
    let patience = (max_evaluations / ((d + 1) * (d + 2))).max(4);
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(patience)
        .with_ftol(1e-12)
        .with_xtol(1e-12)
        .minimize(problem);
    let spent = problem.evaluations.get();
    let ok = !report.termination.was_usage_issue() && report.objective_function.is_finite();
    (ok.then(|| problem.x.as_slice().to_vec()), spent)
}
