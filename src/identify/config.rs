//! The settings of an identification and their validation.

use super::IdentifyError;
use crate::ode::Method;
use serde::Serialize;

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

pub(super) fn validate(c: &Config) -> Result<(), IdentifyError> {
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
