//! The daemon's per-window analyzer: the model compiled and the settings checked once per gate,
//! then [`Analyzer::analyze`] for every window.

use super::series::{analyze_series_with, track_series_with, SeriesOptions};
use super::tracking::{self, Path, Previous, TrackingPolicy};
use super::{AnalysisError, AnalysisSettings, Signal, WindowAnalysis, WindowInput};
use crate::data::TimeSeries;
use crate::identify;
use crate::model::Model;

/// A gate's analysis, prepared once (model compiled, settings checked), used for every window.
/// `Send + Sync`: the daemon shares one per gate across its worker threads.
#[derive(Debug, Clone)]
pub struct Analyzer {
    settings: AnalysisSettings,
    model: Model,
    /// Spectral analyzers (FFT plans and buffers) of past windows, borrowed by one analysis at
    /// a time and returned, so FFTs are planned once per window length and worker, not per
    /// window. Bounded by the number of concurrent analyses.
    spectral_pool: std::sync::Arc<std::sync::Mutex<Vec<crate::spectral::SpectralAnalyzer>>>,
    /// When [`Analyzer::analyze_tracked`] may refine the previous window's model.
    tracking: TrackingPolicy,
}

impl Analyzer {
    /// Checks the settings and compiles the model.
    pub fn new(settings: AnalysisSettings) -> Result<Analyzer, AnalysisError> {
        let model = Model::parse(&settings.model, &settings.params)
            .map_err(|e| AnalysisError::Settings(format!("model: {e}")))?;
        if model.n_coeffs() == 0 {
            return Err(AnalysisError::Settings(
                "model: no unknown coefficients c1, c2, ...".into(),
            ));
        }
        if settings.signal == Signal::Force
            && !settings.stiffness.is_some_and(|k| k.is_finite() && k > 0.0)
        {
            return Err(AnalysisError::Settings(
                "force signals need the installed stiffness (> 0)".into(),
            ));
        }
        if settings.population < 4 {
            return Err(AnalysisError::Settings(
                "population must be at least 4".into(),
            ));
        }
        Ok(Analyzer {
            settings,
            model,
            spectral_pool: Default::default(),
            tracking: TrackingPolicy::default(),
        })
    }

    /// The compiled model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The same analyzer with another tracking policy (checked).
    pub fn with_tracking(mut self, policy: TrackingPolicy) -> Result<Analyzer, AnalysisError> {
        policy
            .validate()
            .map_err(|e| AnalysisError::Settings(format!("tracking.{e}")))?;
        self.tracking = policy;
        Ok(self)
    }

    /// The tracking policy.
    pub fn tracking(&self) -> &TrackingPolicy {
        &self.tracking
    }

    /// Whether `equation` is this analyzer's model with `coefficients` put in (what
    /// [`WindowAnalysis::equation`] holds): a stored window of the same model, whose
    /// coefficients may start a refinement. A changed model, or another number of
    /// coefficients, is not.
    pub fn describes(&self, equation: &str, coefficients: &[f64]) -> bool {
        coefficients.len() == self.model.n_coeffs()
            && coefficients.iter().all(|c| c.is_finite())
            && self.model.substitute(coefficients) == equation
    }

    /// The settings this analyzer was made with.
    pub fn settings(&self) -> &AnalysisSettings {
        &self.settings
    }

    /// Identifies the model on `input` and reports its damping. `warm` is the previous window's
    /// [`WindowAnalysis::warm_start`] of the same gate; `seed` makes the result reproducible.
    pub fn analyze(
        &self,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        self.analyze_with(input, Start::Search(warm), seed, true)
    }

    /// Analyses a window of a gate whose last window is `previous` (`None`: a new gate): the
    /// tracked path when [`tracking::plan`] allows it and [`tracking::accept`] takes the refined
    /// model, else the full search warm-started from `previous` (what [`Analyzer::analyze`]
    /// does). The result's `path` says which; its `seconds` and `evaluations` include a refused
    /// refinement. A refinement that fails is not an error: the full search runs and reports
    /// its own.
    pub fn analyze_tracked(
        &self,
        input: WindowInput<'_>,
        previous: Option<&Previous>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        let started = std::time::Instant::now();
        let mut refused_evaluations = 0;
        if let Ok(p) = tracking::plan(&self.tracking, previous, input.t0) {
            let start = Start::Refine(&p.coefficients, self.tracking.refine_evaluations);
            if let Ok(a) = self.analyze_with(input, start, seed, true) {
                if let Ok(how) = tracking::accept(&self.tracking, p, &a.damping) {
                    // A window accepted without the fit tests does not move the next
                    // refinement's start: chained, the refinements of the noise random-walked
                    // (docs/design.md, "Tracking between windows").
                    let warm_start = match how {
                        tracking::Acceptance::Waived => p.coefficients.clone(),
                        tracking::Acceptance::Fitted => a.warm_start,
                    };
                    return Ok(WindowAnalysis {
                        path: Path::Tracked,
                        warm_start,
                        ..a
                    });
                }
                refused_evaluations = a.evaluations;
            }
        }
        let warm = previous.map(|p| p.coefficients.as_slice());
        let mut a = self.analyze_with(input, Start::Search(warm), seed, true)?;
        a.evaluations += refused_evaluations;
        a.seconds = started.elapsed().as_secs_f64();
        Ok(a)
    }

