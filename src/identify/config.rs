//! The settings of an identification, apart from the problem itself: the search ([`Search`]:
//! how one DE run looks for the coefficients) and the protocol ([`Protocol`]: how many runs,
//! which seeds, retries, the split and the test). [`Config`] bundles them with the problem's
//! settings for callers that keep them before the data exist (the analysis, the CLI).
//!
//! Why three parts (as argmin keeps the problem, the solver and the executor's settings
//! apart): the same problem is searched with other settings (the analysis's force mode, the
//! benchmarks' ablations), and each part is validated on its own with errors that name its
//! fields; the CLI translates field names into its flags.

use super::fitness::Fitness;
use super::problem::{Initial, Output, Problem};
use super::IdentifyError;
use crate::data::TimeSeries;
use crate::model::Model;
use crate::ode::Method;
use serde::Serialize;

/// Largest DE population [`Search::validate`] accepts. Why: the DE keeps about 150 bytes per
/// member (its coordinates twice, the trial, the cost, its own `F` and `CR`), so memory is not
/// the limit here (1.5 MB), but time is: every member costs one integration over the training
/// samples per generation, and 10 000 members over the default 120 generations are 1.2 million
/// integrations, a minute on a 2000-sample record on one core. The chapter uses 20 to 200; a
/// population of 10^8 (a typo) allocated gigabytes and ran toward an out-of-memory kill.
pub const MAX_POPULATION: usize = 10_000;

/// Most DE generations [`Search::validate`] accepts. Why: the convergence history is allocated
/// up front (8 bytes a generation: `--generations 1e11` aborted on an 800 GB allocation), and a
/// generation costs a population's integrations, so 10^5 generations of the default 50 members
/// is already hours on a long record. The chapter uses 120 to 250.
pub const MAX_GENERATIONS: usize = 100_000;

/// Most independent runs [`Protocol::validate`] accepts. Why: each run is a whole search
/// (seconds to minutes) and its result is kept for the report (`--runs 1e11` aborted on a 13 TB
/// allocation); the chapter's protocol uses 25.
pub const MAX_RUNS: usize = 1_000;

/// How one DE run searches: population, generations, the fitness solver, the polish, the
/// continuation. [`Search::default`] is the chapter's settings with the improvements on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Search {
    /// DE population size (4 to [`MAX_POPULATION`]).
    pub population: usize,
    /// DE generations (at most [`MAX_GENERATIONS`]).
    pub generations: usize,
    /// Solver used in the fitness.
    pub solver: Method,
    /// Relative tolerance of the fitness solver (chapter: 1e-3).
    pub rtol: f64,
    /// RK4 steps per sample interval (1 to 1000).
    pub substeps: usize,
    /// Polish the DE winner with Levenberg-Marquardt (not in the chapter).
    pub refine: bool,
    /// Relative tolerance of the solver during the polish (adaptive solvers).
    pub refine_rtol: f64,
    /// Solver of the polish's integrations: Dormand-Prince at `refine_rtol` (the library's
    /// default), or RK4 with `refine_substeps` steps per sample interval (the daemon's, when
    /// the sampling resolves the signal's frequency: `analysis::series::polish_substeps`).
    pub refine_solver: Method,
    /// RK4 steps per sample interval of the polish when `refine_solver` is RK4 (1 to 1000).
    pub refine_substeps: usize,
    /// Integrations the polish may spend (about).
    pub refine_evaluations: usize,
    /// Grow the fitted horizon in three stages (not in the chapter; see the `search` module).
    pub continuation: bool,
    /// Evaluate each generation's trials in parallel (results are identical either way).
    pub parallel: bool,
    /// Trials integrated in lockstep by the fitness (1, 4 or 8; 1 = one by one). Results are
    /// identical for every width (docs/design.md, "A generation in lanes"); the stiff solver
    /// always works one by one.
    pub lanes: usize,
    /// Individuals placed first in the initial population of every run (warm start, bias), in
    /// the DE's coordinates (coefficients, then `y0`, `v0` when fitted).
    pub initial_population: Vec<Vec<f64>>,
}

