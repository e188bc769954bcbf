//! Tracking between windows: when a window may start from the previous window's model with a
//! short least-squares refinement instead of the full DE search (`docs/design.md`, "Tracking").
//!
//! Two pure decisions, so that each branch is testable without numerics:
//! - [`plan`], before the window is analysed: the full search runs when tracking is off, the
//!   gate is new, the previous window's model was not trusted, the new window starts more than
//!   `max_gap_windows` window lengths after the previous one's end (a long gap), or the schedule
//!   says so (every `full_every` windows);
//! - [`accept`], after the refinement: the refined window stands only when it is still trusted,
//!   gives the same verdict as the previous window, the model's frequency at rest is within a
//!   tolerance of the measured dominant frequency, the model still agrees with the model-free
//!   estimates (frequency, envelope growth) when the previous one did, and it fits within a
//!   tolerance of the last full search's fit.
//!
//! The per-gate [`Previous`] lives in the service (the worker pool keeps one per gate).

use super::report::{DampingReport, Verdict};
use super::WindowAnalysis;
use serde::{Deserialize, Serialize};

/// Absolute slack of the fit test, NMAE: a tracked fit may exceed `fit_tolerance` times the
/// last full fit by this much. Value: half the chapter's success criterion (NMAE 0.01); without
/// it a nearly perfect full fit (NMAE 1e-4 on clean data) would make any noise a "regime change".
pub const FIT_SLACK: f64 = 0.005;

/// Largest full-search NMAE the fit test takes as its reference. Value: predicting the signal's
/// mean scores about 0.8 (noise) to 0.9 (a sinusoid) in this NMAE (mean absolute error over the
/// standard deviation), so a full search that fit worse than 1, or not at all (NaN, infinite:
/// its model diverged over the window, about 1 window in 60 on a stable gate), says nothing
/// about how well the gate's model can fit, and must not let any refinement pass: with such a
/// reference the limit was infinite or NaN, and refinements with an infinite NMAE were accepted.
pub const MAX_REFERENCE_NMAE: f64 = 1.0;

/// Upper bound of [`TrackingPolicy::max_gap_windows`]: beyond a few windows the gate may have
/// changed in ways the acceptance test was not designed to catch (it compares with the last
/// window, not with the history).
pub const MAX_GAP_WINDOWS: f64 = 10.0;

/// How a gate's windows are tracked (`[defaults.tracking]` in the daemon's configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingPolicy {
    /// Whether windows may take the tracked path at all (false: every window runs the full DE).
    pub enabled: bool,
    /// The full search runs at least every this many windows (1: always), so that a slowly
    /// drifting model cannot stay in a local optimum the refinement cannot leave.
    pub full_every: usize,
    /// A tracked fit NMAE may be at most this factor times the last full search's, plus
    /// [`FIT_SLACK`].
    pub fit_tolerance: f64,
    /// The refined model's frequency at rest may differ from the window's measured dominant
    /// frequency by at most this fraction.
    pub frequency_tolerance: f64,
    /// Integrations the refinement may charge (`WindowAnalysis::evaluations` of a tracked
    /// window never exceeds it): bounds a tracked window's cost.
    pub refine_evaluations: usize,
    /// Relative tolerance of the refinement's Dormand-Prince integrations (1e-6, as the daemon's
    /// full search's polish: `AnalysisSettings::polish_rtol`).
    pub refine_rtol: f64,
    /// Longest gap the tracked path may bridge: the new window may start at most this many
    /// window lengths (the previous window's duration) after the previous window's end. 0: the
    /// windows must overlap. Why: a replaced job (a busy worker) or a short data gap does not
    /// change the gate, and [`accept`] still guards the refined model; forcing the full search
    /// there made a backlog feed itself (docs/design.md, "Tracking between windows").
    pub max_gap_windows: f64,
}

impl Default for TrackingPolicy {
    fn default() -> Self {
        TrackingPolicy {
            enabled: true,
            full_every: 12,
            fit_tolerance: 1.5,
            frequency_tolerance: 0.05,
            refine_evaluations: 60,
            refine_rtol: 1e-6,
            max_gap_windows: 2.0,
        }
    }
}

