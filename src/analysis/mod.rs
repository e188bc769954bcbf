//! Early-warning analysis of one window: identify the model, then say what its damping means.
//!
//! This is the interface the daemon consumes. [`Analyzer::new`] compiles the model and checks the
//! settings once per gate; [`Analyzer::analyze`] runs on a worker thread for each window.
//!
//! # Layout
//! - `linearisation`: the model at rest (zeta0) and its energy balance at an amplitude
//!   (zeta_eq, limit cycle, time to a limit).
//! - `population`: the DE's initial population biased towards the measured spectrum.
//! - `model_free`: the window without an equation: pre-processing, the spectrum's peak and
//!   growth, a limit cycle's steadiness and envelope relaxation over the gate's history.
//! - `series`: the analysis of one series, phase by phase: the model-free part, force-mode
//!   scaling, initial population, identification, damping figures.
//! - `verdict`: agreement with the spectrum and the verdict table of `docs/damping.md`.
//! - `report`: the damping report and its parts.
//! - `ambient_level`: the gate's ambient level and how far a window stands above it.
//! - `growing`: a noise-driven window whose variance grows, read over common reference
//!   instants instead of the lagged ones.
//! - `prediction_error`: a window far above the ambient level read by the likelihood of an
//!   extended Kalman filter that carries the forcing as process noise.
//! - `cycle_amplitude`: a limit cycle's zeta0 from its amplitude and the damping law of the
//!   gate's last growth.
//! - `falling_cycle`: a limit-cycle window whose envelope fell, its interval widened to span the
//!   envelope's drift over the window.
//! - `tracking`: when a window may refine the previous window's model instead of searching.
//! - `analyzer`: the daemon's per-gate [`Analyzer`].
//! - `trend`: the robust weighted trend of `zeta0` over recent windows and its predicted
//!   crossing of a threshold (the `GateDampingDeclining` warning's evidence).
//! - `trend_reach`: a declining gate's reported interval reaching down to the trend's forecast.
//! - `selection`: ranking candidate equations of one record (information criteria and the
//!   accuracy/complexity front): the seam for structure discovery.
//! - `early_warning`: the model-free critical-slowing-down indicators (rolling variance, lag-1
//!   autocorrelation, Kendall tau), the baseline the trend is compared against.

mod ambient_level;
mod analyzer;
mod cycle_amplitude;
mod early_warning;
mod falling_cycle;
mod growing;
mod linearisation;
mod model_free;
mod model_interval;
mod pooling;
mod population;
mod prediction_error;
mod report;
mod selection;
mod series;
#[cfg(test)]
mod tests;
pub mod tracking;
mod trend;
mod trend_reach;
mod verdict;

pub use ambient_level::{
    departed, departure_ratio, AmbientLevel, AMBIENT_LEVEL_MIN_WINDOWS, AMBIENT_LEVEL_WINDOWS,
    DEPARTED_FROM_AMBIENT,
};
pub use analyzer::Analyzer;
pub use cycle_amplitude::{
    CycleAmplitude, LAW_AMPLITUDE_TOLERANCE, LAW_INTERVAL_INFLATION, LAW_MAX_AGE_SECONDS,
};
pub use early_warning::{kendall_tau, lag1_autocorrelation, rolling, variance, EwsIndicators};
pub use falling_cycle::{span_the_fall, HeldCycle};
pub use growing::{read_growing_window, GROWING_MIN_RATIO, GROWING_MIN_SHIFT};
pub use linearisation::{
    cycle_zeta0, equivalent_damping, limit_cycle, time_to_amplitude, Linearization,
};
pub use model_free::{
    moving_average_samples, relaxation_detrend_degree, rms_swing, BEND_DEGREE, BEND_LEVEL_CHANGE,
    LIMIT_CYCLE_CYCLES, RELAXATION_CYCLES,
};
pub use model_interval::{intervals, zeta0_interval, FittedModel};
pub use pooling::{
    falling, rising, trend_reading, window_middle_lag, PoolingSettings, ZetaPools,
    MIN_CYCLE_POOL_CYCLES, POOL_MIN_WINDOWS, RISING_SHARE,
};
pub use population::{biased_population, SpectralTarget};
pub use prediction_error::{prediction_error_zeta, read_by_prediction_errors};
pub use report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
pub use selection::{
    correlation_factor, information_criteria, rank, CandidateFit, RankedCandidate, FRONT_TIE,
};
pub use series::{
    analyze_series, analyze_series_with, displacement_scales, polish_substeps, pre_run,
    term_scales, track_series_with, SeriesAnalysis, SeriesOptions, DAMPING_FORCE_FRACTION,
    GROWTH_MIN_REACH,
};
pub use tracking::{gate_hash, Path, Previous, TrackingPolicy};
pub use trend::{
    fit_trend, DampingTrend, TrendError, TrendEstimate, TrendPoint, TrendReading, MAX_TREND_POINTS,
    MIN_TREND_POINTS,
};
pub use trend_reach::reach_down_to_trend;
pub use verdict::{
    ambient_decision, claims_unseen_growth, decide, falls, refuse_few_cycles, Decision,
    VerdictFacts, WindowGrowth, FALLING_SIGMAS, MIN_WINDOW_CYCLES,
};

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

