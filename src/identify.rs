//! Identification: the coefficients of a model from a sampled signal (sections 8.3 and 8.4).
//!
//! One run is: a Cauchy DE on the training samples with the evaluation solver and tolerance (the
//! chapter's protocol), then, beyond the chapter, a Levenberg-Marquardt polish of the DE winner on the
//! same training samples with a tighter solver tolerance, and a restart of the DE when its
//! population stagnates. The test NMAE is computed on the held-out samples with the test
//! tolerance. Several runs with consecutive seeds give the spread the chapter reports.
//!
//! # Fitness
//! The chapter's fitness, `-MAE * penalty` over the samples the solver reached, rewards a
//! candidate whose integration dies right after `t0` (a perfect 0 on the one sample it reached).
//! Here a candidate that completes costs its training MAE; a candidate that fails costs
//! `B * (1 + missing / n_train) + partial_sum / n_train`, where `B` is the largest error any
//! completing candidate can have per sample (the integrator's blow-up bound plus the data's
//! largest magnitude). So a failed candidate never beats a completed one, and among failures the
//! one that got further wins, which gives the search a direction. The solver's work per
//! evaluation is capped, so a pathological candidate (chattering `sign()`, extreme stiffness)
//! costs a bounded time and counts as failed.

use crate::data::TimeSeries;
use crate::de::{self, Objective};
use crate::model::{Bound, Model};
use crate::ode::{self, Method, Options};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::ops::ControlFlow;
use std::time::Instant;

/// Where the initial conditions `y(t0)`, `yd(t0)` come from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Initial {
    /// Given by the caller.
    Known {
        /// `y(t0)`.
        y0: f64,
        /// `yd(t0)`.
        v0: f64,
    },
    /// `y0` is the first sample; `v0` the slope at `t0` of a least-squares quadratic through the
    /// first samples (up to 7).
    FromData,
    /// Identified as two extra unknowns after the coefficients.
    Fit,
}

/// Settings of an identification. [`Config::default`] is the chapter's protocol with the
/// improvements switched on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Config {
    /// Initial conditions.
    pub initial: Initial,
    /// Fraction of the samples used for training (the rest is the test set).
    pub train_fraction: f64,
    /// Seed of the random train/test split.
    pub split_seed: u64,
    /// DE population size.
    pub population: usize,
    /// DE generations.
    pub generations: usize,
    /// Independent runs (seeds `seed`, `seed + 1`, ...).
    pub runs: usize,
    /// Seed of the first run.
    pub seed: u64,
    /// Solver used in the fitness.
    pub solver: Method,
    /// Relative tolerance of the fitness solver (chapter: 1e-3).
    pub rtol: f64,
    /// Relative tolerance of the test solver (chapter: 1e-5); the test always uses Dormand-Prince.
    pub test_rtol: f64,
    /// RK4 steps per sample interval.
    pub substeps: usize,
    /// Polish the DE winner with Levenberg-Marquardt (not in the chapter).
    pub refine: bool,
    /// Relative tolerance of the solver during the polish.
    pub refine_rtol: f64,
    /// Integrations the polish may spend (about).
    pub refine_evaluations: usize,
    /// Restart a stagnating DE population (not in the chapter).
    pub restart: bool,
    /// Grow the fitted horizon in three stages (not in the chapter; see [`identify`]).
    pub continuation: bool,
    /// Attempts of one run: a run whose fit stays poor tries again from another seed, with the
    /// generations left in twice the chapter's evaluation budget (1: never).
    pub max_attempts: usize,
    /// Evaluate each generation's trials in parallel (results are identical either way).
    pub parallel: bool,
    /// Individuals placed first in the initial population of every run (warm start, bias), in
    /// the DE's coordinates (coefficients, then `y0`, `v0` when fitted).
    pub initial_population: Vec<Vec<f64>>,
    /// What the data are: displacement, or the support force (section 8.5).
    pub output: Output,
    /// Physical value per unit of each DE coordinate (empty: 1). See [`Fitness`].
    pub scales: Vec<f64>,
    /// Magnitude of the displacement, for tolerances and bounds (`None`: the data's).
    pub y_scale: Option<f64>,
    /// Let the polish adjust known initial conditions too, with these scales for `(y0, v0)`
    /// (force mode: the pre-run's initial conditions are estimates).
    pub polish_initial: Option<(f64, f64)>,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            initial: Initial::FromData,
            train_fraction: 0.5,
            split_seed: 1,
            population: 50,
            generations: 120,
            runs: 1,
            seed: 1,
            solver: Method::Dopri5,
            rtol: 1e-3,
            test_rtol: 1e-5,
            substeps: 2,
            refine: true,
            refine_rtol: 1e-8,
            refine_evaluations: 300,
            restart: true,
            continuation: true,
            max_attempts: 3,
            parallel: false,
            initial_population: Vec::new(),
            output: Output::Displacement,
            scales: Vec::new(),
            y_scale: None,
            polish_initial: None,
        }
    }
}

