//! The analysis of one series, phase by phase: the model-free analysis ([`super::model_free`]),
//! force-mode scaling (pre-run for the initial conditions, coefficient scales), the initial
//! population, the identification, the damping figures and the verdict.

use super::linearisation::{
    cycle_zeta0, equivalent_damping, limit_cycle, time_to_amplitude, Linearization,
};
use super::model_free::{model_free, moving_average_window, preprocess, rms_swing, ModelFree};
use super::model_interval::{intervals, zeta0_interval, FittedModel};
use super::population::{initial_population, PopulationInputs, SpectralTarget};
use super::report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
use super::verdict::{agrees, decide, VerdictFacts, WindowGrowth};
use super::{
    AnalysisError, ForceTerms, ModelInterval, PolishSolver, Signal, MIN_RK4_STEPS_PER_CYCLE,
};
use crate::data::TimeSeries;
use crate::identify::{self, Identification, InitialValues};
use crate::model::Model;
use crate::spectral::{SpectralAnalyzer, WindowOptions};
use std::f64::consts::PI;

/// Options of [`analyze_series`].
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesOptions {
    /// What the samples are.
    pub signal: Signal,
    /// What a force signal holds (the identification's output in force mode).
    pub force_terms: ForceTerms,
    /// Installed stiffness, N/m (force mode).
    pub stiffness: Option<f64>,
    /// The identification's settings (population, generations, runs, seeds, solver, ...). In
    /// force mode its `initial`, `output`, `scales`, `y_scale` and `polish_initial` are set here.
    pub identify: identify::Config,
    /// Bias half of the initial population towards the measured frequency and growth.
    pub fft_bias: bool,
    /// Force mode: a centred moving average over this many seconds is subtracted first (the
    /// chapter's only pre-processing; removes drift). 0: none.
    pub moving_average_seconds: f64,
    /// Amplitude in the signal's unit whose time of reach is predicted.
    pub amplitude_limit: Option<f64>,
    /// Above this fit NMAE the model is not trusted.
    pub max_fit_nmae: f64,
    /// Solver of the polish and the refinement: [`PolishSolver::Rk4`] replaces the
    /// identification's own (`identify.search.refine_solver`) with RK4 at
    /// [`polish_substeps`] where the window's dominant frequency was measured.
    pub polish_solver: PolishSolver,
    /// How a model-based zeta0 gets its interval.
    pub model_interval: ModelInterval,
    /// Which reference instants the ambient SSI-COV correlations use.
    pub ssi_reference: super::SsiReference,
}

impl Default for SeriesOptions {
    fn default() -> Self {
        SeriesOptions {
            signal: Signal::Displacement,
            force_terms: ForceTerms::All,
            stiffness: None,
            identify: identify::Config::default(),
            fft_bias: true,
            moving_average_seconds: 1.0,
            amplitude_limit: None,
            max_fit_nmae: 0.2,
            // The library's polish as it always was; the daemon chooses RK4
            // (`AnalysisSettings::polish_solver`).
            polish_solver: PolishSolver::Dopri5,
            model_interval: ModelInterval::NeweyWest,
            ssi_reference: super::SsiReference::default(),
        }
    }
}

/// RK4 steps per sample interval that give a cycle at angular frequency `omega` (rad/s) at
/// least [`MIN_RK4_STEPS_PER_CYCLE`] steps with samples `dt` seconds apart, at most 1000;
/// `None` when `omega` or `dt` is not a positive finite number.
pub fn polish_substeps(omega: f64, dt: f64) -> Option<usize> {
    let steps_per_sample = MIN_RK4_STEPS_PER_CYCLE * omega * dt / (2.0 * PI);
    (steps_per_sample.is_finite() && steps_per_sample > 0.0)
        .then(|| (steps_per_sample.ceil() as usize).clamp(1, 1000))
}

/// Everything [`analyze_series`] found.
#[derive(Debug, Clone)]
pub struct SeriesAnalysis {
    /// The identification (runs, summary, split).
    pub identification: Identification,
    /// The chosen coefficients, physical units.
    pub coefficients: Vec<f64>,
    /// The initial conditions used (force mode: from the pre-run, polished).
    pub initial: InitialValues,
    /// Damping figures and verdict.
    pub damping: DampingReport,
    /// The data as identified (after pre-processing).
    pub data: TimeSeries,
    /// Samples at each end of `data` where the centred moving average of the pre-processing
    /// was truncated (its half width; 0 without one): there the average lags the drift, so
    /// the data carry an offset the model does not (`spectral::remove_moving_average`). A
    /// picture of "the last periods" ends before them.
    pub edge_samples: usize,
    /// The model's output at every sample (displacement or support force).
    pub prediction: Option<Vec<f64>>,
    /// The model's state `[y, yd]` at every sample.
    pub trajectory: Option<Vec<[f64; 2]>>,
    /// The linearisation at rest.
    pub linearization: Linearization,
}

