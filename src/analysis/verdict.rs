//! The verdict of a window: whether the identified model agrees with the model-free estimates,
//! and what the analysis concludes from the model, the spectrum and the ambient damping.
//!
//! [`decide`] is a pure function of [`VerdictFacts`]; it is the table "fit_nmae, trusted, verdict"
//! of `docs/damping.md`, row by row, and the unit tests below test every row.

use super::report::{AmbientZeta, DampingReport, Verdict, Zeta0Source};
use crate::spectral::{Regime, WindowSpectral};

/// The model's frequency must lie within this fraction of the window's dominant frequency.
/// Value: `docs/damping.md` ("agreement"). It is about three FFT bins of a 10 s window at the lab
/// gate's 10.4 Hz (one bin, 0.1 Hz, is 1 %): far above the interpolated peak's error, far below
/// the gap to another mode or a wrong model.
pub const FREQUENCY_TOLERANCE: f64 = 0.03;

/// The model's envelope growth must lie within this many (summed) standard errors of the
/// window's. Value: `docs/damping.md`; three standard errors, the same significance as
/// `spectral::ClassifyOptions::growth_sigmas`, and the sum of the two errors rather than their
/// root sum of squares keeps the test on the permissive side.
pub const GROWTH_TOLERANCE_SIGMAS: f64 = 3.0;

/// ... plus this floor, as a damping ratio (`sigma = -zeta omega`, so a growth difference of
/// `0.005 omega` is half a percent of damping ratio). Value: `docs/damping.md`; it equals the
/// alert's default `clear_above` (0.5 %), the resolution the alerts need, and keeps a clean,
/// nearly noise-free window (tiny standard errors) from failing on a negligible difference.
pub const GROWTH_TOLERANCE_ZETA: f64 = 0.005;

/// Whether the identified model agrees with the model-free estimates: `data` is the spectral
/// analysis of the window, `model` the same analysis of the model's output. Without uniform
/// sampling (`data` is `None`) there is nothing to compare with and the fit alone judges.
pub fn agrees(data: Option<&WindowSpectral>, model: Option<&WindowSpectral>) -> bool {
    match (data, model) {
        (Some(d), Some(m)) => {
            let f_ok =
                (m.peak.frequency_hz / d.peak.frequency_hz - 1.0).abs() < FREQUENCY_TOLERANCE;
            let w = 2.0 * std::f64::consts::PI * d.peak.frequency_hz;
            let tol = growth_tolerance(d.growth.stderr + m.growth.stderr, w);
            f_ok && (m.growth.sigma - d.growth.sigma).abs() <= tol
        }
        _ => data.is_none(),
    }
}

/// The window's own envelope growth (model-free): what an ambient estimate that claims growth
/// must agree with ([`ambient_decision`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowGrowth {
    /// Envelope growth rate, 1/s (negative: decaying).
    pub sigma: f64,
    /// Its standard error.
    pub stderr: f64,
    /// Angular frequency of the window's dominant peak, rad/s.
    pub omega: f64,
}

impl WindowGrowth {
    /// The growth a report carries (`growth_rate`, its standard error, `frequency_hz`), when it
    /// carries all three, finite.
    pub fn of(d: &super::DampingReport) -> Option<WindowGrowth> {
        let (sigma, stderr, f) = (d.growth_rate?, d.growth_rate_stderr?, d.frequency_hz?);
        let g = WindowGrowth {
            sigma,
            stderr,
            omega: 2.0 * std::f64::consts::PI * f,
        };
        (sigma.is_finite() && stderr.is_finite() && g.omega.is_finite() && g.omega > 0.0)
            .then_some(g)
    }
}

/// Standard errors by which a window's envelope must fall for the window to count as falling
/// ([`falls`], [`super::falling`]).
pub const FALLING_SIGMAS: f64 = 2.0;