/// Why an identification could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// An option is out of range.
    #[error("{0}")]
    Option(String),
    /// Too few samples for the split.
    #[error("{samples} samples are too few: the split needs at least {needed} ({train} train, {test} test)")]
    TooFewSamples {
        samples: usize,
        needed: usize,
        train: usize,
        test: usize,
    },
    /// The model has no unknowns to identify.
    #[error("the model has no unknown coefficients (c1, c2, ...) to identify")]
    NoUnknowns,
    /// RK4 needs uniformly spaced samples.
    #[error("the rk4 solver needs uniformly spaced samples; use --solver dopri5 for this file")]
    NotUniform,
    /// The DE refused its settings.
    #[error(transparent)]
    De(#[from] de::DeError),
}

/// One run's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunResult {
    /// The run's DE seed.
    pub seed: u64,
    /// Identified coefficients `c1..cN`.
    pub coefficients: Vec<f64>,
    /// Initial conditions used or identified.
    pub initial: InitialValues,
    /// Training MAE of the final coefficients (at the polish tolerance when polished).
    pub train_mae: f64,
    /// Test NMAE (`None` when the test integration failed).
    pub test_nmae: Option<f64>,
    /// Objective evaluations (DE and polish).
    pub evaluations: usize,
    /// Of which spent by the polish.
    pub refine_evaluations: usize,
    /// DE restarts.
    pub restarts: usize,
    /// Wall time of the run, seconds.
    pub seconds: f64,
    /// Best-so-far training cost per generation (the chapter's Figure 8.5, right).
    pub history: Vec<f64>,
}

/// Initial conditions of a result.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InitialValues {
    /// `y(t0)`.
    pub y0: f64,
    /// `yd(t0)`.
    pub v0: f64,
}

/// Mean, standard deviation and minimum of the runs' test NMAE.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Summary {
    /// Mean test NMAE (failed tests count as infinite).
    pub mean: f64,
    /// Sample standard deviation (0 for one run).
    pub std: f64,
    /// Smallest test NMAE.
    pub min: f64,
    /// Median test NMAE.
    pub median: f64,
}

/// The result of [`identify`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Identification {
    /// Every run, in seed order.
    pub runs: Vec<RunResult>,
    /// Index of the run with the smallest training MAE (never chosen on test data).
    pub best: usize,
    /// Test NMAE statistics over the runs.
    pub summary: Summary,
    /// Indices of the training samples.
    pub train: Vec<usize>,
    /// Indices of the test samples.
    pub test: Vec<usize>,
}

impl Identification {
    /// The chosen run.
    pub fn best_run(&self) -> &RunResult {
        &self.runs[self.best]
    }
}

