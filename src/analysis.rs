//! Early-warning analysis of one window: identify the model, then say what its damping means.
//!
//! This is the interface the daemon consumes. [`Analyzer::new`] compiles the model and checks the
//! settings once per gate; [`Analyzer::analyze`] runs on a worker thread for each window.

use crate::data::TimeSeries;
use crate::identify::{self, Identification, InitialValues};
use crate::model::Model;
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
    /// Interval (low, high) for `zeta0`: the AR estimate's 95 % interval when `zeta0` comes
    /// from it, the spread of the runs when several were made, else a linearised 95 % interval
    /// from the polish's Jacobian.
    pub zeta0_interval: Option<(f64, f64)>,
    /// Where `zeta0` comes from: `model` (linearised identified model) or `ambient` (AR fit of a
    /// noise-driven window whose free-vibration model does not fit).
    pub zeta0_source: Option<String>,
    /// Equivalent damping ratio at the amplitude seen in the window.
    pub zeta_eq: Option<f64>,
    /// Net energy fed into the structure per cycle (J in force mode).
    pub energy_per_cycle: Option<f64>,
    /// Amplitude where `zeta_eq` crosses zero, in the signal's unit (force amplitude `K0 * a` in
    /// force mode); `None` when the model grows without bound or is stable at rest.
    pub limit_cycle_amplitude: Option<f64>,
    /// Seconds until the amplitude reaches the configured limit at the current growth.
    pub time_to_limit: Option<f64>,
    /// Dominant frequency of the window, Hz.
    pub frequency_hz: Option<f64>,
    /// Model-free envelope growth rate sigma, 1/s (negative: decaying).
    pub growth_rate: Option<f64>,
    /// Standard error of `growth_rate`.
    pub growth_rate_stderr: Option<f64>,
    /// Model-free damping ratio of a noise-driven window (AR fit) and its 95 % interval.
    pub ambient_zeta: Option<(f64, f64, f64)>,
    /// The model's own frequency at rest, Hz (`sqrt(K0/M0) / 2 pi`).
    pub model_frequency_hz: Option<f64>,
    /// Displacement amplitude at the end of the window (model), m or the data's unit.
    pub amplitude: Option<f64>,
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

// ---------------------------------------------------------------------------------------------
// Linearisation and energy balance
// ---------------------------------------------------------------------------------------------

/// The model linearised at rest: `M0*ydd + C0*yd + K0*y` (derivatives of `R` at `y = yd = 0`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Linearization {
    /// `M(t0, 0, 0)`.
    pub m0: f64,
    /// `dR/dyd` at rest.
    pub c0: f64,
    /// `dR/dy` at rest.
    pub k0: f64,
}

impl Linearization {
    /// Central differences of the compiled model at `(t0, 0, 0)`, with steps relative to the
    /// displacement and velocity scales of the problem.
    pub fn of(model: &Model, c: &[f64], t0: f64, y_scale: f64, v_scale: f64) -> Linearization {
        let (hy, hv) = (
            1e-6 * y_scale.abs().max(1e-300),
            1e-6 * v_scale.abs().max(1e-300),
        );
        let r = |y: f64, yd: f64| model.residual(t0, y, yd, c);
        Linearization {
            m0: model.mass(t0, 0.0, 0.0, c),
            c0: (r(0.0, hv) - r(0.0, -hv)) / (2.0 * hv),
            k0: (r(hy, 0.0) - r(-hy, 0.0)) / (2.0 * hy),
        }
    }

    /// Undamped natural angular frequency `sqrt(K0/M0)`, when `K0/M0 > 0`.
    pub fn omega0(&self) -> Option<f64> {
        let w2 = self.k0 / self.m0;
        (w2 > 0.0 && w2.is_finite()).then(|| w2.sqrt())
    }

    /// Damping ratio at rest `C0 / (2 sqrt(K0 M0))` (signs normalised by `M0`), when the rest
    /// position is an oscillator (`K0/M0 > 0`).
    pub fn zeta0(&self) -> Option<f64> {
        let w = self.omega0()?;
        let z = (self.c0 / self.m0) / (2.0 * w);
        z.is_finite().then_some(z)
    }
}