impl Default for Search {
    fn default() -> Self {
        Search {
            population: 50,
            generations: 120,
            solver: Method::Dopri5,
            rtol: 1e-3,
            substeps: 2,
            refine: true,
            refine_rtol: 1e-8,
            refine_solver: Method::Dopri5,
            refine_substeps: 1,
            refine_evaluations: 300,
            continuation: true,
            parallel: false,
            lanes: crate::identify::LANES,
            initial_population: Vec::new(),
        }
    }
}

/// An error naming a field: `field` and what is wrong with its value.
fn invalid(field: &'static str, reason: impl Into<String>) -> IdentifyError {
    IdentifyError::Invalid {
        field,
        reason: reason.into(),
    }
}

/// Smallest relative tolerance of an integration. Why: a step is accepted when its error
/// estimate is below `rtol` times the state, and that estimate cannot fall below the rounding
/// of double precision (2.2e-16 a step, more over a step's stages), so below about 1e-14 no
/// step is ever accepted: `--rtol 1e-300` failed every trial and the error blamed the data.
pub const MIN_TOLERANCE: f64 = 1e-14;

/// A relative tolerance in [`MIN_TOLERANCE`], 1).
fn tolerance(field: &'static str, v: f64) -> Result<(), IdentifyError> {
    if (MIN_TOLERANCE..1.0).contains(&v) {
        Ok(())
    } else if v > 0.0 && v < MIN_TOLERANCE {
        Err(invalid(
            field,
            format!("must be at least {MIN_TOLERANCE:e} (below it no step of double precision is accepted), got {v:e}"),
        ))
    } else {
        Err(invalid(field, format!("must be in [1e-14, 1), got {v}")))
    }
}

impl Search {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), IdentifyError> {
        if self.population < 4 {
            return Err(invalid("population", "must be at least 4"));
        }
        if self.population > MAX_POPULATION {
            return Err(invalid(
                "population",
                format!("must be at most {MAX_POPULATION}, got {}", self.population),
            ));
        }
        if self.generations == 0 {
            return Err(invalid("generations", "must be at least 1"));
        }
        if self.generations > MAX_GENERATIONS {
            return Err(invalid(
                "generations",
                format!(
                    "must be at most {MAX_GENERATIONS}, got {}",
                    self.generations
                ),
            ));
        }
        tolerance("rtol", self.rtol)?;
        tolerance("refine_rtol", self.refine_rtol)?;
        if self.substeps == 0 || self.substeps > 1000 {
            return Err(invalid("substeps", "must be between 1 and 1000"));
        }
        if self.refine_substeps == 0 || self.refine_substeps > 1000 {
            return Err(invalid("refine_substeps", "must be between 1 and 1000"));
        }
        if !matches!(self.lanes, 1 | 4 | 8) {
            return Err(invalid(
                "lanes",
                format!("must be 1, 4 or 8, got {}", self.lanes),
            ));
        }
        Ok(())
    }

    /// With `population` individuals (at least 4).
    pub fn with_population(mut self, population: usize) -> Result<Self, IdentifyError> {
        self.population = population;
        self.validate().map(|()| self)
    }

    /// With `generations` generations.
    pub fn with_generations(mut self, generations: usize) -> Self {
        self.generations = generations;
        self
    }

    /// With another fitness solver and relative tolerance (in (0, 1)).
    pub fn with_solver(mut self, solver: Method, rtol: f64) -> Result<Self, IdentifyError> {
        self.solver = solver;
        self.rtol = rtol;
        self.validate().map(|()| self)
    }

    /// The fitness of the polish: `fitness` with the polish's solver, tolerance (never looser
    /// than the search's) and substeps.
    pub(super) fn polish_fitness<'a>(&self, fitness: &Fitness<'a>) -> Fitness<'a> {
        fitness.with_solver(
            self.refine_solver,
            self.refine_rtol.min(self.rtol),
            self.refine_substeps,
        )
    }

    /// With `substeps` RK4 steps per sample interval (1 to 1000).
    pub fn with_substeps(mut self, substeps: usize) -> Result<Self, IdentifyError> {
        self.substeps = substeps;
        self.validate().map(|()| self)
    }
}

