//! The damping report of a window and its parts (definitions in `docs/damping.md`).

use serde::{Deserialize, Serialize};

/// Where a report's `zeta0` comes from. Serialised as `"model"`, `"ambient"`, `"envelope"`,
/// `"amplitude"` or `"prediction_error"`, the strings of the API and the CLI's JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Zeta0Source {
    /// The linearised identified model (for information only when the report is untrusted).
    Model,
    /// The ambient (SSI-COV) estimate of a window that does not grow (`docs/damping.md`).
    Ambient,
    /// The relaxation of the envelope's perturbations on a limit cycle
    /// ([`crate::spectral::envelope_relaxation`]).
    Envelope,
    /// The limit cycle's amplitude through the damping law of the gate's last growth, combined
    /// with the envelope's reading (`analysis::CycleAmplitude`, `docs/damping.md`, "The cycle's
    /// amplitude").
    Amplitude,
    /// The prediction-error method on a window that left the gate's ambient level and is no held
    /// cycle (`analysis::prediction_error_zeta`, `docs/damping.md`, "A departed window read by
    /// its prediction errors").
    PredictionError,
}

impl Zeta0Source {
    /// The name used in the JSON and the text report.
    pub fn as_str(self) -> &'static str {
        match self {
            Zeta0Source::Model => "model",
            Zeta0Source::Ambient => "ambient",
            Zeta0Source::Envelope => "envelope",
            Zeta0Source::Amplitude => "amplitude",
            Zeta0Source::PredictionError => "prediction_error",
        }
    }
}

impl std::fmt::Display for Zeta0Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The model-free damping ratio of a noise-driven window (SSI-COV, or AR when so configured) with its 95 % interval.
/// Serialised as the array `[zeta, low, high]`, as the API has always shown it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "(f64, f64, f64)", into = "(f64, f64, f64)")]
pub struct AmbientZeta {
    /// Damping ratio of the dominant pole pair.
    pub zeta: f64,
    /// Lower end of the 95 % interval.
    pub low: f64,
    /// Upper end of the 95 % interval.
    pub high: f64,
}

impl From<(f64, f64, f64)> for AmbientZeta {
    fn from((zeta, low, high): (f64, f64, f64)) -> Self {
        AmbientZeta { zeta, low, high }
    }
}

impl From<AmbientZeta> for (f64, f64, f64) {
    fn from(a: AmbientZeta) -> Self {
        (a.zeta, a.low, a.high)
    }
}

impl From<&crate::spectral::EnvelopeRelaxation> for AmbientZeta {
    fn from(e: &crate::spectral::EnvelopeRelaxation) -> Self {
        AmbientZeta {
            zeta: e.zeta0,
            low: e.zeta0_interval.0,
            high: e.zeta0_interval.1,
        }
    }
}

impl From<&crate::spectral::EnvelopeDrift> for AmbientZeta {
    fn from(e: &crate::spectral::EnvelopeDrift) -> Self {
        AmbientZeta {
            zeta: e.zeta0,
            low: e.zeta0_interval.0,
            high: e.zeta0_interval.1,
        }
    }
}

impl From<&crate::spectral::PooledEstimate> for AmbientZeta {
    fn from(p: &crate::spectral::PooledEstimate) -> Self {
        AmbientZeta {
            zeta: p.zeta,
            low: p.interval.0,
            high: p.interval.1,
        }
    }
}

impl From<&crate::spectral::AmbientDamping> for AmbientZeta {
    fn from(a: &crate::spectral::AmbientDamping) -> Self {
        AmbientZeta {
            zeta: a.zeta,
            low: a.zeta_low,
            high: a.zeta_high,
        }
    }
}