impl TrackingPolicy {
    /// Checks the values; the error names the key (`full_every: must be >= 1`).
    pub fn validate(&self) -> Result<(), String> {
        if self.full_every == 0 {
            return Err("full_every: must be >= 1".into());
        }
        if !(self.fit_tolerance.is_finite() && self.fit_tolerance >= 1.0) {
            return Err("fit_tolerance: must be a finite number >= 1".into());
        }
        if !(self.frequency_tolerance.is_finite() && self.frequency_tolerance > 0.0) {
            return Err("frequency_tolerance: must be a finite number > 0".into());
        }
        if self.refine_evaluations < 4 {
            return Err("refine_evaluations: must be >= 4".into());
        }
        if !(self.refine_rtol > 0.0 && self.refine_rtol < 1.0) {
            return Err("refine_rtol: must be in (0, 1)".into());
        }
        if !(self.max_gap_windows.is_finite()
            && (0.0..=MAX_GAP_WINDOWS).contains(&self.max_gap_windows))
        {
            return Err(format!(
                "max_gap_windows: must be a number in [0, {MAX_GAP_WINDOWS}]"
            ));
        }
        Ok(())
    }
}

/// Which way a window was identified. Serialised as `"tracked"` / `"full"` (API, metric label).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Path {
    /// The previous window's model, refined by least squares and accepted by [`accept`].
    Tracked,
    /// The full DE search (with the polish).
    #[default]
    Full,
}

impl Path {
    /// The name in the API and the metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Path::Tracked => "tracked",
            Path::Full => "full",
        }
    }
}

/// What a gate's tracking remembers of its last analysed window.
#[derive(Debug, Clone, PartialEq)]
pub struct Previous {
    /// The last window's coefficients (physical units): the refinement's start.
    pub coefficients: Vec<f64>,
    /// Fit NMAE of the last full search (the reference of the fit test).
    pub full_fit_nmae: f64,
    /// Windows taken on the tracked path since the last full search.
    pub since_full: usize,
    /// The last window's verdict.
    pub verdict: Verdict,
    /// Whether the last window was trusted (by its model or the ambient estimate).
    pub trusted: bool,
    /// Whether the last window's model agreed with the model-free estimates.
    pub agrees: bool,
    /// Time of the last window's first sample.
    pub t_start: f64,
    /// Time of the last window's last sample.
    pub t_end: f64,
}

impl Previous {
    /// The memory after window `a` covering `[t_start, t_end]`, given the memory before it.
    pub fn after(before: Option<&Previous>, a: &WindowAnalysis, t_start: f64, t_end: f64) -> Self {
        let tracked = a.path == Path::Tracked;
        let (full_fit_nmae, since_full) = match (tracked, before) {
            (true, Some(b)) => (b.full_fit_nmae, b.since_full + 1),
            _ => (a.damping.fit_nmae, 0),
        };
        Previous {
            coefficients: a.warm_start.clone(),
            full_fit_nmae,
            since_full,
            verdict: a.damping.verdict,
            trusted: a.damping.trusted,
            agrees: a.damping.agrees,
            t_start,
            t_end,
        }
    }
}

impl Previous {
    /// The memory after a gate's first window, its schedule shifted by a phase taken from the
    /// gate's name: `since_full` starts at `phase(gate) % full_every` instead of 0, so the first
    /// scheduled full search comes 0 to `full_every - 1` windows early, and never late.
    ///
    /// Why: gates that start together (every gate after a restart) otherwise search together
    /// every `full_every` windows, a burst of full searches (about 0.12 s each) that a worker
    /// cannot absorb within one cadence: with 64 gates started at once `gatewatch bench daemon`
    /// replaced 16 jobs after the first round, in bunches every minute. The name, not a random
    /// draw, so that a replay gives the same schedule.
    pub fn first_of(self, gate: &str, policy: &TrackingPolicy) -> Self {
        let phase = gate_hash(gate, 0) % policy.full_every.max(1) as u64;
        Previous {
            since_full: phase as usize,
            ..self
        }
    }
}

/// A stable number from a gate's name and an index: FNV-1a of the name, combined with the index
/// and mixed by splitmix64's finaliser. The daemon's window seeds (`service::worker::window_seed`,
/// index = the window's last sample) and the schedule's phase ([`Previous::first_of`], index 0)
/// both come from it; the same inputs give the same number on every machine and build.
pub fn gate_hash(gate: &str, index: u64) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in gate.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    let mut z = h ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Why a window runs the full search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FullReason {
    /// Tracking is off.
    Disabled,
    /// No previous window (a new gate, or the daemon restarted).
    NewGate,
    /// The previous window's model was not trusted: nothing worth following.
    Untrusted,
    /// The window starts before the previous one (time reset) or more than
    /// `max_gap_windows` window lengths after its end (data missing, many jobs replaced).
    Gap,
    /// `full_every` windows since the last full search.
    Schedule,
    /// The refinement was tried and [`accept`] refused it.
    Refused(Rejection),
}