/// Section 8.5's pre-run: fits `F ~ exp(sigma t) (a cos wt + b sin wt) + d` by linear least
/// squares on the first three periods (the chapter fits `C1 sin(C2 t + C3)` by DE; with `w` from
/// the spectrum the problem is linear) and returns `y0 = F(0)/k`, `v0 = F'(0)/k`.
pub fn pre_run(data: &TimeSeries, w: f64, sigma: f64, k: f64) -> Option<(f64, f64)> {
    let t0 = *data.t.first()?;
    let span = 3.0 * 2.0 * std::f64::consts::PI / w;
    let m = data
        .t
        .iter()
        .take_while(|&&t| t - t0 <= span)
        .count()
        .max(8)
        .min(data.len());
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = nalgebra::Vector3::<f64>::zeros();
    for i in 0..m {
        let tau = data.t[i] - t0;
        let e = (sigma * tau).exp();
        let row = nalgebra::Vector3::new(e * (w * tau).cos(), e * (w * tau).sin(), 1.0);
        a += row * row.transpose();
        rhs += row * data.y[i];
    }
    let sol = a.lu().solve(&rhs)?;
    let (ca, cb) = (sol[0], sol[1]);
    let (y0, v0) = (ca / k, (sigma * ca + w * cb) / k);
    (y0.is_finite() && v0.is_finite()).then_some((y0, v0))
}

/// Force mode: the physical value per unit DE coordinate of each coefficient, so that the DE
/// searches numbers of order one. Coefficient `j` gets `F_rms / g_j`, where `g_j` is the RMS over
/// a harmonic cycle of amplitude `a` at `w` of `d(M*ydd + R)/dc_j`: one unit is a term as large as
/// the measured force. Terms odd in the velocity (damping) get [`DAMPING_FORCE_FRACTION`] of
/// that: a gate's damping force is a few percent of the total (twice the damping ratio), so its
/// coefficients land in [-1, 1] where the DE starts.
pub fn term_scales(model: &Model, t0: f64, a: f64, w: f64, f_rms: f64) -> Vec<f64> {
    let d = model.n_coeffs();
    const N: usize = 64;
    let base = vec![1.0; d];
    (0..d)
        .map(|j| {
            let (mut g2, mut odd2) = (0.0, 0.0);
            let mut cp = base.clone();
            let mut cm = base.clone();
            cp[j] += 1e-3;
            cm[j] -= 1e-3;
            let e = |c: &[f64], y: f64, yd: f64, ydd: f64| {
                model.mass(t0, y, yd, c) * ydd + model.residual(t0, y, yd, c)
            };
            for k in 0..N {
                let th = 2.0 * std::f64::consts::PI * k as f64 / N as f64;
                let (y, yd, ydd) = (a * th.cos(), -a * w * th.sin(), -a * w * w * th.cos());
                let dj = (e(&cp, y, yd, ydd) - e(&cm, y, yd, ydd)) / 2e-3;
                let dj_flip = (e(&cp, y, -yd, ydd) - e(&cm, y, -yd, ydd)) / 2e-3;
                g2 += dj * dj;
                odd2 += (0.5 * (dj - dj_flip)).powi(2);
            }
            let g = (g2 / N as f64).sqrt();
            let damping_like = odd2 > 0.5 * g2;
            let s = f_rms / g
                * if damping_like {
                    DAMPING_FORCE_FRACTION
                } else {
                    1.0
                };
            if s.is_finite() && s > 0.0 {
                s
            } else {
                1.0
            }
        })
        .collect()
}

