//! Early-warning analysis of one window: identify the model, then say what its damping means.
//!
//! This is the interface the daemon consumes. [`Analyzer::new`] compiles the model and checks the
//! settings once per gate; [`Analyzer::analyze`] runs on a worker thread for each window.

use serde::{Deserialize, Serialize};

/// What the samples measure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Signal {
    /// Support force in N; the installed stiffness converts it to displacement (section 8.5).
    #[default]
    Force,
    /// Displacement in m.
    Displacement,
}

/// Settings of the analysis of one gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnalysisSettings {
    /// What the samples are.
    pub signal: Signal,
    /// Installed stiffness in N/m (force mode: converts force to displacement; known constant `k`).
    pub stiffness: Option<f64>,
    /// The equation of motion, in the model language (see [`crate::model`]).
    pub model: String,
    /// Known named constants of the equation.
    pub params: Vec<(String, f64)>,
    /// DE population size.
    pub population: usize,
    /// DE generations (cold start).
    pub generations: usize,
    /// Amplitude (same unit as the signal) whose time of reach is predicted (`time_to_limit`).
    pub amplitude_limit: Option<f64>,
    /// A window whose fit NMAE exceeds this is not trusted (never raises an alarm).
    pub max_fit_nmae: f64,
}

/// One uniformly sampled window.
#[derive(Debug, Clone, Copy)]
pub struct WindowInput<'a> {
    /// Time of the first sample, Unix seconds.
    pub t0: f64,
    /// Sample rate in Hz.
    pub rate_hz: f64,
    /// The samples, oldest first.
    pub values: &'a [f64],
}

/// What the analysis concludes about the gate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Positive damping at rest; the motion is a damped (possibly noise-driven) response.
    Damped,
    /// Negative damping at rest: vibration starts by itself.
    SelfExcited,
    /// The model does not fit or disagrees with the model-free estimate: no conclusion.
    Unknown,
}

/// Damping figures of an identified model (definitions in `docs/damping.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DampingReport {
    /// Damping ratio at rest from the linearisation, `C0 / (2 sqrt(K0 M0))`.
    pub zeta0: Option<f64>,
    /// Interval (low, high) for `zeta0` (spread of independent runs or bootstrap).
    pub zeta0_interval: Option<(f64, f64)>,
    /// Equivalent damping ratio at the amplitude seen in the window.
    pub zeta_eq: Option<f64>,
    /// Net energy fed into the structure per cycle (J in force mode).
    pub energy_per_cycle: Option<f64>,
    /// Amplitude where `zeta_eq` crosses zero; `None` when the model grows without bound.
    pub limit_cycle_amplitude: Option<f64>,
    /// Seconds until the amplitude reaches the configured limit at the current growth.
    pub time_to_limit: Option<f64>,
    /// Dominant frequency of the window, Hz.
    pub frequency_hz: Option<f64>,
    /// Model-free envelope growth rate sigma, 1/s (negative: decaying).
    pub growth_rate: Option<f64>,
    /// Standard error of `growth_rate`.
    pub growth_rate_stderr: Option<f64>,
    /// Whether the model's frequency and growth agree with the model-free estimates.
    pub agrees: bool,
    /// NMAE of the model on the window.
    pub fit_nmae: f64,
    /// Whether the model can be trusted (fits, agrees); an untrusted model never raises an alarm.
    pub trusted: bool,
    /// The conclusion.
    pub verdict: Verdict,
}

/// The result of analysing one window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowAnalysis {
    /// The identified equation with the numbers put in.
    pub equation: String,
    /// Identified coefficients by name (`c1`, ...), in physical units.
    pub coefficients: Vec<(String, f64)>,
    /// Damping figures.
    pub damping: DampingReport,
    /// Objective evaluations spent.
    pub evaluations: usize,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Internal state to warm-start the next window of the same gate.
    pub warm_start: Vec<f64>,
}

/// Why a window could not be analysed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalysisError {
    /// The settings are inconsistent (bad model, missing stiffness in force mode, ...).
    #[error("invalid analysis settings: {0}")]
    Settings(String),
    /// The window cannot be analysed (too short, constant, non-finite).
    #[error("window not analysable: {0}")]
    Window(String),
}

/// A gate's analysis, prepared once (model compiled, settings checked), used for every window.
/// `Send + Sync`: the daemon shares one per gate across its worker threads.
#[derive(Debug, Clone)]
pub struct Analyzer {
    settings: AnalysisSettings,
}

impl Analyzer {
    /// Checks the settings and compiles the model.
    pub fn new(settings: AnalysisSettings) -> Result<Analyzer, AnalysisError> {
        Ok(Analyzer { settings })
    }

    /// The settings this analyzer was made with.
    pub fn settings(&self) -> &AnalysisSettings {
        &self.settings
    }

    /// Identifies the model on `input` and reports its damping. `warm` is the previous window's
    /// [`WindowAnalysis::warm_start`] of the same gate; `seed` makes the result reproducible.
    pub fn analyze(
        &self,
        _input: WindowInput<'_>,
        _warm: Option<&[f64]>,
        _seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        todo!("analysis not yet implemented")
    }
}