/// Why [`accept`] refused a refined model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rejection {
    /// The refinement could not run (the analysis failed).
    Failed,
    /// The refined window is not trusted (see `docs/damping.md`).
    Untrusted,
    /// The model's frequency at rest is off the measured dominant frequency.
    Frequency {
        /// The model's, Hz (`None`: not an oscillator at rest).
        model_hz: Option<f64>,
        /// The measured, Hz.
        measured_hz: f64,
    },
    /// Its frequency or growth disagrees with the model-free estimates, where the previous
    /// model agreed.
    Disagrees,
    /// It is self-excited where the previous window was not, or the reverse: a change of regime
    /// is always confirmed by a search (`Damped` and `Unknown` are not told apart here).
    VerdictChanged,
    /// Its fit NMAE is above the limit derived from the last full search.
    Fit {
        /// The refined model's NMAE.
        nmae: f64,
        /// The limit.
        limit: f64,
    },
}

/// Whether the window starting at `t_start` may try the tracked path: `Ok(previous)` or the
/// reason for the full search.
pub fn plan<'a>(
    policy: &TrackingPolicy,
    previous: Option<&'a Previous>,
    t_start: f64,
) -> Result<&'a Previous, FullReason> {
    if !policy.enabled {
        return Err(FullReason::Disabled);
    }
    let p = previous.ok_or(FullReason::NewGate)?;
    if !p.trusted {
        return Err(FullReason::Untrusted);
    }
    // After the previous window's start, and no more than `max_gap_windows` window lengths
    // after its end (0: inside it).
    let reach = p.t_end + policy.max_gap_windows * (p.t_end - p.t_start).max(0.0);
    if t_start.is_nan() || t_start <= p.t_start || t_start > reach {
        return Err(FullReason::Gap);
    }
    if p.since_full + 1 >= policy.full_every {
        return Err(FullReason::Schedule);
    }
    if p.coefficients.iter().any(|c| !c.is_finite()) || p.coefficients.is_empty() {
        return Err(FullReason::NewGate);
    }
    Ok(p)
}