/// Identifies `model`'s coefficients from `series`. `progress(run, generation, best_cost)` is
/// called after every generation.
pub fn identify(
    model: &Model,
    series: &TimeSeries,
    config: &Config,
    mut progress: impl FnMut(usize, usize, f64),
) -> Result<Identification, IdentifyError> {
    validate(config)?;
    if model.n_coeffs() == 0 {
        return Err(IdentifyError::NoUnknowns);
    }
    if config.solver == Method::Rk4 && series.uniform_step().is_none() {
        return Err(IdentifyError::NotUniform);
    }
    let (train, test) = split(series.len(), config.train_fraction, config.split_seed)?;
    let mut is_train = vec![false; series.len()];
    for &i in &train {
        is_train[i] = true;
    }
    let initial = match config.initial {
        Initial::FromData => {
            let (y0, v0) = initial_from_data(series);
            Initial::Known { y0, v0 }
        }
        other => other,
    };
    let y_scale = config.y_scale.unwrap_or_else(|| magnitude(&series.y));
    let fitness = Fitness::new(
        model,
        series,
        is_train,
        initial,
        config.output,
        config.scales.clone(),
        y_scale,
        config.solver,
        config.rtol,
        config.substeps,
    );
    let spread = std_dev(&series.y);
    let mut runs = Vec::with_capacity(config.runs);
    // Budget of a run: twice the chapter's NP + G (NP + 1) evaluations. A run whose fit is poor
    // (above 1 % of the data's spread) tries again from a fresh seed while this allows.
    let budget = 2 * (config.population + config.generations * (config.population + 1));
    // A fit is good when its training MAE is within 1 % of the data's spread, or within 1.5
    // times the mean absolute measurement noise when that is larger (noisy data cannot fit
    // better; without this, every run on noisy data would retry).
    let good_fit = (0.01 * spread).max(1.5 * noise_mae(&series.y));
    for r in 0..config.runs {
        let seed = config.seed.wrapping_add(r as u64);
        let started = Instant::now();
        let mut best: Option<Attempt> = None;
        let (mut evaluations, mut refine_evaluations, mut restarts) = (0, 0, 0);
        let mut attempt_config = config.clone();
        for k in 0..config.max_attempts.max(1) {
            // Attempt 0 uses the run's seed; retries use other streams of it.
            let attempt_seed = seed ^ ((k as u64) << 48);
            let a = attempt(&fitness, &attempt_config, attempt_seed, spread, |g, c| {
                progress(r, g, c)
            })?;
            evaluations += a.evaluations;
            refine_evaluations += a.refine_evaluations;
            restarts += a.restarts + usize::from(k > 0);
            let good = a.train_cost <= good_fit;
            if best.as_ref().is_none_or(|b| a.train_cost < b.train_cost) {
                best = Some(a);
            }
            // A retry gets the generations the remaining budget pays for (keeping room for its
            // polish), and is not worth starting below a quarter of the configured ones.
            let left = budget.saturating_sub(evaluations + config.refine_evaluations);
            let generations = (left / (config.population + 1)).min(config.generations);
            if good || !config.restart || generations < config.generations / 4 {
                break;
            }
            attempt_config.generations = generations;
        }
        // max_attempts is at least 1, so at least one attempt was made.
        let Attempt {
            coefficients,
            init,
            train_cost,
            history,
            ..
        } = best.expect("at least one attempt");
        let test_nmae = predict(
            model,
            series,
            &coefficients,
            init,
            config.test_rtol,
            config.output,
        )
        .and_then(|p| nmae(test.iter().map(|&i| (p[i], series.y[i]))));
        runs.push(RunResult {
            seed,
            coefficients,
            initial: init,
            train_mae: train_cost,
            test_nmae,
            evaluations,
            refine_evaluations,
            restarts,
            seconds: started.elapsed().as_secs_f64(),
            history,
        });
    }
    let best = (0..runs.len())
        .min_by(|&a, &b| runs[a].train_mae.total_cmp(&runs[b].train_mae))
        .unwrap_or(0);
    let summary = summarize(runs.iter().map(|r| r.test_nmae.unwrap_or(f64::INFINITY)));
    Ok(Identification {
        runs,
        best,
        summary,
        train,
        test,
    })
}