/// Whether an envelope growth rate `sigma` (1/s) with standard error `stderr` says the envelope
/// fell: `sigma` lies more than [`FALLING_SIGMAS`] standard errors below zero (both finite,
/// `stderr` not negative). An ambient window that fell stands alone ([`super::falling`]); a
/// limit-cycle window that fell is no saturated cycle, and its envelope's drift is read too
/// (`model_free`, [`super::span_the_fall`]).
pub fn falls(sigma: f64, stderr: f64) -> bool {
    sigma.is_finite() && stderr.is_finite() && stderr >= 0.0 && sigma < -FALLING_SIGMAS * stderr
}

/// How far two envelope growth rates may differ and still agree: [`GROWTH_TOLERANCE_SIGMAS`]
/// times `stderr` (their summed standard errors) plus [`GROWTH_TOLERANCE_ZETA`] at `omega`.
fn growth_tolerance(stderr: f64, omega: f64) -> f64 {
    GROWTH_TOLERANCE_SIGMAS * stderr + GROWTH_TOLERANCE_ZETA * omega
}

/// The facts a verdict depends on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerdictFacts {
    /// NMAE of the model's output on the window (`INFINITY` without a prediction).
    pub fit_nmae: f64,
    /// The settings' bound: above it the model is not trusted.
    pub max_fit_nmae: f64,
    /// Whether nothing contradicts the model: it agrees with the model-free estimates
    /// (`agrees`), or there was no spectrum to compare with (`DampingReport::agrees` is
    /// `None`, where the fit alone judges).
    pub agrees: bool,
    /// The model's damping ratio at rest, when its rest position is an oscillator.
    pub zeta0_model: Option<f64>,
    /// The ambient (SSI-COV) damping of the window, when the estimate succeeded.
    pub ambient: Option<AmbientZeta>,
    /// `zeta0` from the envelope's relaxation, on a limit-cycle window where it succeeded.
    pub envelope: Option<AmbientZeta>,
    /// `zeta0` from the envelope's drift, on a limit-cycle window the relaxation refused (not
    /// on a saturated cycle: the end of a growth, a shrinking cycle).
    pub envelope_drift: Option<AmbientZeta>,
    /// The model-free regime of the window (`None` without uniform sampling).
    pub regime: Option<Regime>,
    /// The window's envelope growth (`None` without uniform sampling).
    pub growth: Option<WindowGrowth>,
}

impl VerdictFacts {
    /// Whether the model may be believed at all: it fits (`fit_nmae <= max_fit_nmae`) and
    /// agrees with the model-free estimates.
    pub fn model_trusted(&self) -> bool {
        self.fit_nmae <= self.max_fit_nmae && self.agrees
    }
}

/// What [`decide`] concludes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decision {
    /// The conclusion.
    pub verdict: Verdict,
    /// Whether the report may feed the alerts.
    pub trusted: bool,
    /// Where the reported `zeta0` comes from.
    pub source: Zeta0Source,
}

/// Whether the model-free regime is an alarm on its own: a significantly growing envelope or a
/// saturated limit cycle (`spectral::classify`). Such a window never gets a `Damped` verdict.
fn regime_alarms(regime: Option<Regime>) -> bool {
    matches!(regime, Some(Regime::SelfExcited | Regime::LimitCycle))
}