/// Whether the refined model's report `r` may stand for the window (see the module docs).
pub fn accept(
    policy: &TrackingPolicy,
    previous: &Previous,
    r: &DampingReport,
) -> Result<(), Rejection> {
    if !r.trusted {
        return Err(Rejection::Untrusted);
    }
    // A change of regime is a change between self-excited and not. Since the ambient SSI-COV
    // estimate decides noise-driven windows, their verdict flips between `Damped` and `Unknown`
    // (an interval across zero) from window to window without any change in the gate: that is
    // no reason to search again.
    let alarm = |v: Verdict| v == Verdict::SelfExcited;
    if alarm(r.verdict) != alarm(previous.verdict) {
        return Err(Rejection::VerdictChanged);
    }
    if let Some(measured_hz) = r.frequency_hz {
        let off = r.model_frequency_hz.map(|m| (m / measured_hz - 1.0).abs());
        // NaN and a model that is no oscillator fail too.
        if !off.is_some_and(|off| off <= policy.frequency_tolerance) {
            return Err(Rejection::Frequency {
                model_hz: r.model_frequency_hz,
                measured_hz,
            });
        }
    }
    if previous.agrees && !r.agrees {
        return Err(Rejection::Disagrees);
    }
    // f64::min ignores NaN: a NaN reference becomes the ceiling too
    let reference = previous.full_fit_nmae.min(MAX_REFERENCE_NMAE);
    let limit = policy.fit_tolerance * reference + FIT_SLACK;
    if r.fit_nmae.is_nan() || r.fit_nmae > limit {
        return Err(Rejection::Fit {
            nmae: r.fit_nmae,
            limit,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn previous() -> Previous {
        Previous {
            coefficients: vec![19.0, -5.0, 1.0],
            full_fit_nmae: 0.02,
            since_full: 0,
            verdict: Verdict::Damped,
            trusted: true,
            agrees: true,
            t_start: 100.0,
            t_end: 109.995,
        }
    }

    fn report() -> DampingReport {
        DampingReport {
            fit_nmae: 0.025,
            agrees: true,
            trusted: true,
            verdict: Verdict::Damped,
            frequency_hz: Some(10.4),
            model_frequency_hz: Some(10.5),
            ..DampingReport::unknown()
        }
    }

    #[test]
    fn plan_tracks_an_overlapping_window_of_a_trusted_gate() {
        let p = previous();
        assert_eq!(plan(&TrackingPolicy::default(), Some(&p), 105.0), Ok(&p));
    }

    #[test]
    fn plan_tracks_across_a_gap_of_up_to_max_gap_windows() {
        let p = previous();
        let policy = TrackingPolicy::default();
        // the previous window is 9.995 s long and ends at 109.995: 5 jobs replaced at a 5 s
        // cadence (the next window starts at 130) is 2.0 window lengths after its end
        for t in [110.0, 115.0, 125.0, 129.9] {
            assert_eq!(plan(&policy, Some(&p), t), Ok(&p), "{t}");
        }
        let one = TrackingPolicy {
            max_gap_windows: 1.0,
            ..TrackingPolicy::default()
        };
        assert_eq!(plan(&one, Some(&p), 119.9), Ok(&p));
        assert_eq!(plan(&one, Some(&p), 120.1), Err(FullReason::Gap));
    }

    #[test]
    fn plan_runs_the_full_search_when_disabled_new_untrusted_gap_or_due() {
        let policy = TrackingPolicy::default();
        let off = TrackingPolicy {
            enabled: false,
            ..TrackingPolicy::default()
        };
        let p = previous();
        assert_eq!(plan(&off, Some(&p), 105.0), Err(FullReason::Disabled));
        assert_eq!(plan(&policy, None, 105.0), Err(FullReason::NewGate));
        let untrusted = Previous {
            trusted: false,
            ..previous()
        };
        assert_eq!(
            plan(&policy, Some(&untrusted), 105.0),
            Err(FullReason::Untrusted)
        );
        // more than max_gap_windows (2) window lengths after the previous window's end, and
        // before its start (time reset)
        assert_eq!(plan(&policy, Some(&p), 130.5), Err(FullReason::Gap));
        assert_eq!(plan(&policy, Some(&p), 90.0), Err(FullReason::Gap));
        // with no gap allowed, just after the previous window's end
        let overlap_only = TrackingPolicy {
            max_gap_windows: 0.0,
            ..TrackingPolicy::default()
        };
        assert_eq!(plan(&overlap_only, Some(&p), 110.5), Err(FullReason::Gap));
        let due = Previous {
            since_full: policy.full_every - 1,
            ..previous()
        };
        assert_eq!(plan(&policy, Some(&due), 105.0), Err(FullReason::Schedule));
        let always = TrackingPolicy {
            full_every: 1,
            ..TrackingPolicy::default()
        };
        assert_eq!(plan(&always, Some(&p), 105.0), Err(FullReason::Schedule));
    }

    #[test]
    fn a_full_search_that_did_not_fit_is_no_reference() {
        let policy = TrackingPolicy::default(); // fit_tolerance 1.5: limit 1.505 at the ceiling
        for full in [f64::NAN, f64::INFINITY, 75.0] {
            let p = Previous {
                full_fit_nmae: full,
                ..previous()
            };
            let with_fit = |fit_nmae| DampingReport {
                fit_nmae,
                ..report()
            };
            assert_eq!(accept(&policy, &p, &with_fit(0.9)), Ok(()), "{full}");
            for bad in [1.6, 80.0, f64::INFINITY, f64::NAN] {
                assert!(
                    matches!(
                        accept(&policy, &p, &with_fit(bad)),
                        Err(Rejection::Fit { limit, .. }) if (limit - 1.505).abs() < 1e-12
                    ),
                    "reference {full}, refined {bad}"
                );
            }
        }
    }

    #[test]
    fn gate_hash_is_the_daemon_s_window_seed_of_before() {
        // values of the hash as `service::worker::window_seed` computed it before it moved here
        // (FNV-1a, splitmix64), from an independent implementation: every window's seed, and so
        // every daemon result, is unchanged
        assert_eq!(gate_hash("g1", 100), 13_601_181_542_038_338_142);
        assert_eq!(gate_hash("weir-north", 0), 9_865_485_673_146_758_496);
    }

    #[test]
    fn gates_started_together_are_scheduled_apart() {
        let policy = TrackingPolicy::default(); // full_every 12
        let mut first_full = std::collections::BTreeMap::new();
        for g in 0..64 {
            let gate = format!("g{g}");
            let mut p = Some(previous().first_of(&gate, &policy));
            // the same name, the same phase
            assert_eq!(p, Some(previous().first_of(&gate, &policy)));
            // windows until the schedule asks for the full search: never more than full_every
            let mut n = 1;
            while plan(&policy, p.as_ref(), 100.0 + 5.0 * n as f64).is_ok() {
                let q = p.take().unwrap();
                p = Some(Previous {
                    since_full: q.since_full + 1,
                    t_start: q.t_start + 5.0,
                    t_end: q.t_end + 5.0,
                    ..q
                });
                n += 1;
            }
            assert!(n <= policy.full_every, "{gate}: {n}");
            *first_full.entry(n).or_insert(0) += 1;
        }
        // 64 gates over 12 phases: each phase has some, none has a quarter of them
        assert_eq!(first_full.len(), policy.full_every, "{first_full:?}");
        assert!(first_full.values().all(|&k| k < 16), "{first_full:?}");
    }

    #[test]
    fn accept_takes_a_refined_model_that_still_fits() {
        assert_eq!(
            accept(&TrackingPolicy::default(), &previous(), &report()),
            Ok(())
        );
    }

    #[test]
    fn accept_refuses_untrusted_disagreeing_changed_or_worse_fits() {
        let (policy, p) = (TrackingPolicy::default(), previous());
        let untrusted = DampingReport {
            trusted: false,
            ..report()
        };
        assert_eq!(accept(&policy, &p, &untrusted), Err(Rejection::Untrusted));
        let disagrees = DampingReport {
            agrees: false,
            ..report()
        };
        assert_eq!(accept(&policy, &p, &disagrees), Err(Rejection::Disagrees));
        // ... unless the previous model disagreed too (an ambient-only gate)
        let p_disagreed = Previous {
            agrees: false,
            ..previous()
        };
        assert_eq!(accept(&policy, &p_disagreed, &disagrees), Ok(()));
        // a 20 % frequency shift, and a model that is no oscillator at rest
        let shifted = DampingReport {
            frequency_hz: Some(12.5),
            ..report()
        };
        assert!(matches!(
            accept(&policy, &p, &shifted),
            Err(Rejection::Frequency { .. })
        ));
        let no_oscillator = DampingReport {
            model_frequency_hz: None,
            ..report()
        };
        assert!(matches!(
            accept(&policy, &p, &no_oscillator),
            Err(Rejection::Frequency { model_hz: None, .. })
        ));
        let onset = DampingReport {
            verdict: Verdict::SelfExcited,
            ..report()
        };
        assert_eq!(accept(&policy, &p, &onset), Err(Rejection::VerdictChanged));
        // limit = 1.5 * 0.02 + 0.005 = 0.035
        let worse = DampingReport {
            fit_nmae: 0.04,
            ..report()
        };
        assert!(matches!(
            accept(&policy, &p, &worse),
            Err(Rejection::Fit { limit, .. }) if (limit - 0.035).abs() < 1e-12
        ));
        let nan = DampingReport {
            fit_nmae: f64::NAN,
            ..report()
        };
        assert!(matches!(
            accept(&policy, &p, &nan),
            Err(Rejection::Fit { .. })
        ));
    }

    #[test]
    fn previous_counts_tracked_windows_and_keeps_the_full_fit() {
        let mut a = WindowAnalysis {
            equation: String::new(),
            coefficients: Vec::new(),
            damping: report(),
            evaluations: 0,
            seconds: 0.0,
            warm_start: vec![1.0, 2.0, 3.0],
            path: Path::Full,
        };
        let full = Previous::after(None, &a, 0.0, 10.0);
        assert_eq!((full.since_full, full.full_fit_nmae), (0, 0.025));
        a.path = Path::Tracked;
        a.damping.fit_nmae = 0.03;
        let tracked = Previous::after(Some(&full), &a, 5.0, 15.0);
        assert_eq!((tracked.since_full, tracked.full_fit_nmae), (1, 0.025));
        assert_eq!(tracked.coefficients, vec![1.0, 2.0, 3.0]);
        assert_eq!((tracked.t_start, tracked.t_end), (5.0, 15.0));
    }

    #[test]
    fn policy_validation_names_the_key() {
        let bad = TrackingPolicy {
            full_every: 0,
            ..TrackingPolicy::default()
        };
        assert!(bad.validate().unwrap_err().starts_with("full_every"));
        let bad = TrackingPolicy {
            fit_tolerance: 0.5,
            ..TrackingPolicy::default()
        };
        assert!(bad.validate().unwrap_err().starts_with("fit_tolerance"));
        for refine_rtol in [0.0, 1.0, f64::NAN] {
            let bad = TrackingPolicy {
                refine_rtol,
                ..TrackingPolicy::default()
            };
            assert!(bad.validate().unwrap_err().starts_with("refine_rtol"));
        }
        for max_gap_windows in [-1.0, MAX_GAP_WINDOWS + 1.0, f64::NAN, f64::INFINITY] {
            let bad = TrackingPolicy {
                max_gap_windows,
                ..TrackingPolicy::default()
            };
            assert!(bad.validate().unwrap_err().starts_with("max_gap_windows"));
        }
        assert_eq!(TrackingPolicy::default().validate(), Ok(()));
    }
}