/// `FromStr` for a settings enum by its configuration spelling (serde's, kebab-case), so that
/// a command-line flag that mirrors a configuration key reads the same words; an unknown word
/// is an error naming `$what` and the words `$expected`.
macro_rules! from_config_word {
    ($t:ty, $what:literal, $expected:literal) => {
        impl std::str::FromStr for $t {
            type Err = String;

            fn from_str(s: &str) -> Result<Self, String> {
                use serde::de::value::{Error, StrDeserializer};
                <$t>::deserialize(StrDeserializer::<Error>::new(s)).map_err(|_| {
                    format!(concat!("unknown ", $what, " `{}`: expected ", $expected), s)
                })
            }
        }
    };
}

/// What a force signal holds (`force_terms`; docs/damping.md, "What the support force holds").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ForceTerms {
    /// Every term of the equation but the inertia: the damping force plus the stiffness force
    /// (the chapter's section 8.5, equation 8.7).
    #[default]
    All,
    /// The terms without `yd`: the stiffness force alone (a load cell in series with the
    /// gate's spring, the flow's damping acting on the gate's body).
    Stiffness,
}

impl ForceTerms {
    /// The identification's output for a force signal holding these terms.
    pub fn output(self) -> crate::identify::Output {
        match self {
            ForceTerms::All => crate::identify::Output::Force,
            ForceTerms::Stiffness => crate::identify::Output::RestoringForce,
        }
    }
}

from_config_word!(ForceTerms, "force terms", "all or stiffness");

/// Settings of the analysis of one gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnalysisSettings {
    /// What the samples are.
    pub signal: Signal,
    /// What a force signal holds: every term but the inertia, or the stiffness force alone.
    #[serde(default)]
    pub force_terms: ForceTerms,
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
    /// Relative tolerance of the Dormand-Prince integrations of the full search's
    /// Levenberg-Marquardt polish (with [`PolishSolver::Rk4`], where no frequency is measured) ([`DEFAULT_POLISH_RTOL`]; the tracked refinement has its own,
    /// [`TrackingPolicy::refine_rtol`]).
    pub polish_rtol: f64,
    /// Solver of the polish's and the tracked refinement's integrations.
    pub polish_solver: PolishSolver,
    /// How a model-based zeta0 gets its interval.
    pub model_interval: ModelInterval,
    /// Which reference instants the ambient SSI-COV correlations use.
    pub ssi_reference: SsiReference,
}

/// Which reference instants the ambient (SSI-COV) estimate's correlations sum over
/// (`ssi_reference` in the daemon's configuration; `spectral::SsiOptions::common_reference`,
/// docs/damping.md, "Growing windows: the correlations' reference instants").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum SsiReference {
    /// Every lag sums every instant whose partner lies in the window: on a window whose
    /// variance grows, each longer lag sees a quieter record, so a growth reads as damping.
    #[default]
    Lagged,
    /// Every lag sums the same instants: the mode's damping whatever the window's variance does.
    /// The window's regime is still classified on the lagged reading, on which the classifier
    /// was calibrated.
    Common,
}

from_config_word!(SsiReference, "SSI reference", "lagged or common");

/// How a model-based zeta0 gets its 95 % interval (`model_interval` in the daemon's
/// configuration; docs/damping.md, "zeta0_interval").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ModelInterval {
    /// The residuals' Newey-West covariance with the fixed-b critical value
    /// (`identify::covariance`). Why it is the default: it fires `GateNegativeDamping` on an
    /// onset's first negative windows, where the model reads the sign right. Its intervals are
    /// too narrow where the forcing decides the error (a burst's first window: 60 of 80 covered
    /// on the lock gate), and on the onset they are right about the sign, wrong about the size.
    #[default]
    NeweyWest,
    /// The turbulent forcing propagated through the fitted model
    /// (`identify::covariance_under_forcing`): honest where the model is right (a burst's
    /// first window: 80 of 80) and wide where it is not (an onset's ramp). It fires
    /// `GateNegativeDamping` 10 to 40 s later on an onset (docs/benchmarks.md, "The forcing
    /// through the model").
    Forcing,
}