fn validate(c: &Config) -> Result<(), IdentifyError> {
    let bad = |s: &str| Err(IdentifyError::Option(s.to_string()));
    if !(c.train_fraction > 0.0 && c.train_fraction < 1.0) {
        return bad("--train-fraction must be strictly between 0 and 1");
    }
    if c.population < 4 {
        return bad("--population must be at least 4");
    }
    if c.runs == 0 {
        return bad("--runs must be at least 1");
    }
    for (name, v) in [
        ("--rtol", c.rtol),
        ("--test-rtol", c.test_rtol),
        ("refine rtol", c.refine_rtol),
    ] {
        if !(v > 0.0 && v < 1.0) {
            return Err(IdentifyError::Option(format!(
                "{name} must be in (0, 1), got {v}"
            )));
        }
    }
    if c.substeps == 0 || c.substeps > 1000 {
        return bad("--substeps must be between 1 and 1000");
    }
    if let Initial::Known { y0, v0 } = c.initial {
        if !y0.is_finite() || !v0.is_finite() {
            return bad("--y0 and --v0 must be finite numbers");
        }
    }
    Ok(())
}

/// Levenberg-Marquardt (MINPACK's algorithm, from the `levenberg-marquardt` crate) on the
/// simulation residuals of the training samples, from the DE winner `x0`, with a
/// forward-difference Jacobian. Returns the polished point (`None` when the residuals cannot be
/// computed at `x0`) and the integrations spent (at most about `max_evaluations`).
///
/// Why least squares here: near the optimum the residuals are smooth in the coefficients, so a
/// Gauss-Newton method converges in a handful of iterations (a few dozen integrations), where a
/// simplex on the absolute error needs hundreds.
fn polish(fine: &Fitness<'_>, x0: &[f64], max_evaluations: usize) -> (Option<Vec<f64>>, usize) {
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

/// Mean absolute measurement noise of a finely sampled smooth signal, estimated from fourth
/// differences: for white noise of deviation `s`, `std(d4 y) = s sqrt(70)`, and a smooth signal
/// sampled at `h` contributes only about `(w h)^4` of its amplitude. Mean absolute value of
/// Gaussian noise: `s sqrt(2/pi)`.
fn noise_mae(y: &[f64]) -> f64 {
    if y.len() < 5 {
        return 0.0;
    }
    let d4: Vec<f64> = y
        .windows(5)
        .map(|w| w[4] - 4.0 * w[3] + 6.0 * w[2] - 4.0 * w[1] + w[0])
        .collect();
    std_dev(&d4) / 70f64.sqrt() * (2.0 / std::f64::consts::PI).sqrt()
}

/// One search and polish.
struct Attempt {
    coefficients: Vec<f64>,
    init: InitialValues,
    train_cost: f64,
    evaluations: usize,
    refine_evaluations: usize,
    restarts: usize,
    history: Vec<f64>,
}

/// The DE search (with continuation) and the polish of the winner, from `seed`.
fn attempt(
    fitness: &Fitness<'_>,
    config: &Config,
    seed: u64,
    spread: f64,
    progress: impl FnMut(usize, f64),
) -> Result<Attempt, IdentifyError> {
    let found = search(fitness, config, seed, spread, progress)?;
    let mut evaluations = found.evaluations;
    let mut refine_evaluations = 0;
    let fine = fitness.with_tolerance(Method::Dopri5, config.refine_rtol.min(config.rtol));
    let mut train_cost = fine.cost(&found.best, f64::INFINITY, &mut fine.workspace());
    let (mut coefficients, mut init) = fine.unpack(&found.best);
    if config.refine {
        let (target, x0) = match config.polish_initial {
            Some((_, v_scale)) => fine.with_fitted_initial(&found.best, v_scale),
            None => (fine.clone(), found.best.clone()),
        };
        let (polished, spent) = polish(&target, &x0, config.refine_evaluations);
        refine_evaluations = spent;
        evaluations += spent;
        if let Some(p) = polished {
            // Least squares and the DE's mean absolute error agree on noise-free data; on noisy
            // data their optima differ slightly. Accept the polish unless it fits clearly worse
            // in the DE's own measure (a sign it left the DE's basin).
            let cost = target.cost(&p, f64::INFINITY, &mut target.workspace());
            evaluations += 1;
            if cost <= 1.01 * train_cost {
                (coefficients, init) = target.unpack(&p);
                train_cost = cost;
            }
        }
    }
    Ok(Attempt {
        coefficients,
        init,
        train_cost,
        evaluations,
        refine_evaluations,
        restarts: found.restarts,
        history: found.history,
    })
}

/// Generations without progress, per unknown, before a stage restarts (at least four unknowns'
/// worth).
pub const STALL_GENERATIONS_PER_UNKNOWN: usize = 5;

/// The DE search of one run: with continuation, three stages on the first third, the first two
/// thirds and all of the samples (30 %, 30 % and 40 % of the generations), each stage starting
/// from the previous stage's final population; without, one stage on everything.
///
/// Why: the simulation error of an oscillator is multimodal in its coefficients because a wrong
/// frequency or growth shifts the phase, and the longer the record, the more local optima (the
/// chapter's lost nonlinear-damping runs). A short horizon has few of them and is cheap; each
/// longer horizon then starts from a population already in the right basin.
fn search(
    fitness: &Fitness<'_>,
    config: &Config,
    seed: u64,
    spread: f64,
    mut progress: impl FnMut(usize, f64),
) -> Result<de::DeResult, de::DeError> {
    let n = fitness.t.len();
    let g = config.generations;
    let stages: Vec<(usize, usize)> = if config.continuation && n >= 30 && g >= 10 {
        let (g1, g2) = (g * 3 / 10, g * 3 / 10);
        vec![(n / 3, g1), (2 * n / 3, g2), (n, g - g1 - g2)]
    } else {
        vec![(n, g)]
    };
    let mut population = config.initial_population.clone();
    let (mut evaluations, mut restarts, mut offset) = (0, 0, 0);
    let mut history: Vec<f64> = Vec::with_capacity(g + 1);
    let mut last = None;
    for (k, &(horizon, generations)) in stages.iter().enumerate() {
        let stage = fitness.with_horizon(horizon);
        // Different stages draw from different streams of the run's seed.
        let mut settings = de::Settings::new(
            config.population,
            generations,
            seed.wrapping_add((k as u64) << 32),
        );
        settings.parallel = config.parallel;
        // A stalled stage whose training MAE is below 1 % of the data's spread has converged (the
        // benchmark's success criterion is a test NMAE below 0.01); any other stalled stage
        // restarts.
        // The stall window grows with the number of unknowns: a larger search needs more
        // generations per try before a restart is worth its fresh start.
        settings.restart = config.restart.then(|| de::Restart {
            converged_below: 0.01 * spread,
            stall_generations: STALL_GENERATIONS_PER_UNKNOWN * stage.dimension().max(4),
            ..de::Restart::default()
        });
        let mut result = de::minimize(&stage, &settings, &population, |gen, c| {
            progress(offset + gen, c)
        })?;
        offset += result.generations;
        evaluations += result.evaluations;
        restarts += result.restarts;
        if config.refine && k + 1 < stages.len() {
            // Polish the stage's winner on its horizon and hand it to the next stage first: least
            // squares converges in a few iterations inside the right basin, so each longer
            // horizon starts from a solution that is already phase-coherent over the shorter
            // one (over many periods a small frequency error is a large phase error).
            let fine = stage.with_tolerance(Method::Dopri5, config.refine_rtol.min(config.rtol));
            let (polished, spent) = polish(&fine, &result.best, config.refine_evaluations);
            evaluations += spent;
            if let Some(p) = polished {
                let cost = stage.cost(&p, f64::INFINITY, &mut stage.workspace());
                evaluations += 1;
                if cost <= result.best_cost {
                    result.population.insert(0, p.clone());
                    result.population.truncate(config.population);
                    result.best = p;
                    result.best_cost = cost;
                }
            }
        }
        // The history of a stage starts with its initial population (index 0); earlier stages'
        // costs are on shorter horizons, so the curve is per stage, concatenated.
        history.extend_from_slice(if k == 0 {
            &result.history[..]
        } else {
            &result.history[1..]
        });
        population = result.population.clone();
        last = Some(result);
    }
    // `stages` is never empty, so `last` is set.
    let mut result = last.expect("at least one stage");
    result.evaluations = evaluations;
    result.restarts = restarts;
    result.generations = offset;
    result.history = history;
    Ok(result)
}

/// A seeded random split: `round(n * fraction)` training indices, the rest for testing, both
/// sorted.
pub fn split(
    n: usize,
    fraction: f64,
    seed: u64,
) -> Result<(Vec<usize>, Vec<usize>), IdentifyError> {
    const MIN_TRAIN: usize = 4;
    const MIN_TEST: usize = 2;
    let fits = |n: usize| {
        let n_train = ((n as f64) * fraction).round() as usize;
        n_train >= MIN_TRAIN && n.saturating_sub(n_train) >= MIN_TEST
    };
    if !fits(n) {
        // The smallest sample count that works (the training count is rounded); searched, since
        // rounding makes a closed form fiddly, and bounded for absurd fractions.
        const SEARCH_LIMIT: usize = 10_000_000;
        let needed = (n + 1..=SEARCH_LIMIT)
            .find(|&m| fits(m))
            .unwrap_or(SEARCH_LIMIT);
        return Err(IdentifyError::TooFewSamples {
            samples: n,
            needed,
            train: MIN_TRAIN,
            test: MIN_TEST,
        });
    }
    let n_train = ((n as f64) * fraction).round() as usize;
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    let mut train = idx[..n_train].to_vec();
    let mut test = idx[n_train..].to_vec();
    train.sort_unstable();
    test.sort_unstable();
    Ok((train, test))
}

/// `y0` = first sample; `v0` = slope at `t0` of the least-squares quadratic through the first
/// samples (up to 7), which tolerates mild noise better than a two-point difference.
pub fn initial_from_data(s: &TimeSeries) -> (f64, f64) {
    let m = s.len().min(7);
    if m < 2 {
        return (s.y.first().copied().unwrap_or(0.0), 0.0);
    }
    if m == 2 {
        return (s.y[0], (s.y[1] - s.y[0]) / (s.t[1] - s.t[0]));
    }
    // Fit y = a + b*dt + c*dt^2 with dt = t - t0; v0 = b.
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for i in 0..m {
        let dt = s.t[i] - s.t[0];
        let row = nalgebra::Vector3::new(1.0, dt, dt * dt);
        a += row * row.transpose();
        rhs += row * s.y[i];
    }
    match a.lu().solve(&rhs) {
        Some(sol) => (s.y[0], sol[1]),
        None => (s.y[0], (s.y[1] - s.y[0]) / (s.t[1] - s.t[0])),
    }
}

/// NMAE of `(prediction, target)` pairs: mean absolute error over the (population) standard
/// deviation of the targets. `None` when empty or the targets are constant.
pub fn nmae(pairs: impl Iterator<Item = (f64, f64)> + Clone) -> Option<f64> {
    let n = pairs.clone().count();
    if n == 0 {
        return None;
    }
    let mean = pairs.clone().map(|(_, t)| t).sum::<f64>() / n as f64;
    let var = pairs.clone().map(|(_, t)| (t - mean).powi(2)).sum::<f64>() / n as f64;
    let mae = pairs.map(|(p, t)| (p - t).abs()).sum::<f64>() / n as f64;
    (var > 0.0).then(|| mae / var.sqrt())
}

/// The model's state `[y, yd]` at every sample time (Dormand-Prince at `rtol`), `None` on
/// failure.
pub fn trajectory(
    model: &Model,
    times: &[f64],
    coefficients: &[f64],
    init: InitialValues,
    rtol: f64,
) -> Option<Vec<[f64; 2]>> {
    let scale = init.y0.abs().max(init.v0.abs()).max(f64::MIN_POSITIVE);
    let opts = Options {
        rtol,
        atol: rtol * 1e-6 * scale,
        bound: 1e9 * scale,
        max_steps: 1_000_000,
        max_rhs_evals: 10_000_000,
        ..Options::default()
    };
    let mut out = vec![[0.0; 2]; times.len()];
    let sys = Bound {
        model,
        coeffs: coefficients,
    };
    let o = ode::integrate(
        Method::Dopri5,
        &sys,
        [init.y0, init.v0],
        times,
        &opts,
        |i, s| {
            out[i] = *s;
            ControlFlow::Continue(())
        },
    );
    o.is_complete().then_some(out)
}

/// The model's prediction of the data at every sample time: displacement, or support force
/// `R(t, y, yd)` (Dormand-Prince at `rtol`). `None` when the integration fails.
pub fn predict(
    model: &Model,
    series: &TimeSeries,
    coefficients: &[f64],
    init: InitialValues,
    rtol: f64,
    output: Output,
) -> Option<Vec<f64>> {
    let states = trajectory(model, &series.t, coefficients, init, rtol)?;
    Some(
        states
            .iter()
            .zip(&series.t)
            .map(|(s, &t)| match output {
                Output::Displacement => s[0],
                Output::Force => model.residual(t, s[0], s[1], coefficients),
            })
            .collect(),
    )
}

fn std_dev(y: &[f64]) -> f64 {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt()
}

fn magnitude(y: &[f64]) -> f64 {
    let m = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if m > 0.0 {
        m
    } else {
        1.0
    }
}

/// Mean, sample standard deviation, minimum and median of `values`.
pub fn summarize(values: impl Iterator<Item = f64>) -> Summary {
    let mut v: Vec<f64> = values.collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let std = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    v.sort_by(f64::total_cmp);
    let median = if v.len() % 2 == 1 {
        v[v.len() / 2]
    } else {
        0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
    };
    Summary {
        mean,
        std,
        min: v.first().copied().unwrap_or(f64::NAN),
        median,
    }
}

/// What the fitness compares with the data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Output {
    /// The displacement `y` (section 8.4).
    #[default]
    Displacement,
    /// The support force `R(t, y, yd)`: everything in `M*ydd + R = 0` but the inertia term,
    /// i.e. the damping force plus the stiffness force (section 8.5, equation 8.7).
    Force,
}