/// Displacement mode: the physical value per unit DE coordinate of each coefficient (then of
/// `y0` and `v0` when they are fitted), from the record's unit `u`, its largest magnitude
/// rounded to a power of ten: `u^p_j` for the coefficients' amplitude exponents
/// ([`Model::amplitude_exponents`]), `u` for the initial conditions. Empty (all 1, the chapter's
/// search box) for a record of order one (largest magnitude from 0.32 to 3.2) and for a model
/// whose solutions' size is physical. Why a power of ten rather than the magnitude itself: a
/// record of order one is searched exactly as before, and the unit-scale problem a larger
/// record becomes is the same whatever its exact amplitude.
pub fn displacement_scales(model: &Model, magnitude: f64, initial: &identify::Initial) -> Vec<f64> {
    let unit = 10f64.powf(magnitude.log10().round());
    if !(unit.is_finite() && unit > 0.0) || unit == 1.0 {
        return Vec::new();
    }
    let Some(p) = model.amplitude_exponents() else {
        return Vec::new();
    };
    let mut scales: Vec<f64> = p.iter().map(|p| unit.powf(*p)).collect();
    if matches!(initial, identify::Initial::Fit) {
        scales.extend_from_slice(&[unit, unit]);
    }
    if scales.iter().all(|s| s.is_finite() && *s > 0.0) {
        scales
    } else {
        Vec::new()
    }
}

/// Fraction of the measured force that one DE unit of a damping-like coefficient represents.
/// Value: a gate's damping force is about twice its damping ratio times the total force, a few
/// percent for the chapter's gates (|zeta| of 1-2 %), so 3 % puts their damping coefficients at
/// order one, inside the DE's starting box [-1, 1].
pub const DAMPING_FORCE_FRACTION: f64 = 0.03;

/// Identifies `model` on `series` and reports what its damping means (see `docs/damping.md`).
/// `warm` are physical coefficients of a previous identification of the same gate, placed in
/// the initial population.
pub fn analyze_series(
    model: &Model,
    series: &TimeSeries,
    opts: &SeriesOptions,
    warm: Option<&[f64]>,
    progress: impl FnMut(usize, usize, f64),
) -> Result<SeriesAnalysis, AnalysisError> {
    analyze_series_with(model, series, &[], opts, warm, &mut None, progress)
}

/// [`analyze_series`] with a reusable spectral analyzer: `spectral` is used when it fits the
/// series' length and rate, and replaced by a new one (FFT plans and buffers) otherwise, so a
/// caller that analyses windows of one length plans its FFTs once. `history`: the gate's raw
/// samples up to the series' end at its rate, for a limit cycle's envelope relaxation
/// ([`crate::analysis::WindowInput::history`]; empty: the series alone).
pub fn analyze_series_with(
    model: &Model,
    series: &TimeSeries,
    history: &[f64],
    opts: &SeriesOptions,
    warm: Option<&[f64]>,
    spectral: &mut Option<SpectralAnalyzer>,
    progress: impl FnMut(usize, usize, f64),
) -> Result<SeriesAnalysis, AnalysisError> {
    analyze(
        model,
        series,
        history,
        opts,
        Start::Search(warm),
        spectral,
        progress,
    )
}

/// [`analyze_series_with`] without the DE search: the coefficients `from` (physical units, e.g.
/// the previous window's of the same gate) are refined by least squares with at most about
/// `max_evaluations` integrations ([`identify::refine`]); everything else (pre-processing,
/// model-free analysis, scaling, damping figures, verdict) is the same. Whether the result may
/// stand is the caller's decision ([`super::tracking::accept`]).
pub fn track_series_with(
    model: &Model,
    series: &TimeSeries,
    history: &[f64],
    opts: &SeriesOptions,
    from: &[f64],
    max_evaluations: usize,
    spectral: &mut Option<SpectralAnalyzer>,
) -> Result<SeriesAnalysis, AnalysisError> {
    analyze(
        model,
        series,
        history,
        opts,
        Start::Refine(from, max_evaluations),
        spectral,
        |_, _, _| {},
    )
}