/// The verdict of a window, row by row the table of `docs/damping.md`:
///
/// 0. limit-cycle regime with an envelope estimate: from the envelope; `SelfExcited` when its
///    whole interval is below zero, else `Unknown` (untrusted, with its honestly wide interval).
///    On a limit cycle the equivalent damping is zero, so the model's and the ambient `zeta0`
///    read about zero whatever the truth (issue 8); the envelope's relaxation is what still sees
///    it.
///    A limit-cycle regime without a relaxation estimate takes the envelope's drift the same
///    way (row 0b), whatever the model reads: its narrow interval near zero is what missed the
///    truth there (recovery, a shrinking cycle; the lock gate's onset, 60 of 175 such windows
///    covered, stop 72). Until stop 72 a trusted negative model kept deciding, because the
///    drift's honestly wide interval had delayed `GateNegativeDamping` by 25 to 30 s; since
///    stop 71 a steady cycle far above the gate's ambient level reads negative for the alert
///    whatever its interval (`fire_on_limit_cycle`), and on 100 onset seeds of each gate no
///    alert moved (`docs/benchmarks.md`, "Stop 72").
/// 1. the envelope grows significantly (`SelfExcited` regime) and the model is trusted (fits and
///    agrees) with `zeta0 < 0`: `SelfExcited`, from the model. A growing window is where a
///    free-vibration fit is at its best: the growth dominates the turbulent forcing.
/// 2. an ambient (SSI-COV) estimate on any other window but a limit cycle: from the ambient
///    estimate, trusted, the verdict from its interval: `SelfExcited` below zero, `Damped` above
///    zero (not on an alarm regime), `Unknown` across zero. An interval across zero is still
///    evidence (the alerts read it as "cannot tell" and the trend uses it); only a positive
///    interval on a window whose envelope grows contradicts itself and is untrusted. Why the
///    ambient estimate and not the model on a noise-driven window: the free-vibration model
///    treats the turbulent forcing as error and read -1 to -3 % on a stable +1 % gate (issue 8),
///    while SSI-COV is unbiased under sensor noise and its interval covers the truth.
/// 3. no ambient estimate, model trusted, `zeta0 < 0`: `SelfExcited`, from the model;
/// 4. no ambient estimate, model trusted, `zeta0 >= 0`, the regime is no alarm: `Damped`, from
///    the model;
/// 5. anything else: `Unknown`, untrusted, the model's `zeta0` for information only. This
///    includes a trusted model with `zeta0 >= 0` on a self-excited or limit-cycle window: the
///    spectrum sees a vibration sustaining itself, so "damped" would be a false all-clear.
pub fn decide(f: &VerdictFacts) -> Decision {
    let alarm = regime_alarms(f.regime);
    let decision = |verdict, trusted, source| Decision {
        verdict,
        trusted,
        source,
    };
    if let (Some(Regime::LimitCycle), Some(e)) = (f.regime, f.envelope) {
        return if e.high < 0.0 {
            decision(Verdict::SelfExcited, true, Zeta0Source::Envelope)
        } else {
            decision(Verdict::Unknown, false, Zeta0Source::Envelope)
        };
    }
    let model_trusted = f.model_trusted();
    let model_negative = model_trusted && f.zeta0_model.is_some_and(|z| z < 0.0);
    if model_negative && f.regime == Some(Regime::SelfExcited) {
        return decision(Verdict::SelfExcited, true, Zeta0Source::Model);
    }
    if let (Some(Regime::LimitCycle), Some(d)) = (f.regime, f.envelope_drift) {
        return if d.high < 0.0 {
            decision(Verdict::SelfExcited, true, Zeta0Source::Envelope)
        } else {
            decision(Verdict::Unknown, false, Zeta0Source::Envelope)
        };
    }
    match f.ambient {
        Some(a) if f.regime != Some(Regime::LimitCycle) => {
            return ambient_decision(a, f.regime, f.growth)
        }
        _ => {}
    }
    match f.zeta0_model {
        Some(_) if model_negative => decision(Verdict::SelfExcited, true, Zeta0Source::Model),
        Some(_) if model_trusted && !alarm => decision(Verdict::Damped, true, Zeta0Source::Model),
        _ => decision(Verdict::Unknown, false, Zeta0Source::Model),
    }
}

