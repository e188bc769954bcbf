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
//!
//! # Layout
//! - `problem`: what is identified from what ([`Problem`]: model, data, output, initial
//!   conditions, scales);
//! - `config`: how ([`Search`]: one DE run; [`Protocol`]: runs, seeds, retries, split, test;
//!   [`Config`]: both with the problem's settings, for callers without the data yet);
//! - `fitness`: the training objective ([`Fitness`]);
//! - `covariance`: the coefficients' covariance at the optimum and the delta method
//!   ([`Covariance`]);
//! - `forcing`: the same covariance with the turbulent forcing propagated through the fitted
//!   model (an adjoint sweep), for `model_interval = "forcing"`;
//! - `search`: one attempt of a run, the DE with continuation and restarts, then the polish;
//! - `polish`: the Levenberg-Marquardt polish of a DE winner;
//! - `refine`: the polish alone from known coefficients (the daemon's tracked windows);
//! - `split`: the train/test split and the initial conditions from the data;
//! - `predict`: the model's trajectory and prediction at the sample times;
//! - `stats`: NMAE, summaries and the noise estimate.

use crate::data::TimeSeries;
use crate::de;
use crate::model::{Model, ScaleGroup};
use crate::ode::Method;
use serde::Serialize;
use std::time::Instant;

mod config;
mod covariance;
mod fitness;
mod forcing;
mod polish;
mod predict;
mod problem;
mod refine;
mod search;
mod split;
mod stats;

pub use config::{
    Config, Protocol, Search, MAX_GENERATIONS, MAX_POPULATION, MAX_RUNS, MIN_TOLERANCE,
};
pub use covariance::{
    bandwidth, covariance, difference_steps, fixed_b_critical_value_95, Covariance, Optimum,
    COVARIANCE_RTOL,
};
pub use fitness::{Fitness, FitnessWorkspace, LANES};
pub use forcing::covariance_under_forcing;
pub use predict::{output_of, predict, trajectory};
pub use problem::Problem;
pub use problem::{Initial, Output};
pub use refine::refine;
pub use search::STALL_GENERATIONS_PER_UNKNOWN;
pub use split::{initial_from_data, min_samples, split};
pub use stats::{median, nmae, std_dev, summarize};

use search::{attempt, Attempt};
use stats::noise_mae;

/// Why an identification could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// A setting is out of range: `field` names it as in [`Search`], [`Protocol`] or
    /// [`Problem`] (the CLI translates it into its flag).
    #[error("{field} {reason}")]
    Invalid {
        /// The field, e.g. `train_fraction`.
        field: &'static str,
        /// What is wrong, e.g. `must be strictly between 0 and 1`.
        reason: String,
    },
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
    #[error("the rk4 solver needs uniformly spaced samples; use dopri5 for this series")]
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
    /// Whether the final coefficients integrate over every training sample. When not, no
    /// trial of the run integrated and `train_mae` is the failure penalty of the fitness (a
    /// large finite number that gives the search a direction), not an error of a fit.
    #[serde(skip)]
    pub train_integrated: bool,
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
    /// Groups of coefficients the data determine only up to a common factor (see
    /// [`Model::scale_groups`]; only for displacement data: a measured force fixes the scale).
    /// The runs keep the search's values; reports show [`Identification::normalized`] ones.
    pub scale_groups: Vec<ScaleGroup>,
}

impl Identification {
    /// The chosen run.
    pub fn best_run(&self) -> &RunResult {
        &self.runs[self.best]
    }

    /// `coefficients` normalised by every scale group (see [`normalize`]).
    pub fn normalized(&self, coefficients: &[f64]) -> Vec<f64> {
        normalize(&self.scale_groups, coefficients)
    }
}

/// `coefficients` with each of `groups` divided by its fixed member; a group whose fixed member
/// is 0 or not finite is left as it is.
pub fn normalize(groups: &[ScaleGroup], coefficients: &[f64]) -> Vec<f64> {
    let mut c = coefficients.to_vec();
    for g in groups {
        if let Some(n) = g.normalize(&c) {
            c = n;
        }
    }
    c
}

/// Identifies `model`'s coefficients from `series` with the settings of `config` (see
/// [`run`]). `progress(run, generation, best_cost)` is called after every generation.
pub fn identify(
    model: &Model,
    series: &TimeSeries,
    config: &Config,
    progress: impl FnMut(usize, usize, f64),
) -> Result<Identification, IdentifyError> {
    config.validate()?;
    let problem = config.problem(model, series)?;
    run(&problem, &config.search, &config.protocol, progress)
}