    /// [`Analyzer::analyze`] without the FFT-biased initial population (for the benchmark that
    /// shows what the bias buys).
    pub fn analyze_unbiased(
        &self,
        input: WindowInput<'_>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        self.analyze_with(input, Start::Search(None), seed, false)
    }

    fn analyze_with(
        &self,
        input: WindowInput<'_>,
        start: Start<'_>,
        seed: u64,
        fft_bias: bool,
    ) -> Result<WindowAnalysis, AnalysisError> {
        let started = std::time::Instant::now();
        if !(input.rate_hz.is_finite() && input.rate_hz > 0.0) {
            return Err(AnalysisError::Window(
                "the sample rate must be positive".into(),
            ));
        }
        if let Some(i) = input.values.iter().position(|v| !v.is_finite()) {
            return Err(AnalysisError::Window(format!("sample {i} is not finite")));
        }
        // Window-relative time keeps the numbers small; time-dependent models see t = 0 at the
        // window's start.
        let t: Vec<f64> = (0..input.values.len())
            .map(|i| i as f64 / input.rate_hz)
            .collect();
        let series = TimeSeries::new(t, input.values.to_vec())
            .map_err(|e| AnalysisError::Window(e.to_string()))?;
        let s = &self.settings;
        let mut opts = SeriesOptions {
            signal: s.signal,
            force_terms: s.force_terms,
            stiffness: s.stiffness,
            identify: identify::Config {
                search: identify::Search {
                    population: s.population,
                    generations: s.generations,
                    // One RK4 step per sample: three times cheaper than dopri5 over a long
                    // window; the polish (`polish_solver`) sets the final accuracy.
                    solver: crate::ode::Method::Rk4,
                    substeps: 1,
                    refine_rtol: s.polish_rtol,
                    ..identify::Search::default()
                },
                protocol: identify::Protocol {
                    seed,
                    split_seed: seed,
                    // The daemon's work per window must stay bounded: no retries.
                    max_attempts: 1,
                    ..identify::Protocol::default()
                },
                ..identify::Config::default()
            },
            amplitude_limit: s.amplitude_limit,
            max_fit_nmae: s.max_fit_nmae,
            fft_bias,
            polish_solver: s.polish_solver,
            model_interval: s.model_interval,
            ssi_reference: s.ssi_reference,
            ..SeriesOptions::default()
        };
        if let Start::Refine(..) = start {
            // The tracked refinement's own tolerance (`tracking.refine_rtol`).
            opts.identify.search.refine_rtol = self.tracking.refine_rtol;
        }
        // Borrow a spectral analyzer (the lock is held only to pop and push, never during the
        // analysis; a poisoned pool just means planning afresh).
        let mut spectral = self.spectral_pool.lock().ok().and_then(|mut p| p.pop());
        let result = match start {
            Start::Search(warm) => analyze_series_with(
                &self.model,
                &series,
                input.history,
                &opts,
                warm,
                &mut spectral,
                |_, _, _| {},
            ),
            Start::Refine(from, evaluations) => track_series_with(
                &self.model,
                &series,
                input.history,
                &opts,
                from,
                evaluations,
                &mut spectral,
            ),
        };
        if let (Some(sa), Ok(mut pool)) = (spectral, self.spectral_pool.lock()) {
            pool.push(sa);
        }
        let a = result?;
        let run = a.identification.best_run();
        Ok(WindowAnalysis {
            equation: self.model.substitute(&a.coefficients),
            coefficients: a
                .coefficients
                .iter()
                .enumerate()
                .map(|(i, v)| (format!("c{}", i + 1), *v))
                .collect(),
            damping: a.damping,
            evaluations: run.evaluations,
            seconds: started.elapsed().as_secs_f64(),
            warm_start: a.coefficients,
            path: Path::Full,
        })
    }
}

/// Where [`Analyzer::analyze_with`] starts.
#[derive(Clone, Copy)]
enum Start<'a> {
    /// The DE search, warm-started.
    Search(Option<&'a [f64]>),
    /// The refinement of these coefficients with at most this many integrations.
    Refine(&'a [f64], usize),
}
