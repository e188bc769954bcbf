//! Refinement of known coefficients without a search: the tracked path of the daemon.
//!
//! A gate's next window overlaps the last by half; while the gate does not change, the previous
//! window's coefficients are already in the right basin, and the Levenberg-Marquardt polish
//! converges from them in a few iterations. This skips the DE entirely. (Measured, though, the
//! polishes at the fine tolerance and not the RK4 generations are most of a full window's cost,
//! and a tracked window is its polish's integrations: docs/benchmarks.md, "Where a tracked
//! window's CPU goes".) Whether the refined model is good enough is judged by the caller
//! (`analysis::tracking`), which runs the full identification when it is not.

use super::config::{Protocol, Search};

use super::polish::polish_to_budget;
use super::problem::{Initial, Problem};
use super::split::initial_from_data;
use super::{summarize, Identification, IdentifyError, InitialValues, RunResult};
use crate::de::Objective;
use std::time::Instant;

/// Refines `start` (physical coefficients `c1..cN`, e.g. the previous window's) on `problem` by
/// the Levenberg-Marquardt polish alone, charging at most `max_evaluations` integrations (at
/// least 2: the training cost at the start and at the end; `evaluations` of the run), on
/// the same train/test split as [`super::run`], at the polish tolerance `search.refine_rtol`
/// (the daemon's tracked path sets its own, `tracking.refine_rtol`). Returns one
/// run (seed `protocol.seed`, no history); its training MAE is the DE's measure, so it compares
/// with a full run's.
///
/// When the polish fails (the residuals cannot be computed at `start`, or it ends worse than
/// `start`), `start` itself is returned with its cost: the caller's acceptance test rejects it.
///
/// ```
/// use gatewatch::data::TimeSeries;
/// use gatewatch::identify::{refine, Config};
/// use gatewatch::model::Model;
/// let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
/// let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.01).collect();
/// // y = exp(-0.1 t) cos(w t) solves it with c1 = 0.2, c2 = w^2 + 0.01.
/// let w = 6.0f64;
/// let y: Vec<f64> = t.iter().map(|t| (-0.1 * t).exp() * (w * t).cos()).collect();
/// let series = TimeSeries::new(t, y).unwrap();
/// let config = Config::default();
/// let problem = config.problem(&model, &series).unwrap();
/// let id = refine(&problem, &config.search, &config.protocol, &[0.19, 36.3], 200).unwrap();
/// let c = &id.best_run().coefficients;
/// assert!((c[0] - 0.2).abs() < 0.02 && (c[1] - 36.01).abs() < 0.1, "{c:?}");
/// ```
pub fn refine(
    problem: &Problem<'_>,
    search: &Search,
    protocol: &Protocol,
    start: &[f64],
    max_evaluations: usize,
) -> Result<Identification, IdentifyError> {
    protocol.validate()?;
    search.validate()?;
    let (model, series) = (problem.model, problem.series);
    if start.len() != model.n_coeffs() {
        return Err(IdentifyError::Invalid {
            field: "start",
            reason: format!(
                "has {} coefficients, the model {}",
                start.len(),
                model.n_coeffs()
            ),
        });
    }
    if let Some(i) = start.iter().position(|c| !c.is_finite()) {
        return Err(IdentifyError::Invalid {
            field: "start",
            reason: format!("coefficient c{} is not finite", i + 1),
        });
    }
    let started = Instant::now();
    let super::Setup {
        scale_groups,
        train,
        test,
        fitness,
    } = super::setup(problem, protocol, search)?;
    // The polish's own solver and tolerance, as after a DE search.
    let fine = search.polish_fitness(&fitness);
    let mut x0 = fine.pack(start);
    if matches!(problem.initial, Initial::Fit) {
        // Fitted initial conditions start from the data's (scaled into DE coordinates).
        let (y0, v0) = initial_from_data(series);
        let n = x0.len();
        let s = fine.unpack(&[vec![0.0; n], vec![1.0, 1.0]].concat()).1;
        x0.extend_from_slice(&[y0 / s.y0, v0 / s.v0]);
    }
    let (target, x0) = match problem.polish_initial {
        Some((_, v_scale)) => fine.with_fitted_initial(&x0, v_scale),
        None => (fine.clone(), x0),
    };
    // The two training costs below are charged one integration each: the polish gets the rest,
    // so that the refinement never charges more than `max_evaluations`.
    let polished = polish_to_budget(&target, &x0, max_evaluations.saturating_sub(2).max(1));
    // The training costs at the start and the end come from the polish's residuals there when
    // it has them (the same numbers as `target.cost(x, inf)`, without integrating again); each
    // is charged one evaluation either way, so the count does not depend on it.
    let cost_at = |x: &[f64], r: &Option<Vec<f64>>| match r {
        Some(r) => target.cost_of_residuals(r),
        None => target.cost(x, f64::INFINITY, &mut target.workspace()),
    };
    let start_cost = cost_at(&x0, &polished.start);
    let mut evaluations = polished.spent + 1;
    let (mut x, mut train_cost) = (x0, start_cost);
    if let Some(p) = polished.x {
        let cost = cost_at(&p, &polished.end);
        evaluations += 1;
        // As after a search: least squares may move slightly off the MAE optimum on noisy data.
        if cost <= 1.01 * start_cost || !start_cost.is_finite() {
            (x, train_cost) = (p, cost);
        }
    }
    let (coefficients, init): (Vec<f64>, InitialValues) = target.unpack(&x);
    let test_nmae = super::test_nmae(problem, protocol, &coefficients, init, &test);
    let run = RunResult {
        seed: protocol.seed,
        coefficients,
        initial: init,
        train_mae: train_cost,
        test_nmae,
        train_integrated: target.integrated(train_cost),
        evaluations,
        refine_evaluations: evaluations,
        restarts: 0,
        seconds: started.elapsed().as_secs_f64(),
        history: Vec::new(),
    };
    let summary = summarize(std::iter::once(test_nmae.unwrap_or(f64::INFINITY)));
    Ok(Identification {
        runs: vec![run],
        best: 0,
        summary,
        train,
        test,
        scale_groups,
    })
}