/// Where the identification of [`analyze`] starts.
#[derive(Clone, Copy)]
enum Start<'a> {
    /// The DE search, with an optional warm start in its initial population.
    Search(Option<&'a [f64]>),
    /// The least-squares refinement of these coefficients, with this many integrations at most.
    Refine(&'a [f64], usize),
}

fn analyze(
    model: &Model,
    series: &TimeSeries,
    history: &[f64],
    opts: &SeriesOptions,
    start: Start<'_>,
    spectral: &mut Option<SpectralAnalyzer>,
    progress: impl FnMut(usize, usize, f64),
) -> Result<SeriesAnalysis, AnalysisError> {
    let n = series.len();
    if n < 2 {
        return Err(AnalysisError::Window(format!("{n} samples are too few")));
    }
    let t0 = series.t[0];
    let data = preprocess(series, opts);
    let edge_samples = moving_average_window(series, opts).map_or(0, |w| w / 2);
    let free = model_free(&data, history, opts, spectral);

    let mut config = opts.identify.clone();
    if opts.polish_solver == PolishSolver::Rk4 {
        let dt = data.t.get(1).zip(data.t.first()).map(|(b, a)| b - a);
        if let Some(substeps) = free
            .omega
            .zip(dt)
            .and_then(|(w, dt)| polish_substeps(w, dt))
        {
            config.search.refine_solver = crate::ode::Method::Rk4;
            config.search.refine_substeps = substeps;
        }
    }
    let scale = scale_problem(model, &data, opts, &free, &mut config)?;
    // The coefficients' scales (a fitted `(y0, v0)` follows them).
    let scales = if config.scales.len() >= model.n_coeffs() {
        config.scales[..model.n_coeffs()].to_vec()
    } else {
        vec![1.0; model.n_coeffs()]
    };
    // The refinement has no population: the biased one (dozens of linearisations) is skipped.
    if let Start::Search(warm) = start {
        let initial_population = initial_population(
            model,
            warm,
            &PopulationInputs {
                scales: &scales,
                population: config.search.population,
                seed: config.protocol.seed,
                fit_initial_conditions: matches!(config.initial, identify::Initial::Fit),
                fft_bias: opts.fft_bias,
                target: free.omega.map(|omega| SpectralTarget {
                    omega,
                    sigma: free.sigma_clean,
                }),
                t0,
                y_scale: scale.y,
                v_scale: scale.v,
            },
        );
        config.search.initial_population = initial_population;
    }

    let identification = match start {
        Start::Search(_) => identify::identify(model, &data, &config, progress),
        Start::Refine(from, max_evaluations) => config.validate().and_then(|()| {
            let problem = config.problem(model, &data)?;
            identify::refine(
                &problem,
                &config.search,
                &config.protocol,
                from,
                max_evaluations,
            )
        }),
    }
    .map_err(|e| match e {
        identify::IdentifyError::De(e) => AnalysisError::Settings(e.to_string()),
        other => AnalysisError::Settings(other.to_string()),
    })?;
    let best = identification.best_run().clone();
    let c = best.coefficients.clone();
    let lin = Linearization::of(model, &c, t0, scale.y, scale.v);
    let trajectory =
        identify::trajectory(model, &data.t, &c, best.initial, config.protocol.test_rtol);
    // The prediction is the trajectory's output: one integration for both (what
    // `identify::predict` would integrate again).
    let prediction = trajectory
        .as_ref()
        .map(|tr| identify::output_of(model, &data.t, &c, tr, config.output));
    let fit_nmae = prediction
        .as_ref()
        .and_then(|p| identify::nmae(p.iter().copied().zip(data.y.iter().copied())))
        .unwrap_or(f64::INFINITY);

    let fitted = Fitted {
        model,
        c: &c,
        lin: &lin,
        t0,
        signal: opts.signal,
    };
    let mut damping = damping_figures(&fitted, &data, trajectory.as_deref(), free.omega, opts);
    damping.fit_nmae = fit_nmae;
    // Agreement with the model-free estimates: the same spectral analysis of the prediction
    // (peak and growth; `agrees` compares nothing else, so no ambient estimate of it).
    let prediction_options = WindowOptions {
        ambient: crate::spectral::AmbientMethod::Skip,
        ..free.window_options
    };
    let model_spec = match (spectral.as_mut(), prediction.as_ref()) {
        (Some(sa), Some(p)) => sa.analyze_window(p, &prediction_options).ok(),
        _ => None,
    };
    // Without the window's spectrum there is nothing to compare (n/a); with it, a model that
    // could not be simulated agrees with nothing.
    damping.agrees = free
        .spec
        .as_ref()
        .map(|d| fit_nmae.is_finite() && agrees(Some(d), model_spec.as_ref()));
    if let Some(s) = &free.spec {
        damping.frequency_hz = Some(s.peak.frequency_hz);
        damping.growth_rate = Some(s.growth.sigma);
        damping.growth_rate_stderr = Some(s.growth.stderr);
        damping.ambient_zeta = s.ambient.as_ref().map(AmbientZeta::from);
        damping.ambient_common_zeta = s.ambient_common.as_ref().map(AmbientZeta::from);
        damping.ambient_frequency_hz = s.ambient.as_ref().map(|a| a.frequency_hz);
        damping.signal_rms = Some(identify::std_dev(&data.y)).filter(|r| r.is_finite());
        damping.rms_swing = rms_swing(&data.y);
        damping.window_cycles = match (data.t.first(), data.t.last()) {
            (Some(a), Some(b)) => Some(s.peak.frequency_hz * (b - a)).filter(|c| c.is_finite()),
            _ => None,
        };
    }
    damping.envelope_zeta = free.relaxation;
    damping.envelope_record_seconds = free.envelope_record_seconds;
    damping.envelope_drift_zeta = free.drift;
    damping.ambient_record_zeta = free.ambient_record.map(|r| r.0);
    damping.ambient_record_seconds = free.ambient_record.map(|r| r.1);
    let runs_zeta: Vec<f64> = identification
        .runs
        .iter()
        .filter_map(|r| Linearization::of(model, &r.coefficients, t0, scale.y, scale.v).zeta0())
        .collect();
    let fit = FittedModel {
        model,
        coefficients: &c,
        scales: &scales,
        initial: best.initial,
        output: config.output,
        initial_estimated: config.polish_initial.is_some()
            || !matches!(config.initial, identify::Initial::Known { .. }),
    };
    // Computed only when the model's zeta0 is reported (2p + 1 integrations).
    let model_interval = |method: ModelInterval| {
        hull(
            zeta0_interval(&fit, &data, t0, scale.y, scale.v, method),
            run_spread(runs_zeta.iter().copied()),
        )
    };
    // On a window that grew into its cycle: zeta0 and the damping law it carries, both under the
    // forcing, from one covariance. The law is zeta0 as the cycle's amplitude (in the signal's
    // unit, as the gate's memory will measure it) says it through these coefficients'
    // non-linear damping (`cycle_zeta0`): at the optimum the model's zeta0, but with the
    // non-linear term's uncertainty, which zeta0's interval leaves out (docs/damping.md, "The
    // cycle's amplitude").
    let cycle = damping.limit_cycle_amplitude;
    let law_at = |c: &[f64]| {
        let lin = Linearization::of(model, c, t0, scale.y, scale.v);
        let a = match opts.signal {
            Signal::Force => cycle? / lin.k0.abs(),
            Signal::Displacement => cycle?,
        };
        cycle_zeta0(model, c, &lin, a, t0)
    };
    let growth_intervals = || {
        let zeta0 = |c: &[f64]| Linearization::of(model, c, t0, scale.y, scale.v).zeta0();
        let [z, law] = intervals(
            &fit,
            &data,
            (scale.y, scale.v),
            ModelInterval::Forcing,
            [&zeta0, &law_at],
        );
        let runs_law = identification
            .runs
            .iter()
            .filter_map(|r| law_at(&r.coefficients));
        GrowthIntervals {
            zeta0: hull(z, run_spread(runs_zeta.iter().copied())),
            law: law_at(&c).zip(hull(law, run_spread(runs_law))),
        }
    };
    conclude(
        &mut damping,
        free.drift,
        lin.zeta0(),
        (model_interval, opts.model_interval),
        growth_intervals,
        free.spec.map(|s| s.regime),
        opts.max_fit_nmae,
    );
    Ok(SeriesAnalysis {
        identification,
        coefficients: c,
        initial: best.initial,
        damping,
        data,
        edge_samples,
        prediction,
        trajectory,
        linearization: lin,
    })
}

/// Displacement and velocity scales of the problem (steps of the linearisation, bias targets).
#[derive(Debug, Clone, Copy)]
struct ProblemScales {
    /// Displacement, m or the data's unit.
    y: f64,
    /// Velocity.
    v: f64,
}

/// Scales the problem. Force mode (section 8.5): the pre-run gives the initial conditions, the
/// identification fits the support force with coefficients scaled by [`term_scales`].
/// Displacement mode: the data's largest magnitude and the measured frequency.
fn scale_problem(
    model: &Model,
    data: &TimeSeries,
    opts: &SeriesOptions,
    free: &ModelFree,
    config: &mut identify::Config,
) -> Result<ProblemScales, AnalysisError> {
    let t0 = data.t[0];
    match opts.signal {
        Signal::Force => {
            let k = opts
                .stiffness
                .filter(|k| k.is_finite() && *k > 0.0)
                .ok_or_else(|| {
                    AnalysisError::Settings(
                        "force signals need the installed stiffness (> 0)".into(),
                    )
                })?;
            let w = free.omega.ok_or_else(|| {
                AnalysisError::Window("no dominant frequency in the window".into())
            })?;
            let sigma = free.spec.as_ref().map_or(0.0, |s| s.growth.sigma);
            let (y0, v0) = pre_run(data, w, sigma, k).ok_or_else(|| {
                AnalysisError::Window("the pre-run for the initial conditions failed".into())
            })?;
            let f_rms = identify::std_dev(&data.y);
            if f_rms.is_nan() || f_rms <= 0.0 {
                return Err(AnalysisError::Window("the signal is constant".into()));
            }
            let y_scale = std::f64::consts::SQRT_2 * f_rms / k;
            config.initial = identify::Initial::Known { y0, v0 };
            config.output = opts.force_terms.output();
            config.scales = term_scales(model, t0, y_scale, w, f_rms);
            config.y_scale = Some(y_scale);
            config.polish_initial = Some((y_scale, y_scale * w));
            Ok(ProblemScales {
                y: y_scale,
                v: y_scale * w,
            })
        }
        Signal::Displacement => {
            let y_scale = data
                .y
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
                .max(f64::MIN_POSITIVE);
            if config.scales.is_empty() {
                config.scales = displacement_scales(model, y_scale, &config.initial);
            }
            Ok(ProblemScales {
                y: y_scale,
                v: y_scale * free.omega.unwrap_or(1.0),
            })
        }
    }
}

/// The identified model and where its linearisation was taken.
struct Fitted<'a> {
    model: &'a Model,
    c: &'a [f64],
    lin: &'a Linearization,
    t0: f64,
    signal: Signal,
}