/// The training objective of section 8.3 with the corrected penalty (see the module docs).
///
/// The DE works on `x`; the model's coefficients (and fitted initial conditions) are `x[j] *
/// scale[j]`, so that a problem in physical units (kg, N s/m, N/m) is searched on numbers of
/// order one.
#[derive(Debug, Clone)]
pub struct Fitness<'a> {
    model: &'a Model,
    t: &'a [f64],
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
    /// The objective on the samples flagged in `is_train`. `initial` must be `Known` or `Fit`.
    /// `y_scale` is the displacement's magnitude (the data's in displacement mode; force over
    /// stiffness in force mode); `scales` the physical value per unit of each DE coordinate
    /// (empty: all 1).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: &'a Model,
        series: &'a TimeSeries,
        is_train: Vec<bool>,
        initial: Initial,
        output: Output,
        scales: Vec<f64>,
        y_scale: f64,
        method: Method,
        rtol: f64,
        substeps: usize,
    ) -> Fitness<'a> {
        let n = series.len();
        let n_train = is_train.iter().filter(|b| **b).count().max(1);
        let d = model.n_coeffs()
            + if matches!(initial, Initial::Fit) {
                2
            } else {
                0
            };
        let scales = if scales.len() == d {
            scales
        } else {
            vec![1.0; d]
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