/// Equivalent damping at displacement amplitude `a`: the energy the velocity-odd part of `R`
/// dissipates over one harmonic cycle `y = a cos(theta)`, `yd = -a w sin(theta)` at the
/// linearised frequency, expressed as a viscous damping ratio (first-order averaging, as in
/// Krylov-Bogoliubov). Returns `(zeta_eq, energy fed in per cycle)`.
pub fn equivalent_damping(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    a: f64,
    t0: f64,
) -> Option<(f64, f64)> {
    let w = lin.omega0()?;
    const N: usize = 256;
    let mut work = 0.0;
    for k in 0..N {
        let th = 2.0 * std::f64::consts::PI * k as f64 / N as f64;
        let (y, yd) = (a * th.cos(), -a * w * th.sin());
        let odd = 0.5 * (model.residual(t0, y, yd, c) - model.residual(t0, y, -yd, c));
        // dt = dtheta / w, so the integral of odd * yd dt is sum(odd * yd) * (2 pi / N) / w.
        work += odd * yd;
    }
    let dissipated = work * 2.0 * std::f64::consts::PI / N as f64 / w;
    let c_eq = dissipated / (std::f64::consts::PI * w * a * a);
    let zeta_eq = (c_eq / lin.m0) / (2.0 * w);
    (zeta_eq.is_finite() && dissipated.is_finite()).then_some((zeta_eq, -dissipated))
}

/// The smallest displacement amplitude above `from / 1000` where `zeta_eq` turns from negative to
/// non-negative (a stable limit cycle), searched up to `1000 * from`.
pub fn limit_cycle(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    from: f64,
    t0: f64,
) -> Option<f64> {
    let z = |a: f64| equivalent_damping(model, c, lin, a, t0).map(|(z, _)| z);
    let (lo, hi) = (from * 1e-3, from * 1e3);
    const STEPS: usize = 120;
    let mut prev = (lo, z(lo)?);
    for k in 1..=STEPS {
        let a = lo * (hi / lo).powf(k as f64 / STEPS as f64);
        let za = z(a)?;
        if prev.1 < 0.0 && za >= 0.0 {
            let (mut l, mut h) = (prev.0, a);
            for _ in 0..60 {
                let m = (l * h).sqrt();
                if z(m)? < 0.0 {
                    l = m;
                } else {
                    h = m;
                }
            }
            return Some((l * h).sqrt());
        }
        prev = (a, za);
    }
    None
}

/// Time for the amplitude to grow from `now` to `limit` by the averaged amplitude equation
/// `da/dt = -zeta_eq(a) w a`; `Some(0)` when already there, `None` when it never gets there
/// (damped somewhere on the way).
pub fn time_to_amplitude(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    now: f64,
    limit: f64,
    t0: f64,
) -> Option<f64> {
    if now >= limit {
        return Some(0.0);
    }
    let w = lin.omega0()?;
    const STEPS: usize = 200;
    let step = (limit / now).ln() / STEPS as f64;
    let mut t = 0.0;
    for k in 0..STEPS {
        let a = now * ((k as f64 + 0.5) * step).exp();
        let (z, _) = equivalent_damping(model, c, lin, a, t0)?;
        if z >= 0.0 {
            return None;
        }
        t += step / (-z * w);
    }
    Some(t)
}

// ---------------------------------------------------------------------------------------------
// FFT-biased initial population (section 8.4.4, generalised)
// ---------------------------------------------------------------------------------------------

/// What the spectrum says about the linearisation: `K0/M0 = omega^2` and, when the envelope
/// growth is clean, `C0/M0 = -2 sigma`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpectralTarget {
    /// Measured angular frequency, rad/s.
    pub omega: f64,
    /// Measured envelope growth rate, 1/s, if trustworthy.
    pub sigma: Option<f64>,
}