impl Fitted<'_> {
    /// Displacement amplitude to the signal's unit (force mode: `K0 * a`).
    fn signal_of(&self, a: f64) -> f64 {
        if self.signal == Signal::Force {
            self.lin.k0.abs() * a
        } else {
            a
        }
    }

    /// The signal's unit to displacement amplitude.
    fn displacement_of(&self, s: f64) -> f64 {
        if self.signal == Signal::Force {
            s / self.lin.k0.abs()
        } else {
            s
        }
    }
}

/// The model's damping figures at the window's amplitude: `zeta_eq`, energy per cycle, limit
/// cycle, time to the configured limit, the model's frequency. The rest of the report (spectrum,
/// agreement, verdict) is filled in by the caller.
fn damping_figures(
    f: &Fitted<'_>,
    data: &TimeSeries,
    trajectory: Option<&[[f64; 2]]>,
    omega_meas: Option<f64>,
    opts: &SeriesOptions,
) -> DampingReport {
    let (model, c, lin, t0) = (f.model, f.c, f.lin, f.t0);
    // Amplitude now: the model's largest |y| over its last period.
    let amplitude = trajectory.and_then(|tr| {
        let period = 2.0 * PI / lin.omega0().or(omega_meas)?;
        let t_end = data.t[data.len() - 1];
        let a = tr
            .iter()
            .zip(&data.t)
            .filter(|(_, &t)| t >= t_end - period)
            .fold(0.0f64, |m, (s, _)| m.max(s[0].abs()));
        (a > 0.0).then_some(a)
    });
    let eq = amplitude.and_then(|a| equivalent_damping(model, c, lin, a, t0));
    let limit_cycle_amplitude = match (lin.zeta0(), amplitude) {
        (Some(z), Some(a)) if z < 0.0 => limit_cycle(model, c, lin, a, t0).map(|a| f.signal_of(a)),
        _ => None,
    };
    let time_to_limit = match (opts.amplitude_limit, amplitude) {
        (Some(limit), Some(a)) if limit > 0.0 => {
            time_to_amplitude(model, c, lin, a, f.displacement_of(limit), t0)
        }
        _ => None,
    };
    let zeta_eq_curve = trajectory
        .and_then(|tr| visited_amplitudes(tr, &data.t, lin.omega0().or(omega_meas)?))
        .map(|(lo, hi)| {
            (0..CURVE_POINTS)
                .filter_map(|k| {
                    let a = lo + (hi - lo) * k as f64 / (CURVE_POINTS - 1) as f64;
                    let (z, _) = equivalent_damping(model, c, lin, a, t0)?;
                    Some((f.signal_of(a), z))
                })
                .collect()
        })
        .unwrap_or_default();
    DampingReport {
        zeta_eq_curve,
        zeta_eq: eq.map(|e| e.0),
        energy_per_cycle: eq.map(|e| e.1),
        limit_cycle_amplitude,
        time_to_limit,
        model_frequency_hz: lin.omega0().map(|w| w / (2.0 * PI)),
        amplitude: amplitude.map(|a| f.signal_of(a)),
        ..DampingReport::unknown()
    }
}