/// Damping figures of an identified model (definitions in `docs/damping.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DampingReport {
    /// Damping ratio at rest from the linearisation, `C0 / (2 sqrt(K0 M0))`.
    pub zeta0: Option<f64>,
    /// Interval (low, high) for `zeta0`: the 95 % interval of the AR or envelope estimate when
    /// `zeta0` comes from it, the spread of the runs when several were made, else `None` (as
    /// `docs/damping.md` says).
    pub zeta0_interval: Option<(f64, f64)>,
    /// Where `zeta0` comes from (`None` when there is no `zeta0`).
    pub zeta0_source: Option<Zeta0Source>,
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
    /// Model-free damping ratio of a noise-driven window (SSI-COV) before pooling and its 95 % interval.
    pub ambient_zeta: Option<AmbientZeta>,
    /// The same window's SSI-COV reading over common reference instants (`ambient_zeta` is the
    /// lagged one unless `ssi_reference = "common"`), with its 95 % interval: where it lies
    /// well below the lagged one, the window's variance grows ([`DampingReport::ssi_growing`]).
    #[serde(default)]
    pub ambient_common_zeta: Option<AmbientZeta>,
    /// `zeta0` of a limit-cycle window from the relaxation of its envelope, or from its drift
    /// where the relaxation refused the window (not on a saturated cycle), with its 95 %
    /// interval (`[zeta, low, high]`; `docs/damping.md`, "The limit cycle").
    #[serde(default)]
    pub envelope_zeta: Option<AmbientZeta>,
    /// Seconds of record `envelope_zeta` read, first sample to last: up to the last 100 cycles
    /// of the gate's history, back to where the cycle's level moved (`docs/damping.md`, "On a
    /// slow gate, 100 cycles of history"), or the window's; `None` without an envelope
    /// estimate. What the pool counts as the record consecutive estimates share.
    #[serde(default)]
    pub envelope_record_seconds: Option<f64>,
    /// `zeta0` of a limit-cycle window from its envelope's drift over the window alone, with its
    /// 95 % interval, where the relaxation refused the window or the window's envelope fell
    /// (`growth_rate` more than two standard errors below zero: a shrinking cycle, not a
    /// saturated one); `None` elsewhere. On a falling cycle read by the relaxation, where no
    /// held cycle reads it (`amplitude_zeta`), `zeta0`'s interval spans this one too
    /// (`analysis::span_the_fall`; `docs/damping.md`, "A falling cycle's interval spans its
    /// drift").
    #[serde(default)]
    pub envelope_drift_zeta: Option<AmbientZeta>,
    /// The SSI-COV reading of the window together with its history, the last 100 cycles back to
    /// where the response's level moved, with its 95 % interval; `None` where the window itself
    /// holds 100 cycles or the history adds nothing (`docs/damping.md`, "One ambient reading of
    /// 100 cycles"). What the ambient pool reads for a window that did not rise.
    #[serde(default)]
    pub ambient_record_zeta: Option<AmbientZeta>,
    /// Seconds of record `ambient_record_zeta` read, first sample to last.
    #[serde(default)]
    pub ambient_record_seconds: Option<f64>,
    /// The trusted model's `zeta0` with its 95 % interval (`[zeta, low, high]`), whatever the
    /// window's source; `None` when the model is not trusted or its interval is undetermined.
    /// What the gate's memory needs to let the model decide a window that left the ambient
    /// level (`docs/damping.md`, "The gate's ambient level").
    #[serde(default)]
    pub model_zeta: Option<AmbientZeta>,
    /// `zeta0` of a limit-cycle window from the cycle's amplitude and the damping law of the
    /// gate's last growth (`[zeta, low, high]`), before its combination with the envelope's;
    /// `None` without a growth in the last half hour (`docs/damping.md`, "The cycle's
    /// amplitude"). On a cycle whose envelope fell, the reading through the law of the cycle the
    /// gate held before (its envelope's fall and its amplitude; then also `zeta0`,
    /// `docs/damping.md`, "A falling cycle read through the cycle it held").
    #[serde(default)]
    pub amplitude_zeta: Option<AmbientZeta>,
    /// On a window that grew into its limit cycle and whose model decided it: the model's
    /// `zeta0` with its 95 % interval under the turbulent forcing
    /// (`identify::covariance_under_forcing`, whatever `model_interval` says), the damping law
    /// the gate carries to the cycle with `limit_cycle_amplitude` (`docs/damping.md`, "The
    /// cycle's amplitude"); `None` elsewhere, and when that interval reaches zero.
    #[serde(default)]
    pub growth_zeta: Option<AmbientZeta>,
    /// The prediction-error method's `zeta0` with its 95 % interval, read where the window stood
    /// at least half the departure ratio above the gate's ambient level when it was dispatched
    /// and is no held cycle (`analysis::read_by_prediction_errors`); `None` elsewhere. The gate's
    /// memory reports it for a window that left the level (`docs/damping.md`, "A departed
    /// window read by its prediction errors"), and a rising window's `zeta0_interval` spans it
    /// ("A rising window's interval spans its prediction errors").
    #[serde(default)]
    pub prediction_error_zeta: Option<AmbientZeta>,
    /// On the same window: the damping law the gate carries to the cycle after it, as the zeta0
    /// that makes the model's limit-cycle amplitude a cycle of its non-linear damping
    /// (`linearisation::cycle_zeta0`; at the optimum the model's `zeta0`), with that function's
    /// 95 % interval under the forcing: the non-linear term's uncertainty is in it, which
    /// `growth_zeta`'s leaves out. `None` where `growth_zeta` is, and when this interval reaches
    /// zero (`docs/damping.md`, "The cycle's amplitude").
    #[serde(default)]
    pub growth_law_zeta: Option<AmbientZeta>,
    /// The model's equivalent damping ratio over the amplitudes the window visited: points
    /// `(amplitude in the signal's unit, zeta_eq)`, amplitude increasing; empty without a model
    /// oscillator at rest.
    #[serde(default)]
    pub zeta_eq_curve: Vec<(f64, f64)>,
    /// The model's own frequency at rest, Hz (`sqrt(K0/M0) / 2 pi`).
    pub model_frequency_hz: Option<f64>,
    /// Natural frequency of the pole behind `ambient_zeta` (SSI-COV's), Hz: far more precise
    /// than `frequency_hz`, the window's spectral peak, whose bin is `1 / window` wide (5 % of a
    /// 2 Hz gate's frequency in a 10 s window). The ambient pool tests "the same mode" on it.
    #[serde(default)]
    pub ambient_frequency_hz: Option<f64>,
    /// Displacement amplitude at the end of the window (model), m or the data's unit.
    pub amplitude: Option<f64>,
    /// Whether the model's frequency and growth agree with the model-free estimates; `None`
    /// (`null`) when the window has no spectrum to compare with (too short, or not uniformly
    /// sampled: no `frequency_hz`), where the fit alone judges. Why not `true` there: `identify`
    /// on 20 rows printed "frequency: n/a" and then "agrees with the spectrum: yes".
    #[serde(default)]
    pub agrees: Option<bool>,
    /// NMAE of the model on the window (infinite when the model did not integrate over it).
    #[serde(deserialize_with = "null_is_infinite")]
    pub fit_nmae: f64,
    /// Whether the model can be trusted (fits, agrees); an untrusted model never raises an alarm.
    pub trusted: bool,
    /// The conclusion.
    pub verdict: Verdict,
    /// The model-free regime of the window (`None` without uniform sampling).
    #[serde(default)]
    pub regime: Option<crate::spectral::Regime>,
    /// Windows whose ambient or envelope estimates were pooled into `zeta0` and its interval
    /// (`None`: the window alone; `docs/damping.md`, "Pooling windows").
    #[serde(default)]
    pub zeta0_windows: Option<usize>,
    /// Whether this window's own estimate signalled a change of the gate's ambient state alone
    /// (more than 3 combined standard errors from the pool, or its pole moved more than 5 %)
    /// and was held back: `zeta0`, its interval and `zeta0_windows` are then the pool's figure
    /// from before it, the window's own estimate is in `ambient_zeta`, and the next window
    /// decides whether it was a change (`docs/damping.md`, "One far window is held").
    #[serde(default)]
    pub zeta0_held: bool,
    /// On an ambient window that rose towards the departure ratio (`ambient_ratio` at least
    /// half of `departure_ratio`, `analysis::rising`), or whose envelope fell (`growth_rate`
    /// more than two standard errors below zero, `analysis::falling`), and is therefore
    /// reported alone (`zeta0_windows` 1, its own `zeta0` and interval): the figure and 95 %
    /// interval of the pool it still joined. The trend reads this one, as it reads every pooled
    /// window (`analysis::trend_reading`; `docs/damping.md`, "A rising window stands alone",
    /// "A falling window stands alone"). Also on
    /// a limit-cycle window whose pool lies below zero but is short of
    /// `analysis::MIN_CYCLE_POOL_CYCLES` at the ambient level, reported untrusted: the pool's
    /// figure, which the trend reads as it did before that rule. `None` elsewhere.
    #[serde(default)]
    pub pooled_zeta: Option<AmbientZeta>,
    /// Seconds from the window's end back to the instant a pooled `zeta0` stands for: the middle
    /// of the records its pool combined (`spectral::PooledEstimate::record_middle`), set where
    /// the pool set `zeta0_windows` (ambient or envelope source; a window alone in its pool:
    /// its own record's middle). `None` where `zeta0` is the window's own reading (a model, the
    /// prediction errors, the cycle's amplitude, a rising or falling window beside its pool),
    /// which stands for the window's middle. The
    /// trend places each figure at its instant, not at the window's end (`docs/damping.md`,
    /// "Trend": a pool of a 5 Hz gate reads about 16 s behind its newest window).
    #[serde(default)]
    pub zeta0_lag_seconds: Option<f64>,
    /// The same for `pooled_zeta`: seconds from the window's end back to the middle of that
    /// pool's records; `None` where `pooled_zeta` is.
    #[serde(default)]
    pub pooled_lag_seconds: Option<f64>,
    /// Standard deviation of the window's signal about its mean, in the signal's unit (`None`
    /// without a model-free analysis): what the gate's memory compares with its ambient level
    /// (`docs/damping.md`, "The gate's ambient level").
    #[serde(default)]
    pub signal_rms: Option<f64>,
    /// `signal_rms` over the gate's ambient level (the median RMS of its last noise-driven
    /// windows); `None` until the gate has one. A window far above it shows the gate has left
    /// its ambient state, what one window needs before it may fire an alert at once (at
    /// `alert::at_once_ratio` of [`DampingReport::departure_ratio`] or more).
    #[serde(default)]
    pub ambient_ratio: Option<f64>,
    /// The `ambient_ratio` from which this gate counts as having left its ambient level (what
    /// one window needs to be read by its model; to fire at once it needs twice the margin
    /// over 3 and at least 3.5, `alert::at_once_ratio`): 3 on a gate whose windows
    /// hold 50 cycles or more, up to 4.65 on a slow gate whose windows hold few
    /// (`analysis::departure_ratio`); `None` until the gate has a level.
    #[serde(default)]
    pub departure_ratio: Option<f64>,
    /// Cycles of the window's dominant frequency the window holds (frequency times duration;
    /// `None` without a model-free analysis): what sets how far a noise-driven window's RMS
    /// scatters about the gate's level.
    #[serde(default)]
    pub window_cycles: Option<f64>,
    /// Largest over smallest standard deviation of the window's three thirds (`None` without a
    /// model-free analysis): near 1 on a stationary response, far above it where the gate
    /// changed state inside the window (a burst beginning or ending in it).
    #[serde(default)]
    pub rms_swing: Option<f64>,
    /// Whether the window holds two states of the gate: it left the ambient level, its response
    /// changed abruptly inside it (`rms_swing`) and its own estimate could not tell the sign, so
    /// `zeta0_interval` also spans the previous window's reading, which saw the first state
    /// (`docs/damping.md`, "A window that holds two states").
    #[serde(default)]
    pub spans_change: bool,
    /// Whether the window is a noise-driven one whose variance grows: at least 2 times the
    /// gate's ambient level, without an abrupt change inside it (`rms_swing` below 4), its
    /// lagged SSI-COV reading lies more than 0.4 of its standard error above the common-instant
    /// one. `zeta0` and its interval are then the common
    /// reading, alone (`zeta0_windows` 1), and the ambient pool starts afresh after it
    /// (`docs/damping.md`, "A growing window read over common instants").
    #[serde(default)]
    pub ssi_growing: bool,
    /// Whether the window holds fewer than `analysis::MIN_WINDOW_CYCLES` (16) cycles of its
    /// dominant frequency (`window_cycles`): its figures are then no evidence (untrusted,
    /// verdict `unknown`, no alert, not in the trend). A gate this slow needs a longer window
    /// (`docs/operations.md`, "A slow gate").
    #[serde(default)]
    pub too_few_cycles: bool,
    /// The window's own 95 % interval for `zeta0`, set only where `zeta0_interval` was widened
    /// down to the gate's declining trend (`analysis::reach_down_to_trend`, docs/damping.md, "A
    /// declining gate's interval reaches down to its trend"). The trend and the alert read this
    /// one ([`DampingReport::own_interval`]): the widened end is the trend's, not the window's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_interval: Option<(f64, f64)>,
}