from_config_word!(ModelInterval, "model interval", "newey-west or forcing");

/// Solver of a window's least-squares integrations (the full search's polish and the tracked
/// refinement; `polish_solver` in the daemon's configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PolishSolver {
    /// Classical RK4 on the sample grid, with as many steps per sample interval as give a cycle
    /// of the window's measured dominant frequency at least [`MIN_RK4_STEPS_PER_CYCLE`] steps
    /// (`series::polish_substeps`); Dormand-Prince where no frequency was measured.
    ///
    /// Why it is the daemon's default: a window's polish is most of its CPU (a CPU profile of
    /// `bench daemon` at 128 gates: half of the worker's time, against a tenth for the DE), and
    /// Dormand-Prince at 1e-6 needs more right-hand-side evaluations than RK4 at 32 steps per
    /// cycle, with a step-size controller on the critical path, one by one for every trial
    /// step. RK4's own error at 32 steps per cycle is far below what a window resolves
    /// (`MIN_RK4_STEPS_PER_CYCLE`), and its residuals are smooth in the coefficients (no
    /// step-size controller), which the forward-difference Jacobian likes. Measured: a cold
    /// window at two thirds of the CPU, a tracked one at two thirds, and the warning bench's
    /// rows as before or better (docs/benchmarks.md, "RK4 in the polish").
    #[default]
    Rk4,
    /// Dormand-Prince 5(4) at `polish_rtol` (the tracked refinement: `tracking.refine_rtol`),
    /// as before session 32.
    Dopri5,
}

/// Fewest RK4 steps per cycle of the dominant frequency in a window's polish
/// ([`PolishSolver::Rk4`]).
///
/// Why 32: classical RK4 applied to an undamped oscillator multiplies the amplitude by
/// `1 - (w h)^6 / 144` per step (its stability polynomial on the imaginary axis), a numerical
/// damping ratio of `(w h)^5 / 144`, and its frequency is off by about `(w h)^4 / 120`. At the
/// fundamental that is negligible from 16 steps per cycle (6e-5, 0.006 points). But the gate
/// model's cubic damping `c3*yd^2*yd` puts a third harmonic into a large-amplitude window, and
/// at 16 steps per cycle of the fundamental that harmonic has 5 (`(w h)^5 / 144` = 6e-3 on it).
/// Measured: with one step per sample on the lab gate (19 samples per cycle) 6 of 20 onset
/// seeds fired `GateNegativeDamping` after -1 %, against 4 with Dormand-Prince; with two steps
/// per sample (38 per cycle, the third harmonic at 13) 3 of 20 (docs/benchmarks.md, "RK4 in the
/// polish"). 32 steps per cycle give the third harmonic about 11: two steps per sample on the
/// daemon's gates (lab: 200 Hz at 10.4 Hz; lock: 100 Hz at 5 Hz).
pub const MIN_RK4_STEPS_PER_CYCLE: f64 = 32.0;

/// Default [`AnalysisSettings::polish_rtol`] of a daemon window: 1e-6.
///
/// Why not the library's 1e-8 (`identify::Search::refine_rtol`, which takes the noise-free seed
/// cases to an NMAE of ~1e-5): a gate's window fits to an NMAE of about 0.5 (the turbulent
/// forcing a free-vibration model cannot follow), so the solver's 1e-6 is five orders below what
/// the fit can resolve, and it halves a cold window's CPU (Dormand-Prince needs about
/// `100^(1/5) = 2.5` times fewer steps; docs/benchmarks.md, "A looser polish for noisy
/// windows"). The difference step of the polish's Jacobian follows the tolerance
/// (`identify::polish::fd_step`), which is what made 1e-6 lose accuracy before.
pub const DEFAULT_POLISH_RTOL: f64 = 1e-6;

/// One uniformly sampled window.
#[derive(Debug, Clone, Copy)]
pub struct WindowInput<'a> {
    /// Time of the first sample, Unix seconds.
    pub t0: f64,
    /// Sample rate in Hz.
    pub rate_hz: f64,
    /// The samples, oldest first.
    pub values: &'a [f64],
    /// The gate's contiguous samples up to the window's end (the window is their tail), oldest
    /// first, for the estimates that need more cycles than the window holds (a limit cycle's
    /// envelope relaxation, docs/damping.md). Empty, or not longer than `values`: the window
    /// alone.
    pub history: &'a [f64],
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
    /// Whether the window was identified by the full search or tracked from the previous
    /// window's model ([`tracking`]).
    #[serde(default)]
    pub path: Path,
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