/// Points of the `zeta_eq(A)` curve of a report: few enough for the API, enough for a picture.
pub const CURVE_POINTS: usize = 17;

/// The smallest and largest per-period peak `|y|` of the model's trajectory: the amplitudes the
/// window visited (`None` without a full period or with a zero peak).
fn visited_amplitudes(tr: &[[f64; 2]], t: &[f64], omega: f64) -> Option<(f64, f64)> {
    let period = 2.0 * PI / omega;
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    let (mut start, mut peak) = (*t.first()?, 0.0f64);
    for (s, &ti) in tr.iter().zip(t) {
        if ti - start >= period {
            lo = lo.min(peak);
            hi = hi.max(peak);
            start = ti;
            peak = 0.0;
        }
        peak = peak.max(s[0].abs());
    }
    (hi > 0.0 && lo.is_finite() && lo > 0.0).then_some((lo, hi))
}

/// Range of zeta0 over the runs, when there were several.
fn run_spread(zetas: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (mut count, mut lo, mut hi) = (0usize, f64::INFINITY, f64::NEG_INFINITY);
    for z in zetas {
        count += 1;
        lo = lo.min(z);
        hi = hi.max(z);
    }
    (count > 1).then_some((lo, hi))
}

/// The smallest interval holding both (either alone when the other is missing): the
/// covariance interval widened by the runs' spread, which it may not cover when runs land in
/// different minima.
fn hull(a: Option<(f64, f64)>, b: Option<(f64, f64)>) -> Option<(f64, f64)> {
    match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, b) => a.or(b),
    }
}