/// Row 2 of [`decide`]: what an ambient (SSI-COV) estimate concludes on its own, trusted:
/// `SelfExcited` when its interval lies below zero, `Damped` above zero (untrusted `Unknown` on
/// an alarm regime: a positive interval on a window that grows contradicts itself), `Unknown`
/// across zero. Also used after the fact on a model window at the gate's ambient level
/// (`AmbientLevel::observe`).
///
/// The other contradiction: an interval below zero that claims more growth than the window's
/// own envelope shows ([`claims_unseen_growth`]) is untrusted `Unknown` too. Why: on a stable
/// +0.5 % 2 Hz barrier gate (20 cycles a window) SSI-COV read one window -23.8 % (-41.0,
/// -6.6), a growth of `e^8` in 10 s at the interval's least negative end, where the window's
/// thirds differed by a factor of 3; pooled with the next window's +0.04 % it gave -11.95 %
/// (-20.98, -2.92), and the two fired `GateNegativeDamping` (`bench warning --gates barrier
/// --scenarios stable-low --hours 12`, seed 2, 16,705 s; docs/damping.md).
pub fn ambient_decision(
    a: AmbientZeta,
    regime: Option<Regime>,
    growth: Option<WindowGrowth>,
) -> Decision {
    let decision = |verdict, trusted| Decision {
        verdict,
        trusted,
        source: Zeta0Source::Ambient,
    };
    if a.high < 0.0 {
        decision(Verdict::SelfExcited, true).unknown_if(claims_unseen_growth(a, growth))
    } else if a.low > 0.0 {
        decision(Verdict::Damped, true).unknown_if(regime_alarms(regime))
    } else {
        decision(Verdict::Unknown, true)
    }
}

/// Whether ambient estimate `a`, whose interval lies below zero, claims more growth than the
/// window's envelope shows: the slowest growth its interval allows, `-high * omega`, exceeds the
/// measured growth by more than the tolerance `agrees` gives a model (`GROWTH_TOLERANCE_SIGMAS`
/// standard errors plus `GROWTH_TOLERANCE_ZETA`). A real negative damping grows the window at
/// about its rate (a growing window, or the first seconds of one); a spurious SSI-COV pole of a
/// short record does not. Without the growth (no uniform sampling) nothing is claimed.
pub fn claims_unseen_growth(a: AmbientZeta, growth: Option<WindowGrowth>) -> bool {
    growth.is_some_and(|g| {
        let claimed = -a.high * g.omega;
        claimed > g.sigma + growth_tolerance(g.stderr, g.omega)
    })
}

/// Fewest cycles of its dominant frequency a window must hold for its damping to be evidence
/// (`trusted`) whatever its source ([`refuse_few_cycles`]): the fewest the ambient estimator
/// reads, four jackknife blocks of four cycles (`spectral::SsiOptions`'s `min_blocks` and
/// `min_block_cycles`; a unit test keeps the two equal).
///
/// Why: below it no estimator of the window has a reference to be checked against, and each
/// is confidently wrong. A 1 Hz gate in 10 s windows (10 cycles, `bench warning --gates surge`,
/// stop 85) read a stable gate at +1 % with a median error of 3.6 points, covered in 63 % of
/// its windows, and paged 91 times a day at +1 % and 194 at +0.5 % (`GateNegativeDamping`),
/// and warned 79 and 91 times (`GateDampingDeclining`). The 2 Hz barrier gate's 20 cycles pass, as its
/// benchmark rows do. What serves a slow gate is a longer window: docs/operations.md, "A slow
/// gate".
pub const MIN_WINDOW_CYCLES: f64 = 16.0;

/// Marks the report of a window holding fewer than [`MIN_WINDOW_CYCLES`] cycles of its dominant
/// frequency (`window_cycles`) as no evidence: untrusted, verdict `Unknown`, no pooled figure
/// for the trend (`too_few_cycles` says why); its figures stay for the record. Returns whether
/// it did. A report without `window_cycles` (no model-free analysis) is left as it is.
pub fn refuse_few_cycles(d: &mut DampingReport) -> bool {
    let few = d.window_cycles.is_some_and(|c| c < MIN_WINDOW_CYCLES);
    if few {
        d.trusted = false;
        d.verdict = Verdict::Unknown;
        d.pooled_zeta = None;
        d.too_few_cycles = true;
    }
    few
}