/// Solves `problem`: `protocol.runs` runs of `search`, each with its retries, each judged on
/// the test samples. `progress(run, generation, best_cost)` is called after every generation.
pub fn run(
    problem: &Problem<'_>,
    search: &Search,
    protocol: &Protocol,
    mut progress: impl FnMut(usize, usize, f64),
) -> Result<Identification, IdentifyError> {
    protocol.validate()?;
    search.validate()?;
    let series = problem.series;
    if search.solver == Method::Rk4 && series.uniform_step().is_none() {
        return Err(IdentifyError::NotUniform);
    }
    let Setup {
        scale_groups,
        train,
        test,
        fitness,
    } = setup(problem, protocol, search)?;
    let spread = std_dev(&series.y);
    let mut runs = Vec::with_capacity(protocol.runs);
    // Budget of a run: twice the chapter's NP + G (NP + 1) evaluations. A run whose fit is poor
    // (above 1 % of the data's spread) tries again from a fresh seed while this allows.
    let budget = 2 * (search.population + search.generations * (search.population + 1));
    // A fit is good when its training MAE is within 1 % of the data's spread, or within 1.5
    // times the mean absolute measurement noise when that is larger (noisy data cannot fit
    // better; without this, every run on noisy data would retry).
    let good_fit = (0.01 * spread).max(1.5 * noise_mae(&series.y));
    for r in 0..protocol.runs {
        let seed = protocol.seed.wrapping_add(r as u64);
        let started = Instant::now();
        let mut best: Option<Attempt> = None;
        let (mut evaluations, mut refine_evaluations, mut restarts) = (0, 0, 0);
        let mut attempt_search = search.clone();
        for k in 0..protocol.max_attempts.max(1) {
            // Attempt 0 uses the run's seed; retries use other streams of it.
            let attempt_seed = seed ^ ((k as u64) << 48);
            let a = attempt(
                &fitness,
                &attempt_search,
                protocol.restart,
                problem.polish_initial,
                attempt_seed,
                spread,
                |g, c| progress(r, g, c),
            )?;
            evaluations += a.evaluations;
            refine_evaluations += a.refine_evaluations;
            restarts += a.restarts + usize::from(k > 0);
            let good = a.train_cost <= good_fit;
            if best.as_ref().is_none_or(|b| a.train_cost < b.train_cost) {
                best = Some(a);
            }
            // A retry gets the generations the remaining budget pays for (keeping room for its
            // polish), and is not worth starting below a quarter of the configured ones.
            let left = budget.saturating_sub(evaluations + search.refine_evaluations);
            let generations = (left / (search.population + 1)).min(search.generations);
            if good || !protocol.restart || generations < search.generations / 4 {
                break;
            }
            attempt_search.generations = generations;
        }
        // max_attempts is at least 1, so at least one attempt was made.
        let Attempt {
            coefficients,
            init,
            train_cost,
            history,
            ..
        } = best.expect("at least one attempt");
        let test_nmae = test_nmae(problem, protocol, &coefficients, init, &test);
        runs.push(RunResult {
            seed,
            coefficients,
            initial: init,
            train_mae: train_cost,
            test_nmae,
            train_integrated: fitness.integrated(train_cost),
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
        scale_groups,
    })
}
/// What a search and a refinement share: the scale groups, the train/test split and the
/// training objective on it.
pub(crate) struct Setup<'a> {
    pub(crate) scale_groups: Vec<ScaleGroup>,
    pub(crate) train: Vec<usize>,
    pub(crate) test: Vec<usize>,
    pub(crate) fitness: Fitness<'a>,
}

/// The NMAE on the `test` samples of the prediction from `coefficients` and `init` (`None` when
/// it fails): what a search's run and a refinement are judged by.
pub(crate) fn test_nmae(
    problem: &Problem<'_>,
    protocol: &Protocol,
    coefficients: &[f64],
    init: InitialValues,
    test: &[usize],
) -> Option<f64> {
    let series = problem.series;
    predict(
        problem.model,
        series,
        coefficients,
        init,
        protocol.test_rtol,
        problem.output,
    )
    .and_then(|p| nmae(test.iter().map(|&i| (p[i], series.y[i]))))
}

pub(crate) fn setup<'a>(
    problem: &Problem<'a>,
    protocol: &Protocol,
    search: &Search,
) -> Result<Setup<'a>, IdentifyError> {
    // Only the displacement is blind to a common factor of M and R; a force output is R itself.
    let scale_groups = match problem.output {
        Output::Displacement => problem.model.scale_groups(),
        Output::Force | Output::RestoringForce => Vec::new(),
    };
    let n = problem.series.len();
    let (train, test) = split(n, protocol.train_fraction, protocol.split_seed)?;
    let mut is_train = vec![false; n];
    for &i in &train {
        is_train[i] = true;
    }
    let fitness = Fitness::new(problem, is_train, search);
    Ok(Setup {
        scale_groups,
        train,
        test,
        fitness,
    })
}