/// Fills in the verdict, `trusted` and `zeta0` with its interval and source from the report's
/// fit, agreement, ambient and envelope estimates and the envelope's `drift` ([`decide`]),
/// `model_zeta` when the model is trusted (its interval by the configured method, computed at
/// most once, and only when the model is trusted or decides), and `growth_zeta` on a window that
/// grew into its cycle.
fn conclude(
    damping: &mut DampingReport,
    drift: Option<AmbientZeta>,
    zeta0_model: Option<f64>,
    (model_interval, method): (impl Fn(ModelInterval) -> Option<(f64, f64)>, ModelInterval),
    growth_intervals: impl Fn() -> GrowthIntervals,
    regime: Option<crate::spectral::Regime>,
    max_fit_nmae: f64,
) {
    let facts = VerdictFacts {
        fit_nmae: damping.fit_nmae,
        max_fit_nmae,
        agrees: damping.agrees != Some(false),
        zeta0_model,
        ambient: damping.ambient_zeta,
        envelope: damping.envelope_zeta,
        envelope_drift: drift,
        regime,
        growth: WindowGrowth::of(damping),
    };
    let decision = decide(&facts);
    // the report's envelope estimate is the relaxation's, or the drift's where it refused
    damping.envelope_zeta = damping.envelope_zeta.or(drift);
    let model_trusted = facts.model_trusted();
    let model = zeta0_model.map(|z| {
        let interval = (model_trusted || decision.source == Zeta0Source::Model)
            .then(|| model_interval(method))
            .flatten();
        (z, interval)
    });
    damping.model_zeta = match model {
        Some((zeta, Some((low, high)))) if model_trusted => Some(AmbientZeta { zeta, low, high }),
        _ => None,
    };
    let model_free = match decision.source {
        Zeta0Source::Ambient => damping.ambient_zeta,
        Zeta0Source::Envelope => damping.envelope_zeta,
        // never decided per window: the gate's memory combines it afterwards
        Zeta0Source::Amplitude | Zeta0Source::Model | Zeta0Source::PredictionError => None,
    };
    let (zeta0, interval) = match model_free {
        Some(a) => (Some(a.zeta), Some((a.low, a.high))),
        None => (zeta0_model, model.and_then(|m| m.1)),
    };
    damping.zeta0 = zeta0;
    damping.zeta0_interval = interval;
    damping.zeta0_source = zeta0.map(|_| decision.source);
    damping.trusted = decision.trusted;
    damping.verdict = decision.verdict;
    damping.regime = regime;
    let growth = grew_into_cycle(damping).then(&growth_intervals);
    let below_zero = |(zeta, (low, high)): (f64, (f64, f64))| {
        (high < 0.0).then_some(AmbientZeta { zeta, low, high })
    };
    damping.growth_zeta = growth
        .as_ref()
        .and_then(|g| below_zero((zeta0_model?, g.zeta0?)));
    // the law only with the growth itself: a law whose interval reaches zero carries nothing
    damping.growth_law_zeta = growth
        .and_then(|g| below_zero(g.law?))
        .filter(|_| damping.growth_zeta.is_some());
    // Where the window grew into its cycle, the model's interval is the one under the forcing as
    // well: there it is honest, the Newey-West one too narrow (`docs/damping.md`, "The cycle's
    // amplitude").
    if let (Some(g), Some(m)) = (damping.growth_zeta, damping.model_zeta.as_mut()) {
        m.low = m.low.min(g.low);
        m.high = m.high.max(g.high);
        if damping.zeta0_source == Some(Zeta0Source::Model) {
            damping.zeta0_interval = Some((m.low, m.high));
        }
    }
    read_the_models_sign_from_its_interval(damping);
}