impl Decision {
    /// This decision turned into an untrusted `Unknown` when `cond` holds.
    fn unknown_if(self, cond: bool) -> Decision {
        if cond {
            Decision {
                verdict: Verdict::Unknown,
                trusted: false,
                ..self
            }
        } else {
            self
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The guard's bar is the fewest cycles the ambient estimator reads: its four blocks of
    /// four cycles. If SSI-COV's defaults change, the bar must be chosen again.
    #[test]
    fn the_fewest_cycles_are_the_ambient_estimators() {
        let o = crate::spectral::SsiOptions::default();
        assert_eq!(MIN_WINDOW_CYCLES, o.min_blocks as f64 * o.min_block_cycles);
    }

    /// A window below the bar loses its evidence, keeps its figures and says why; one at or
    /// above it, or without a count of its cycles, is left as it was.
    #[test]
    fn a_window_of_too_few_cycles_is_no_evidence() {
        let confident = |cycles: Option<f64>| DampingReport {
            zeta0: Some(-0.02),
            zeta0_interval: Some((-0.025, -0.015)),
            trusted: true,
            verdict: Verdict::SelfExcited,
            pooled_zeta: Some(AmbientZeta {
                zeta: -0.02,
                low: -0.025,
                high: -0.015,
            }),
            window_cycles: cycles,
            ..DampingReport::unknown()
        };
        let mut d = confident(Some(10.0));
        assert!(refuse_few_cycles(&mut d));
        assert!(!d.trusted && d.verdict == Verdict::Unknown && d.too_few_cycles);
        assert_eq!(d.pooled_zeta, None);
        assert_eq!(
            (d.zeta0, d.zeta0_interval),
            (Some(-0.02), Some((-0.025, -0.015)))
        );
        for cycles in [Some(MIN_WINDOW_CYCLES), Some(20.0), None] {
            let mut d = confident(cycles);
            assert!(!refuse_few_cycles(&mut d), "{cycles:?}");
            assert_eq!(d, confident(cycles));
        }
    }

    const AMBIENT_DAMPED: AmbientZeta = AmbientZeta {
        zeta: 0.01,
        low: 0.006,
        high: 0.014,
    };

    /// A trusted model, an ambient estimate and a damped regime; each test changes what it needs.
    fn facts() -> VerdictFacts {
        VerdictFacts {
            fit_nmae: 0.05,
            max_fit_nmae: 0.2,
            agrees: true,
            zeta0_model: Some(0.01),
            ambient: Some(AMBIENT_DAMPED),
            envelope: None,
            envelope_drift: None,
            regime: Some(Regime::Damped),
            growth: None,
        }
    }

    fn decision(verdict: Verdict, trusted: bool, source: Zeta0Source) -> Decision {
        Decision {
            verdict,
            trusted,
            source,
        }
    }

    /// Rows 1 and 3: a trusted negative model decides on a growing window, and on any window
    /// without an ambient estimate.
    #[test]
    fn row_trusted_negative_zeta0_is_self_excited_on_growth_or_without_ambient() {
        for (regime, ambient) in [
            (Some(Regime::SelfExcited), Some(AMBIENT_DAMPED)),
            (Some(Regime::SelfExcited), None),
            (None, None),
            (Some(Regime::Undecided), None),
            (Some(Regime::LimitCycle), None),
            (Some(Regime::LimitCycle), Some(AMBIENT_DAMPED)),
        ] {
            let f = VerdictFacts {
                zeta0_model: Some(-0.01),
                regime,
                ambient,
                ..facts()
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::SelfExcited, true, Zeta0Source::Model),
                "{regime:?}"
            );
        }
    }

    /// Issue 8: a trusted model reading -1..-3 % on a stable +1 % gate replaced the ambient
    /// estimate. A negative model `zeta0` that a `Damped` regime's ambient interval contradicts
    /// gives way to the ambient estimate.
    #[test]
    fn model_contradicted_by_a_damped_ambient_interval_gives_way() {
        for z in [-0.003, -0.012, -0.03] {
            let f = VerdictFacts {
                zeta0_model: Some(z),
                ..facts()
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::Damped, true, Zeta0Source::Ambient),
                "{z}"
            );
        }
        // On a window whose envelope does not grow the ambient estimate decides even when its
        // interval reaches zero: trusted evidence that cannot tell the sign.
        let f = VerdictFacts {
            zeta0_model: Some(-0.01),
            ambient: Some(AmbientZeta {
                zeta: 0.004,
                low: -0.001,
                high: 0.009,
            }),
            regime: Some(Regime::Undecided),
            ..facts()
        };
        assert_eq!(
            decide(&f),
            decision(Verdict::Unknown, true, Zeta0Source::Ambient)
        );
        // Nor does a regime other than Damped (an onset whose envelope grows).
        let f = VerdictFacts {
            zeta0_model: Some(-0.01),
            regime: Some(Regime::SelfExcited),
            ..facts()
        };
        assert_eq!(decide(&f).verdict, Verdict::SelfExcited);
    }