/// How the runs are made and judged: their number and seeds, the retries of a poor run, the
/// DE restarts, the train/test split and the test tolerance. [`Protocol::default`] is one run
/// with seed 1 on a half split.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Protocol {
    /// Independent runs (seeds `seed`, `seed + 1`, ...), 1 to [`MAX_RUNS`].
    pub runs: usize,
    /// Seed of the first run.
    pub seed: u64,
    /// Fraction of the samples used for training (the rest is the test set), in (0, 1).
    pub train_fraction: f64,
    /// Seed of the random train/test split.
    pub split_seed: u64,
    /// Relative tolerance of the test solver (chapter: 1e-5); the test always uses Dormand-Prince.
    pub test_rtol: f64,
    /// Restart a stagnating DE population, and retry a run whose fit stays poor (not in the
    /// chapter).
    pub restart: bool,
    /// Attempts of one run: a run whose fit stays poor tries again from another seed, with the
    /// generations left in twice the chapter's evaluation budget (1: never).
    pub max_attempts: usize,
}

impl Default for Protocol {
    fn default() -> Self {
        Protocol {
            runs: 1,
            seed: 1,
            train_fraction: 0.5,
            split_seed: 1,
            test_rtol: 1e-5,
            restart: true,
            max_attempts: 3,
        }
    }
}

impl Protocol {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), IdentifyError> {
        if !(self.train_fraction > 0.0 && self.train_fraction < 1.0) {
            return Err(invalid(
                "train_fraction",
                "must be strictly between 0 and 1",
            ));
        }
        if self.runs == 0 {
            return Err(invalid("runs", "must be at least 1"));
        }
        if self.runs > MAX_RUNS {
            return Err(invalid(
                "runs",
                format!("must be at most {MAX_RUNS}, got {}", self.runs),
            ));
        }
        tolerance("test_rtol", self.test_rtol)
    }

    /// With `runs` runs from seed `seed` (at least one run).
    pub fn with_runs(mut self, runs: usize, seed: u64) -> Result<Self, IdentifyError> {
        self.runs = runs;
        self.seed = seed;
        self.validate().map(|()| self)
    }

    /// With a split of `train_fraction` (in (0, 1)) of the samples for training, drawn with
    /// `split_seed`.
    pub fn with_split(
        mut self,
        train_fraction: f64,
        split_seed: u64,
    ) -> Result<Self, IdentifyError> {
        self.train_fraction = train_fraction;
        self.split_seed = split_seed;
        self.validate().map(|()| self)
    }
}

/// Everything of an identification but the model and the data: the problem's settings (what the
/// data are, the initial conditions, the scales), the [`Search`] and the [`Protocol`].
/// [`Config::default`] is the chapter's protocol with the improvements switched on.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Config {
    /// Initial conditions.
    pub initial: Initial,
    /// What the data are: displacement, or the support force (section 8.5).
    pub output: Output,
    /// Physical value per unit of each DE coordinate (empty: 1). See [`super::Fitness`].
    pub scales: Vec<f64>,
    /// Magnitude of the displacement, for tolerances and bounds (`None`: the data's).
    pub y_scale: Option<f64>,
    /// Let the polish adjust known initial conditions too, with these scales for `(y0, v0)`
    /// (force mode: the pre-run's initial conditions are estimates).
    pub polish_initial: Option<(f64, f64)>,
    /// How one run searches.
    pub search: Search,
    /// How the runs are made and judged.
    pub protocol: Protocol,
}

impl Config {
    /// The problem of identifying `model` from `series` with these settings.
    pub fn problem<'a>(
        &self,
        model: &'a Model,
        series: &'a TimeSeries,
    ) -> Result<Problem<'a>, IdentifyError> {
        let mut p = Problem::new(model, series)?
            .with_initial(self.initial)?
            .with_output(self.output)
            .with_scales(self.scales.clone())?;
        if let Some(y) = self.y_scale {
            p = p.with_y_scale(y)?;
        }
        if let Some(s) = self.polish_initial {
            p = p.with_polish_initial(s)?;
        }
        Ok(p)
    }

    /// Checks the search, the protocol and the initial conditions (what can be checked without
    /// the model and the data); the error names the first bad field.
    pub fn validate(&self) -> Result<(), IdentifyError> {
        self.protocol.validate()?;
        self.search.validate()?;
        super::problem::check_initial(self.initial)
    }
}