/// A model-decided window's verdict says what its interval says, as an ambient one's does:
/// `self_excited` or `damped` only when the interval lies on that side of zero, `unknown`
/// (still trusted: the interval is evidence, "cannot tell") across it. [`decide`] chose the row
/// from the model's point before its interval was computed. Why (session 49): a steady sine
/// read by its model as -0.03 % (-0.11, +0.05) was printed and stored as `self_excited`, the
/// interval saying the opposite. The alerts read the interval, not the verdict, so no alert
/// changes; the printout, the API, the history and its plot do. A window without an interval
/// keeps its row.
pub(super) fn read_the_models_sign_from_its_interval(d: &mut DampingReport) {
    if d.zeta0_source != Some(Zeta0Source::Model) || d.verdict == Verdict::Unknown {
        return;
    }
    if let Some((low, high)) = d.zeta0_interval {
        if low <= 0.0 && 0.0 <= high {
            d.verdict = Verdict::Unknown;
        }
    }
}

/// What a window that grew into its cycle carries, both under the forcing (`conclude`):
/// zeta0's interval, and the damping law `(value, interval)` of `cycle_zeta0` at the model's
/// limit-cycle amplitude.
struct GrowthIntervals {
    zeta0: Option<(f64, f64)>,
    law: Option<(f64, (f64, f64))>,
}

/// The growth window's amplitude at its end over the model's limit-cycle amplitude below which
/// its model is no damping law for the cycle (`growth_zeta`): a window that stayed far below its
/// cycle barely saw the non-linear damping (at 0.7 of the cycle's amplitude the non-linear part
/// is half the linear one).
pub const GROWTH_MIN_REACH: f64 = 0.7;

/// Whether a concluded window may have grown into its cycle: its model trusted and negative, on
/// a growing or limit-cycle regime, its amplitude at the end at least [`GROWTH_MIN_REACH`] of
/// its model's limit cycle (`docs/damping.md`, "The cycle's amplitude"), and the model decides
/// it or the gate's ambient level may give it to the model after this analysis
/// (`ambient_level::model_may_read`). The gate's memory carries it only when the model decides
/// the window in the end (`CycleAmplitude`). A held cycle is decided by its envelope, never by
/// the model, whose reading there is biased: its windows skip the forcing covariance, which
/// made a held cycle's analysis a third slower when every window computed it.
fn grew_into_cycle(d: &DampingReport) -> bool {
    let reached = match (d.amplitude, d.limit_cycle_amplitude) {
        (Some(a), Some(lc)) => lc.is_finite() && lc > 0.0 && a >= GROWTH_MIN_REACH * lc,
        _ => false,
    };
    reached
        && (d.zeta0_source == Some(Zeta0Source::Model) || super::ambient_level::model_may_read(d))
        && d.model_zeta.is_some_and(|m| m.zeta < 0.0)
        && matches!(
            d.regime,
            Some(crate::spectral::Regime::SelfExcited | crate::spectral::Regime::LimitCycle)
        )
}