    /// Issue 8: on a limit cycle the envelope's relaxation decides, not the model (whose `zeta0`
    /// scattered between -1 and +0.6 % at a true -2 %).
    #[test]
    fn limit_cycle_with_envelope_estimate_reports_it() {
        let negative = AmbientZeta {
            zeta: -0.02,
            low: -0.03,
            high: -0.01,
        };
        let wide = AmbientZeta {
            zeta: -0.01,
            low: -0.03,
            high: 0.01,
        };
        for zeta0_model in [Some(0.004), Some(-0.01), None] {
            let f = VerdictFacts {
                zeta0_model,
                envelope: Some(negative),
                regime: Some(Regime::LimitCycle),
                ..facts()
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::SelfExcited, true, Zeta0Source::Envelope)
            );
            let f = VerdictFacts {
                envelope: Some(wide),
                ..f
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::Unknown, false, Zeta0Source::Envelope)
            );
        }
        // The envelope estimate is used only on a limit cycle.
        let f = VerdictFacts {
            envelope: Some(negative),
            ..facts()
        };
        assert_eq!(decide(&f).source, Zeta0Source::Ambient);
    }

    /// Row 0b: a limit-cycle window without a relaxation estimate takes the envelope's drift
    /// (negative: self-excited; reaching zero: unknown, untrusted), whatever the model reads;
    /// the drift is used only on a limit cycle.
    #[test]
    fn limit_cycle_without_relaxation_takes_the_drift() {
        let negative = AmbientZeta {
            zeta: -0.015,
            low: -0.035,
            high: -0.001,
        };
        let wide = AmbientZeta {
            zeta: -0.005,
            low: -0.03,
            high: 0.02,
        };
        let lc = |zeta0_model, fit_nmae, drift| VerdictFacts {
            zeta0_model,
            fit_nmae,
            envelope_drift: Some(drift),
            regime: Some(Regime::LimitCycle),
            ..facts()
        };
        // a positive, an untrusted, a trusted negative and no model
        let models = [
            (Some(0.002), 0.05),
            (Some(-0.01), 0.6),
            (Some(-0.01), 0.05),
            (None, 0.05),
        ];
        for (model, fit) in models {
            assert_eq!(
                decide(&lc(model, fit, negative)),
                decision(Verdict::SelfExcited, true, Zeta0Source::Envelope),
                "model {model:?}, fit {fit}"
            );
            assert_eq!(
                decide(&lc(model, fit, wide)),
                decision(Verdict::Unknown, false, Zeta0Source::Envelope),
                "model {model:?}, fit {fit}"
            );
        }
        // without the drift, a trusted negative model decides (row 3)
        let no_drift = VerdictFacts {
            envelope_drift: None,
            ..lc(Some(-0.01), 0.05, wide)
        };
        assert_eq!(
            decide(&no_drift),
            decision(Verdict::SelfExcited, true, Zeta0Source::Model)
        );
        let damped = VerdictFacts {
            envelope_drift: Some(negative),
            ..facts()
        };
        assert_eq!(decide(&damped).source, Zeta0Source::Ambient);
    }

    /// Row 2: the ambient estimate's interval gives the verdict on a window that does not grow.
    #[test]
    fn row_ambient_interval_gives_the_verdict() {
        let negative = AmbientZeta {
            zeta: -0.008,
            low: -0.014,
            high: -0.002,
        };
        for (zeta0_model, fit_nmae) in [(Some(0.01), 0.05), (Some(-0.01), 0.5), (None, 0.5)] {
            let base = VerdictFacts {
                zeta0_model,
                fit_nmae,
                ..facts()
            };
            assert_eq!(
                decide(&base),
                decision(Verdict::Damped, true, Zeta0Source::Ambient)
            );
            for regime in [Some(Regime::SelfExcited), Some(Regime::Undecided), None] {
                let f = VerdictFacts {
                    ambient: Some(negative),
                    regime,
                    ..base
                };
                assert_eq!(
                    decide(&f),
                    decision(Verdict::SelfExcited, true, Zeta0Source::Ambient),
                    "{f:?}"
                );
            }
        }
        // A positive interval on a growing window contradicts itself: untrusted.
        let f = VerdictFacts {
            fit_nmae: 0.5,
            regime: Some(Regime::SelfExcited),
            ..facts()
        };
        assert_eq!(
            decide(&f),
            decision(Verdict::Unknown, false, Zeta0Source::Ambient)
        );
    }

    #[test]
    fn row_trusted_non_negative_zeta0_is_damped_without_ambient() {
        for (z, regime) in [
            (0.01, Some(Regime::Damped)),
            (0.0, Some(Regime::Damped)),
            (0.01, Some(Regime::Undecided)),
            // Without uniform sampling there is no regime: the model alone decides.
            (0.01, None),
        ] {
            let f = VerdictFacts {
                zeta0_model: Some(z),
                regime,
                ambient: None,
                ..facts()
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::Damped, true, Zeta0Source::Model),
                "{z} {regime:?}"
            );
        }
        // The bound itself still fits.
        let f = VerdictFacts {
            fit_nmae: 0.2,
            ambient: None,
            ..facts()
        };
        assert_eq!(decide(&f).verdict, Verdict::Damped);
    }

    #[test]
    fn row_untrusted_model_with_positive_ambient_interval_is_damped_from_ambient() {
        for f in [
            // Does not fit.
            VerdictFacts {
                fit_nmae: 0.5,
                ..facts()
            },
            // Fits but disagrees with the spectrum.
            VerdictFacts {
                agrees: false,
                ..facts()
            },
            // No oscillator at rest, and an undecided regime.
            VerdictFacts {
                fit_nmae: f64::INFINITY,
                zeta0_model: None,
                regime: Some(Regime::Undecided),
                ..facts()
            },
        ] {
            assert_eq!(
                decide(&f),
                decision(Verdict::Damped, true, Zeta0Source::Ambient),
                "{f:?}"
            );
        }
    }

    #[test]
    fn row_anything_else_is_unknown_and_untrusted() {
        let untrusted = VerdictFacts {
            fit_nmae: 0.5,
            ..facts()
        };
        for f in [
            // No ambient estimate.
            VerdictFacts {
                ambient: None,
                ..untrusted
            },
            // A trusted model with no oscillator at rest and no usable ambient estimate.
            VerdictFacts {
                zeta0_model: None,
                ambient: None,
                ..facts()
            },
            // NaN fit: not trusted.
            VerdictFacts {
                fit_nmae: f64::NAN,
                ambient: None,
                ..facts()
            },
            // A trusted model saying "damped" on a window whose envelope grows significantly.
            VerdictFacts {
                regime: Some(Regime::SelfExcited),
                ambient: None,
                ..facts()
            },
        ] {
            assert_eq!(
                decide(&f),
                decision(Verdict::Unknown, false, Zeta0Source::Model),
                "{f:?}"
            );
        }
    }

    /// Regression (issue 7, defect 3): a limit-cycle window whose ambient interval lies just above
    /// zero, below `ClassifyOptions::max_limit_cycle_zeta` (0.002), got a trusted `Damped` verdict
    /// through the ambient fallback, although the spectrum calls it an alarm.
    #[test]
    fn limit_cycle_never_gets_a_trusted_damped_verdict() {
        let limit_cycle_ambient = AmbientZeta {
            zeta: 0.0015,
            low: 0.001,
            high: 0.002,
        };
        for (fit_nmae, zeta0_model) in [
            (0.5, Some(-0.01)),
            (0.5, Some(0.003)),
            (0.5, None),
            (0.05, Some(0.001)),
        ] {
            let f = VerdictFacts {
                fit_nmae,
                zeta0_model,
                ambient: Some(limit_cycle_ambient),
                regime: Some(Regime::LimitCycle),
                ..facts()
            };
            assert_eq!(
                decide(&f),
                decision(Verdict::Unknown, false, Zeta0Source::Model),
                "{f:?}"
            );
        }
        // The trusted model saying so still raises it.
        let f = VerdictFacts {
            zeta0_model: Some(-0.01),
            ambient: Some(limit_cycle_ambient),
            regime: Some(Regime::LimitCycle),
            ..facts()
        };
        assert_eq!(decide(&f).verdict, Verdict::SelfExcited);
    }

    #[test]
    fn a_negative_ambient_interval_must_not_claim_more_growth_than_the_window_shows() {
        // the barrier gate's spurious pole: -23.8 % (-41.0, -6.6) at 2 Hz on a window whose
        // envelope grew at most about 0.17 / s
        let spurious = AmbientZeta {
            zeta: -0.238,
            low: -0.410,
            high: -0.066,
        };
        let omega = 2.0 * std::f64::consts::PI * 2.0;
        let seen = WindowGrowth {
            sigma: 0.1,
            stderr: 0.02,
            omega,
        };
        assert!(claims_unseen_growth(spurious, Some(seen)));
        let f = VerdictFacts {
            fit_nmae: 0.29, // the model untrusted: row 2 decides
            ambient: Some(spurious),
            regime: Some(Regime::SelfExcited),
            growth: Some(seen),
            ..facts()
        };
        assert_eq!(
            decide(&f),
            decision(Verdict::Unknown, false, Zeta0Source::Ambient)
        );
        // a real growth at -1 % whose SSI interval lies below zero: about its rate, it stands
        let real = AmbientZeta {
            zeta: -0.01,
            low: -0.016,
            high: -0.004,
        };
        let growing = WindowGrowth {
            sigma: 0.01 * omega,
            stderr: 0.03,
            omega,
        };
        let f = VerdictFacts {
            ambient: Some(real),
            growth: Some(growing),
            ..f
        };
        assert_eq!(
            decide(&f),
            decision(Verdict::SelfExcited, true, Zeta0Source::Ambient)
        );
        // the tolerance is the agreement test's: 3 standard errors plus half a point of damping
        let edge = GROWTH_TOLERANCE_SIGMAS * 0.03 + GROWTH_TOLERANCE_ZETA * omega;
        let just = |high: f64| AmbientZeta {
            zeta: high - 0.01,
            low: high - 0.02,
            high,
        };
        let still = WindowGrowth {
            sigma: 0.0,
            ..growing
        };
        assert!(!claims_unseen_growth(
            just(-0.99 * edge / omega),
            Some(still)
        ));
        assert!(claims_unseen_growth(
            just(-1.01 * edge / omega),
            Some(still)
        ));
        // without the window's growth nothing is claimed
        assert!(!claims_unseen_growth(spurious, None));
    }
}