/// `n` individuals (DE coordinates: coefficient `j` is `x[j] * scales[j]`) drawn uniformly from
/// `[-1, 1]` and then moved by a few damped Gauss-Newton steps, minimum-norm, onto the set of
/// coefficients whose linearisation matches `target` (the chapter's "line of possible values",
/// for any model structure). Individuals the projection cannot fix are returned unmoved.
#[allow(clippy::too_many_arguments)]
pub fn biased_population(
    model: &Model,
    scales: &[f64],
    target: SpectralTarget,
    n: usize,
    seed: u64,
    t0: f64,
    y_scale: f64,
    v_scale: f64,
) -> Vec<Vec<f64>> {
    use rand::{RngExt, SeedableRng};
    let d = model.n_coeffs();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x000f_b1a5);
    let w = target.omega;
    // Written as M0 w^2 - K0 and C0 + 2 sigma M0 rather than ratios: linear in the coefficients
    // of every model whose M0, C0 and K0 are, so that the minimum-norm step lands on the set in
    // one iteration (a ratio's 1/M0 makes Gauss-Newton overshoot from random starts).
    let residuals = |x: &[f64]| -> Option<([f64; 2], f64)> {
        let c: Vec<f64> = x.iter().zip(scales).map(|(x, s)| x * s).collect();
        let lin = Linearization::of(model, &c, t0, y_scale, v_scale);
        let r1 = lin.m0 * w * w - lin.k0;
        let r2 = match target.sigma {
            Some(sigma) => (lin.c0 + 2.0 * sigma * lin.m0) * w,
            None => 0.0,
        };
        let size = lin.m0.abs() * w * w + lin.k0.abs();
        (r1.is_finite() && r2.is_finite()).then_some(([r1, r2], size))
    };
    (0..n)
        .map(|_| {
            let mut x: Vec<f64> = (0..d).map(|_| rng.random_range(-1.0..=1.0)).collect();
            for _ in 0..8 {
                let Some((r, size)) = residuals(&x) else {
                    break;
                };
                if r[0].abs() <= 1e-9 * size && r[1].abs() <= 1e-9 * size {
                    break;
                }
                // J (2 x d) by forward differences, then dx = -J^T (J J^T + mu I)^-1 r.
                let mut jac = vec![[0.0; 2]; d];
                let mut ok = true;
                for j in 0..d {
                    let h = 1e-6 * x[j].abs().max(1e-3);
                    let mut xp = x.clone();
                    xp[j] += h;
                    match residuals(&xp) {
                        Some((rp, _)) => jac[j] = [(rp[0] - r[0]) / h, (rp[1] - r[1]) / h],
                        None => ok = false,
                    }
                }
                if !ok {
                    break;
                }
                // J J^T, regularised relative to its size (one constraint may be absent: r2 = 0).
                let mut a = [[0.0; 2]; 2];
                for col in &jac {
                    for p in 0..2 {
                        for q in 0..2 {
                            a[p][q] += col[p] * col[q];
                        }
                    }
                }
                let eps = 1e-12 * (a[0][0] + a[1][1]) + f64::MIN_POSITIVE;
                a[0][0] += eps;
                a[1][1] += eps;
                let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
                if !(det.abs() > 0.0 && det.is_finite()) {
                    break;
                }
                let lam = [
                    (a[1][1] * r[0] - a[0][1] * r[1]) / det,
                    (a[0][0] * r[1] - a[1][0] * r[0]) / det,
                ];
                for (xj, col) in x.iter_mut().zip(&jac) {
                    *xj -= col[0] * lam[0] + col[1] * lam[1];
                }
            }
            x
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// The analysis of a series: pre-processing, pre-run, identification, damping report
// ---------------------------------------------------------------------------------------------

/// Options of [`analyze_series`].
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesOptions {
    /// What the samples are.
    pub signal: Signal,
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
}

impl Default for SeriesOptions {
    fn default() -> Self {
        SeriesOptions {
            signal: Signal::Displacement,
            stiffness: None,
            identify: identify::Config::default(),
            fft_bias: true,
            moving_average_seconds: 1.0,
            amplitude_limit: None,
            max_fit_nmae: 0.2,
        }
    }
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
    /// The model's output at every sample (displacement or support force).
    pub prediction: Option<Vec<f64>>,
    /// The model's state `[y, yd]` at every sample.
    pub trajectory: Option<Vec<[f64; 2]>>,
    /// The linearisation at rest.
    pub linearization: Linearization,
}

fn rms(x: &[f64]) -> f64 {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt()
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

/// Fraction of the measured force that one DE unit of a damping-like coefficient represents.
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
    analyze_series_with(model, series, opts, warm, &mut None, progress)
}

/// [`analyze_series`] with a reusable spectral analyzer: `spectral` is used when it fits the
/// series' length and rate, and replaced by a new one (FFT plans and buffers) otherwise, so a
/// caller that analyses windows of one length plans its FFTs once.
pub fn analyze_series_with(
    model: &Model,
    series: &TimeSeries,
    opts: &SeriesOptions,
    warm: Option<&[f64]>,
    spectral: &mut Option<crate::spectral::SpectralAnalyzer>,
    progress: impl FnMut(usize, usize, f64),
) -> Result<SeriesAnalysis, AnalysisError> {
    use crate::spectral::{SpectralAnalyzer, WindowOptions};
    let n = series.len();
    if n < 2 {
        return Err(AnalysisError::Window(format!("{n} samples are too few")));
    }
    let fs = series.uniform_step().map(|h| 1.0 / h);
    let t0 = series.t[0];
    let duration = series.t[n - 1] - t0;

    // Pre-processing: force signals lose their moving average (drift).
    let mut data = series.clone();
    if opts.signal == Signal::Force && opts.moving_average_seconds > 0.0 {
        if let Some(fs) = fs {
            let w = ((opts.moving_average_seconds * fs).round() as usize) | 1;
            if w > 1 && w < n {
                crate::spectral::remove_moving_average(&series.y, w, &mut data.y);
            }
        }
    }

    // Model-free analysis (uniform sampling only).
    let window_options = WindowOptions {
        moving_average: 0,
        min_freq_hz: 3.0 / duration.max(f64::MIN_POSITIVE),
        ..WindowOptions::default()
    };
    let fits = |sa: &SpectralAnalyzer| {
        fs.is_some_and(|fs| sa.len() == n && (sa.rate_hz() - fs).abs() <= 1e-9 * fs)
    };
    if !spectral.as_ref().is_some_and(fits) {
        *spectral = fs.and_then(|fs| SpectralAnalyzer::new(n, fs).ok());
    }
    let spec = spectral
        .as_mut()
        .and_then(|sa| sa.analyze_window(&data.y, &window_options).ok());
    // A short record (a few periods) cannot give an envelope growth, but its dominant frequency
    // still constrains the search.
    let peak_hz = spec.as_ref().map(|s| s.peak.frequency_hz).or_else(|| {
        let mut detrended = data.y.clone();
        crate::spectral::detrend_linear(&mut detrended);
        spectral
            .as_mut()
            .and_then(|sa| {
                sa.dominant_frequency(&detrended, window_options.min_freq_hz)
                    .ok()
            })
            .map(|p| p.frequency_hz)
    });
    let omega_meas = peak_hz.map(|f| 2.0 * std::f64::consts::PI * f);
    // The growth constrains the linearisation only when the envelope is a clean exponential.
    let sigma_clean = spec.as_ref().and_then(|s| {
        let g = &s.growth;
        (g.stderr < 0.1 * g.sigma.abs() + 1e-9).then_some(g.sigma)
    });

    let mut config = opts.identify.clone();
    let (y_scale, v_scale) = match opts.signal {
        Signal::Force => {
            let k = opts
                .stiffness
                .filter(|k| k.is_finite() && *k > 0.0)
                .ok_or_else(|| {
                    AnalysisError::Settings(
                        "force signals need the installed stiffness (> 0)".into(),
                    )
                })?;
            let w = omega_meas.ok_or_else(|| {
                AnalysisError::Window("no dominant frequency in the window".into())
            })?;
            let sigma = spec.as_ref().map_or(0.0, |s| s.growth.sigma);
            let (y0, v0) = pre_run(&data, w, sigma, k).ok_or_else(|| {
                AnalysisError::Window("the pre-run for the initial conditions failed".into())
            })?;
            let f_rms = rms(&data.y);
            if f_rms.is_nan() || f_rms <= 0.0 {
                return Err(AnalysisError::Window("the signal is constant".into()));
            }
            let y_scale = std::f64::consts::SQRT_2 * f_rms / k;
            config.initial = identify::Initial::Known { y0, v0 };
            config.output = identify::Output::Force;
            config.scales = term_scales(model, t0, y_scale, w, f_rms);
            config.y_scale = Some(y_scale);
            config.polish_initial = Some((y_scale, y_scale * w));
            (y_scale, y_scale * w)
        }
        Signal::Displacement => {
            let y_scale = data
                .y
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
                .max(f64::MIN_POSITIVE);
            (y_scale, y_scale * omega_meas.unwrap_or(1.0))
        }
    };
    let scales = if config.scales.len() == model.n_coeffs() {
        config.scales.clone()
    } else {
        vec![1.0; model.n_coeffs()]
    };
    let fit_ic = matches!(config.initial, identify::Initial::Fit);

    // Initial population: warm start, then the FFT-biased half.
    let mut initial_population: Vec<Vec<f64>> = Vec::new();
    if let Some(c) = warm.filter(|c| c.len() == model.n_coeffs() && c.iter().all(|v| v.is_finite()))
    {
        let mut x: Vec<f64> = c.iter().zip(&scales).map(|(c, s)| c / s).collect();
        if fit_ic {
            x.extend_from_slice(&[0.0, 0.0]);
        }
        initial_population.push(x);
    }
    // The bias assumes the window's dominant frequency is the natural one, which holds for free
    // and self-excited vibration but not for a forced or parametrically excited model (one that
    // depends on t): there it would pull the search to the forcing frequency.
    if opts.fft_bias && !model.uses_time() {
        if let Some(w) = omega_meas {
            let target = SpectralTarget {
                omega: w,
                sigma: sigma_clean,
            };
            let half = config.search.population / 2;
            let mut rng_ic = config.protocol.seed;
            for mut x in biased_population(
                model,
                &scales,
                target,
                half,
                config.protocol.seed,
                t0,
                y_scale,
                v_scale,
            ) {
                if fit_ic {
                    // Fitted initial conditions keep uniform random starts.
                    rng_ic = rng_ic
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let u = |r: u64| (r >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                    x.extend_from_slice(&[u(rng_ic), u(rng_ic.rotate_left(29))]);
                }
                initial_population.push(x);
            }
        }
    }
    config.search.initial_population = initial_population;

    let identification =
        identify::identify(model, &data, &config, progress).map_err(|e| match e {
            identify::IdentifyError::De(e) => AnalysisError::Settings(e.to_string()),
            other => AnalysisError::Settings(other.to_string()),
        })?;
    let best = identification.best_run().clone();
    let c = best.coefficients.clone();
    let lin = Linearization::of(model, &c, t0, y_scale, v_scale);
    let trajectory =
        identify::trajectory(model, &data.t, &c, best.initial, config.protocol.test_rtol);
    let prediction = identify::predict(
        model,
        &data,
        &c,
        best.initial,
        config.protocol.test_rtol,
        config.output,
    );
    let fit_nmae = prediction
        .as_ref()
        .and_then(|p| identify::nmae(p.iter().copied().zip(data.y.iter().copied())))
        .unwrap_or(f64::INFINITY);

    // Amplitude now: the model's largest |y| over its last period.
    let amplitude = trajectory.as_ref().and_then(|tr| {
        let period = 2.0 * std::f64::consts::PI / lin.omega0().or(omega_meas)?;
        let t_end = data.t[n - 1];
        let a = tr
            .iter()
            .zip(&data.t)
            .filter(|(_, &t)| t >= t_end - period)
            .fold(0.0f64, |m, (s, _)| m.max(s[0].abs()));
        (a > 0.0).then_some(a)
    });
    let eq = amplitude.and_then(|a| equivalent_damping(model, &c, &lin, a, t0));
    // Signal units: displacement, or force K0 * a.
    let to_signal = |a: f64| {
        if opts.signal == Signal::Force {
            lin.k0.abs() * a
        } else {
            a
        }
    };
    let from_signal = |s: f64| {
        if opts.signal == Signal::Force {
            s / lin.k0.abs()
        } else {
            s
        }
    };
    let zeta0_model = lin.zeta0();
    let limit_cycle_amplitude = match (zeta0_model, amplitude) {
        (Some(z), Some(a)) if z < 0.0 => limit_cycle(model, &c, &lin, a, t0).map(to_signal),
        _ => None,
    };
    let time_to_limit = match (opts.amplitude_limit, amplitude) {
        (Some(limit), Some(a)) if limit > 0.0 => {
            time_to_amplitude(model, &c, &lin, a, from_signal(limit), t0)
        }
        _ => None,
    };

    // Agreement with the model-free estimates: the same spectral analysis of the prediction.
    let model_spec = match (spectral.as_mut(), prediction.as_ref()) {
        (Some(sa), Some(p)) => sa.analyze_window(p, &window_options).ok(),
        _ => None,
    };
    let agrees = match (&spec, &model_spec) {
        (Some(d), Some(m)) => {
            let f_ok = (m.peak.frequency_hz / d.peak.frequency_hz - 1.0).abs() < 0.03;
            let w = 2.0 * std::f64::consts::PI * d.peak.frequency_hz;
            let tol = 3.0 * (d.growth.stderr + m.growth.stderr) + 0.005 * w;
            f_ok && (m.growth.sigma - d.growth.sigma).abs() <= tol
        }
        // Without uniform sampling there is nothing to compare with: judge by the fit alone.
        _ => spec.is_none(),
    };

    let ambient = spec
        .as_ref()
        .and_then(|s| s.ambient)
        .map(|a| (a.zeta, a.zeta_low, a.zeta_high));
    let runs_zeta: Vec<f64> = identification
        .runs
        .iter()
        .filter_map(|r| Linearization::of(model, &r.coefficients, t0, y_scale, v_scale).zeta0())
        .collect();
    let model_interval = (runs_zeta.len() > 1).then(|| {
        let lo = runs_zeta.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = runs_zeta.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    });
    let fits = fit_nmae <= opts.max_fit_nmae;
    let regime_self_excited = spec
        .as_ref()
        .is_some_and(|s| matches!(s.regime, crate::spectral::Regime::SelfExcited));
    let (zeta0, zeta0_interval, source, trusted, verdict) = match (zeta0_model, ambient) {
        (Some(z), _) if fits && agrees => (
            Some(z),
            model_interval,
            "model",
            true,
            if z < 0.0 {
                Verdict::SelfExcited
            } else {
                Verdict::Damped
            },
        ),
        (_, Some((z, lo, hi))) if lo > 0.0 && !regime_self_excited => {
            (Some(z), Some((lo, hi)), "ambient", true, Verdict::Damped)
        }
        (z, _) => (z, model_interval, "model", false, Verdict::Unknown),
    };
    let damping = DampingReport {
        zeta0,
        zeta0_interval,
        zeta0_source: zeta0.map(|_| source.to_string()),
        zeta_eq: eq.map(|e| e.0),
        energy_per_cycle: eq.map(|e| e.1),
        limit_cycle_amplitude,
        time_to_limit,
        frequency_hz: spec.as_ref().map(|s| s.peak.frequency_hz),
        growth_rate: spec.as_ref().map(|s| s.growth.sigma),
        growth_rate_stderr: spec.as_ref().map(|s| s.growth.stderr),
        ambient_zeta: ambient,
        model_frequency_hz: lin.omega0().map(|w| w / (2.0 * std::f64::consts::PI)),
        amplitude: amplitude.map(to_signal),
        agrees,
        fit_nmae,
        trusted,
        verdict,
    };
    Ok(SeriesAnalysis {
        identification,
        coefficients: c,
        initial: best.initial,
        damping,
        data,
        prediction,
        trajectory,
        linearization: lin,
    })
}

// ---------------------------------------------------------------------------------------------
// The daemon's per-window analyzer
// ---------------------------------------------------------------------------------------------

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
        })
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
        self.analyze_with(input, warm, seed, true)
    }

    /// [`Analyzer::analyze`] without the FFT-biased initial population (for the benchmark that
    /// shows what the bias buys).
    pub fn analyze_unbiased(
        &self,
        input: WindowInput<'_>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        self.analyze_with(input, None, seed, false)
    }

    fn analyze_with(
        &self,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
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
        let opts = SeriesOptions {
            signal: s.signal,
            stiffness: s.stiffness,
            identify: identify::Config {
                search: identify::Search {
                    population: s.population,
                    generations: s.generations,
                    // One RK4 step per sample: three times cheaper than dopri5 over a long
                    // window; the polish (dopri5 at 1e-8) sets the final accuracy.
                    solver: crate::ode::Method::Rk4,
                    substeps: 1,
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
            ..SeriesOptions::default()
        };
        // Borrow a spectral analyzer (the lock is held only to pop and push, never during the
        // analysis; a poisoned pool just means planning afresh).
        let mut spectral = self.spectral_pool.lock().ok().and_then(|mut p| p.pop());
        let result = analyze_series_with(
            &self.model,
            &series,
            &opts,
            warm,
            &mut spectral,
            |_, _, _| {},
        );
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
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn gate_model() -> Model {
        Model::parse(
            "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
            &[("k".to_string(), 81360.0)],
        )
        .unwrap()
    }

    #[test]
    fn linearization_of_the_gate_model() {
        let m = gate_model();
        let lin = Linearization::of(&m, &[19.14, -12.18, 447.3], 0.0, 1e-3, 0.065);
        assert_relative_eq!(lin.m0, 19.14, max_relative = 1e-12);
        assert_relative_eq!(lin.c0, -12.18, max_relative = 1e-6);
        assert_relative_eq!(lin.k0, 81360.0, max_relative = 1e-6);
        let zeta = -12.18 / (2.0 * (81360.0f64 * 19.14).sqrt());
        assert_relative_eq!(lin.zeta0().unwrap(), zeta, max_relative = 1e-6);
        // A rest position without restoring force has no damping ratio.
        let flat = Linearization {
            m0: 1.0,
            c0: 0.1,
            k0: -1.0,
        };
        assert_eq!(flat.zeta0(), None);
    }

    #[test]
    fn equivalent_damping_of_cubic_damping_matches_harmonic_balance() {
        // c_eq(a) = c1 + (3/4) c3 (a w)^2 for (c1 + c3 yd^2) yd.
        let m = gate_model();
        let c = [19.14, -12.18, 447.3];
        let lin = Linearization::of(&m, &c, 0.0, 1e-3, 0.065);
        let w = lin.omega0().unwrap();
        for a in [1e-4, 1e-3, 3e-3] {
            let (z, energy) = equivalent_damping(&m, &c, &lin, a, 0.0).unwrap();
            let c_eq = -12.18 + 0.75 * 447.3 * (a * w).powi(2);
            assert_relative_eq!(z, c_eq / (2.0 * 19.14 * w), max_relative = 1e-6);
            // Energy fed in per cycle: -pi c_eq w a^2.
            assert_relative_eq!(
                energy,
                -std::f64::consts::PI * c_eq * w * a * a,
                max_relative = 1e-6
            );
        }
        let a_lc = limit_cycle(&m, &c, &lin, 1e-3, 0.0).unwrap();
        let expected = (4.0f64 * 12.18 / (3.0 * 447.3)).sqrt() / w;
        assert_relative_eq!(a_lc, expected, max_relative = 1e-6);
        // Below the limit cycle the amplitude grows towards it but never reaches a limit above it.
        assert_eq!(
            time_to_amplitude(&m, &c, &lin, 1e-3, 2.0 * expected, 0.0),
            None
        );
        // Without the cubic term it grows exponentially: t = ln(limit/now) / sigma.
        let linear = [19.14, -12.18, 0.0];
        let t = time_to_amplitude(&m, &linear, &lin, 1e-3, 1e-2, 0.0).unwrap();
        let sigma = 12.18 / (2.0 * 19.14);
        assert_relative_eq!(t, 10f64.ln() / sigma, max_relative = 1e-3);
        assert_eq!(limit_cycle(&m, &linear, &lin, 1e-3, 0.0), None);
    }

    #[test]
    fn biased_population_satisfies_the_spectral_constraints() {
        let m = gate_model();
        let scales = [19.0, 40.0, 1000.0];
        let w = 2.0 * std::f64::consts::PI * 10.38;
        let target = SpectralTarget {
            omega: w,
            sigma: Some(0.3),
        };
        let pop = biased_population(&m, &scales, target, 20, 7, 0.0, 1e-3, 0.065);
        assert_eq!(pop.len(), 20);
        for x in &pop {
            let c: Vec<f64> = x.iter().zip(&scales).map(|(x, s)| x * s).collect();
            let lin = Linearization::of(&m, &c, 0.0, 1e-3, 0.065);
            assert_relative_eq!(lin.k0 / lin.m0, w * w, max_relative = 1e-6);
            assert_relative_eq!(lin.c0 / lin.m0, -0.6, epsilon = 1e-6);
        }
        // The coordinates the constraints leave free stay spread out.
        let c3: Vec<f64> = pop.iter().map(|x| x[2]).collect();
        let spread = c3.iter().cloned().fold(f64::MIN, f64::max)
            - c3.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 0.5, "{c3:?}");
    }
}