/// `fit_nmae` read back: JSON has no infinity, so serde_json writes an infinite NMAE (a model
/// that did not integrate over the window) as `null`; `null` reads back as that infinity. It was
/// refused, and the daemon counted every such stored window as damaged at each restart and
/// rebuilt the gate's memory without it.
fn null_is_infinite<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

impl DampingReport {
    /// A report that knows nothing: no figures, no fit (`fit_nmae` infinite), no agreement,
    /// untrusted,
    /// verdict `Unknown`. Callers (and test doubles) set only the fields they know:
    ///
    /// ```
    /// use gatewatch::analysis::{DampingReport, Verdict};
    /// let r = DampingReport {
    ///     zeta0: Some(0.01),
    ///     trusted: true,
    ///     verdict: Verdict::Damped,
    ///     ..DampingReport::unknown()
    /// };
    /// assert_eq!(r.zeta_eq, None);
    /// ```
    pub fn unknown() -> DampingReport {
        DampingReport {
            zeta0: None,
            zeta0_interval: None,
            zeta0_source: None,
            zeta_eq: None,
            energy_per_cycle: None,
            limit_cycle_amplitude: None,
            time_to_limit: None,
            frequency_hz: None,
            growth_rate: None,
            growth_rate_stderr: None,
            ambient_zeta: None,
            ambient_common_zeta: None,
            envelope_zeta: None,
            envelope_record_seconds: None,
            envelope_drift_zeta: None,
            ambient_record_zeta: None,
            ambient_record_seconds: None,
            model_zeta: None,
            amplitude_zeta: None,
            growth_zeta: None,
            prediction_error_zeta: None,
            growth_law_zeta: None,
            zeta_eq_curve: Vec::new(),
            model_frequency_hz: None,
            ambient_frequency_hz: None,
            amplitude: None,
            agrees: None,
            fit_nmae: f64::INFINITY,
            trusted: false,
            verdict: Verdict::Unknown,
            regime: None,
            zeta0_windows: None,
            zeta0_held: false,
            pooled_zeta: None,
            zeta0_lag_seconds: None,
            pooled_lag_seconds: None,
            signal_rms: None,
            ambient_ratio: None,
            departure_ratio: None,
            window_cycles: None,
            rms_swing: None,
            spans_change: false,
            ssi_growing: false,
            too_few_cycles: false,
            window_interval: None,
        }
    }

    /// The window's own 95 % interval for `zeta0`: `window_interval` where the report's was
    /// widened down to the trend, else `zeta0_interval`. What the trend and the alert read of
    /// the window, so that neither reads the trend's own band back as a window's evidence.
    pub fn own_interval(&self) -> Option<(f64, f64)> {
        self.window_interval.or(self.zeta0_interval)
    }
}

impl Default for DampingReport {
    /// [`DampingReport::unknown`].
    fn default() -> Self {
        DampingReport::unknown()
    }
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

impl Verdict {
    /// The name used in the JSON, the store and the tables: `damped`, `self_excited`,
    /// `unknown`.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Damped => "damped",
            Verdict::SelfExcited => "self_excited",
            Verdict::Unknown => "unknown",
        }
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}
