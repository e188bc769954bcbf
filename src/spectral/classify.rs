//! The model-free regime of a window (self-excited, limit cycle, damped, undecided) and the
//! options and result of the whole window analysis.

use super::{AmbientDamping, ArOptions, GrowthOptions, GrowthRate, Peak, SsiOptions};

/// Model-free regime of a window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Regime {
    /// The envelope grows significantly, or the ambient damping is significantly negative.
    SelfExcited,
    /// Self-excited and saturated: a nearly constant envelope (CV far below the Rayleigh value of
    /// a noise-driven response) with an ambient damping interval reaching zero or below.
    LimitCycle,
    /// The ambient damping is significantly positive, the envelope neither grows nor looks like a
    /// limit cycle.
    Damped,
    /// None of the above: too little evidence either way.
    Undecided,
}

/// Thresholds of [`classify`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassifyOptions {
    /// The envelope grows significantly when `sigma - k * stderr > min_growth_rate`; this is `k`.
    pub growth_sigmas: f64,
    /// Minimum growth rate to call self-excitation, 1/s (guards against tiny, irrelevant growth).
    pub min_growth_rate: f64,
    /// Damped requires `zeta_low` above this (a small positive margin keeps a limit cycle, whose
    /// damping estimate sits near zero, out of `Damped`).
    pub min_damped_zeta: f64,
    /// A limit cycle has an envelope CV below this (Rayleigh: 0.52).
    pub max_limit_cycle_cv: f64,
    /// ... and an ambient `zeta` (the point estimate) below this: its equivalent damping is
    /// zero, and SSI-COV reads 0.00 to 0.07 % on the simulated limit cycles (default 0.1 %). The point, not the
    /// interval's lower end: SSI's honest intervals on a noise-driven +1 % window often reach
    /// zero, and with the lower end a stable window whose envelope happened to be steady was
    /// taken for a limit cycle (a false alarm in `bench warning`, `stable`, lab gate).
    pub max_limit_cycle_zeta: f64,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        ClassifyOptions {
            growth_sigmas: 3.0,
            min_growth_rate: 0.02,
            min_damped_zeta: 0.001,
            max_limit_cycle_cv: 0.3,
            max_limit_cycle_zeta: 0.001,
        }
    }
}

/// Classifies a window from its envelope growth and (optional) ambient damping, in this order:
/// self-excited if the envelope grows significantly (`sigma - k se > min_growth_rate`) or the
/// whole ambient interval is below zero; limit cycle if the envelope CV is below
/// `max_limit_cycle_cv` and the ambient `zeta` below `max_limit_cycle_zeta` (a noise-driven
/// response near zero damping also has a large, slowly varying envelope, but a Rayleigh-like CV);
/// damped if the ambient interval lies above `min_damped_zeta`; otherwise undecided.
///
/// Limits: growth is only seen while it happens (seconds at `zeta = -1 %`); a window that saw
/// nothing but a steady limit cycle relies on the CV test, which needs several envelope
/// correlation times `1/(|zeta| omega)` in the window and fails near the bifurcation where the
/// limit cycle is small against the noise. The daemon's analysis asks the CV test of a window
/// holding fewer than 100 cycles again over the last 100 cycles of the gate's history
/// (`analysis::LIMIT_CYCLE_CYCLES`): a noise-driven envelope decorrelates over `1 / (2 pi zeta)`
/// cycles, so a window's length in seconds made the test gate-dependent.
pub fn classify(
    growth: &GrowthRate,
    ambient: Option<&AmbientDamping>,
    opts: &ClassifyOptions,
) -> Regime {
    let grows = growth.sigma - opts.growth_sigmas * growth.stderr > opts.min_growth_rate;
    if grows {
        return Regime::SelfExcited;
    }
    match ambient {
        Some(a) if a.zeta_high < 0.0 => Regime::SelfExcited,
        Some(a)
            if growth.envelope_cv < opts.max_limit_cycle_cv
                && a.zeta < opts.max_limit_cycle_zeta =>
        {
            Regime::LimitCycle
        }
        Some(a) if a.zeta_low > opts.min_damped_zeta => Regime::Damped,
        _ => Regime::Undecided,
    }
}

/// Options of [`SpectralAnalyzer::analyze_window`](super::SpectralAnalyzer::analyze_window).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowOptions {
    /// Centred moving-average window, samples (`<= 1`: linear detrending instead).
    pub moving_average: usize,
    /// Lowest frequency considered for the dominant peak, Hz.
    pub min_freq_hz: f64,
    /// Envelope growth options.
    pub growth: GrowthOptions,
    /// How the ambient damping is estimated (the dominant frequency picks the mode).
    pub ambient: AmbientMethod,
    /// Classification thresholds.
    pub classify: ClassifyOptions,
}

impl Default for WindowOptions {
    /// 1 s moving average at 200 Hz (~10 periods of the lab gate), 1 Hz floor.
    fn default() -> Self {
        WindowOptions {
            moving_average: 201,
            min_freq_hz: 1.0,
            growth: GrowthOptions::default(),
            ambient: AmbientMethod::default(),
            classify: ClassifyOptions::default(),
        }
    }
}

/// How [`super::SpectralAnalyzer::analyze_window`] estimates the ambient (noise-driven) damping.
///
/// Why SSI-COV by default: white sensor noise lives only at lag zero of the correlation
/// function, which covariance-driven SSI never uses, while an AR(p) fit treats it as part of the
/// process and reads the damping too high (issue 8: +2 % read as +5.6 %; `docs/benchmarks.md`,
/// "Ambient damping under sensor noise"). Its lengths are in periods of the dominant frequency,
/// so one default serves any gate. SSI also holds when the damping is negative: the correlations
/// of a noise-driven linear system obey `R(k + j) = A^j R(k)` whether it decays or grows, which
/// is all the method uses, provided every lag sums the same reference instants
/// ([`SsiOptions::common_reference`]); with the default lagged sums a window whose variance grows
/// reads too damped (a free growth as `+|zeta|`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AmbientMethod {
    /// Covariance-driven stochastic subspace identification ([`super::ssi_cov_damping`]).
    Ssi(SsiOptions),
    /// AR(p) least squares ([`super::ambient_damping`]), the hint replaced by the dominant
    /// frequency: biased by sensor noise, kept for comparison.
    Ar(ArOptions),
    /// No ambient estimate (the analysis of a model's noise-free prediction, where only the peak
    /// and the growth are compared).
    Skip,
}

impl Default for AmbientMethod {
    fn default() -> Self {
        AmbientMethod::Ssi(SsiOptions::default())
    }
}

/// The model-free analysis of one window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowSpectral {
    /// Dominant spectral peak.
    pub peak: Peak,
    /// Envelope growth.
    pub growth: GrowthRate,
    /// Ambient damping (`None` if the estimate failed or was skipped).
    pub ambient: Option<AmbientDamping>,
    /// With SSI-COV, the reading over common reference instants
    /// ([`SsiOptions::common_reference`]) whatever the options chose for `ambient` (the same
    /// estimate when they chose it): beside the lagged reading it shows a window whose variance
    /// grows (`analysis::read_growing_window`). `None` with another method or when it failed.
    pub ambient_common: Option<AmbientDamping>,
    /// The regime.
    pub regime: Regime,
}
