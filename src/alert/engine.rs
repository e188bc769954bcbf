//! The per-gate alert state machine: pure (no tokio, no I/O), time passed in explicitly.
//!
//! See `docs/alerts.md` for the state diagram and the reasons behind every transition.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::ser::SerializeMap;
use serde::{Deserialize, Serialize, Serializer};

mod annotations;
pub mod persist;
mod rules;
mod trend_alert;

use annotations::{damping_alert, damping_annotations, stale_alert};
#[cfg(test)]
use annotations::{fmt_hz, fmt_percent, fmt_sig};
pub use rules::{AlertRules, RulesError};
use trend_alert::Declining;

use crate::analysis::{TrendEstimate, Zeta0Source};

/// `alertname` of the alert raised when a gate's identified damping at rest is negative.
pub const ALERT_NEGATIVE_DAMPING: &str = "GateNegativeDamping";
/// `alertname` of the warning raised when a gate's damping trend heads for `fire_below`.
pub const ALERT_DAMPING_DECLINING: &str = "GateDampingDeclining";
/// `alertname` of the alert raised when a gate stopped sending samples.
pub const ALERT_DATA_STALE: &str = "GateDataStale";

/// The displayed state of a gate's damping alert.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GateState {
    /// Damping is fine (or in the hysteresis band without an alert).
    Ok,
    /// Negative damping seen, fewer than `for_windows` consecutive windows so far.
    Pending,
    /// `GateNegativeDamping` is firing.
    Firing,
    /// The alert resolved on the last window; `ok` from the next good window.
    Resolved,
    /// The last window was untrusted / had no damping ratio, or the gate's data is stale.
    Unknown,
}

impl GateState {
    /// The lowercase name, as serialized.
    pub fn as_str(self) -> &'static str {
        match self {
            GateState::Ok => "ok",
            GateState::Pending => "pending",
            GateState::Firing => "firing",
            GateState::Resolved => "resolved",
            GateState::Unknown => "unknown",
        }
    }
}

impl fmt::Display for GateState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One identification result of a gate window.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Observation<'a> {
    /// Damping ratio at rest; negative = self-excited. `None` (or NaN/inf) = unknown.
    pub zeta0: Option<f64>,
    /// 95 % interval `(low, high)` of `zeta0`. `None` = no evidence: the window neither fires
    /// nor resolves `GateNegativeDamping` (it reads as unknown), however confident `zeta0` looks.
    pub zeta0_interval: Option<(f64, f64)>,
    /// Whether the identification is trustworthy enough to act on.
    pub trusted: bool,
    /// The window's signal RMS over the gate's ambient level (`DampingReport::ambient_ratio`;
    /// `None`: no level yet). One window fires at once only when it stands at least
    /// [`at_once_ratio`] of `departure_ratio` (3.5 by default), or the rules'
    /// `fire_at_once_min_ratio`, above it.
    pub ambient_ratio: Option<f64>,
    /// The ratio from which the gate counts as having left its ambient level
    /// (`DampingReport::departure_ratio`: 3 on a gate whose windows hold 50 cycles or more,
    /// more on a slower one); `None`: [`AT_ONCE_MIN_AMBIENT_RATIO`] (an at-once bar of
    /// [`AT_ONCE_FLOOR`]).
    pub departure_ratio: Option<f64>,
    /// Whether the spectrum classified the window as a limit cycle (`DampingReport::regime`
    /// is [`crate::spectral::Regime::LimitCycle`]): a steady oscillation, an envelope far
    /// steadier than a noise-driven response's. Standing at least [`at_once_ratio`] above the
    /// gate's ambient level it reads negative whatever its interval, with the rules'
    /// `fire_on_limit_cycle` (docs/alerts.md, "A steady cycle far above the ambient level").
    pub limit_cycle: bool,
    /// Whether the spectrum classified the window as self-excited (`DampingReport::regime` is
    /// [`crate::spectral::Regime::SelfExcited`]): its envelope grows significantly (or its
    /// ambient interval lies below zero). Standing at least [`at_once_ratio`] above the gate's
    /// ambient level it reads negative whatever its interval, with the rules' `fire_on_growth`
    /// (docs/alerts.md, "A growing oscillation far above the ambient level").
    pub growing: bool,
    /// Frequency of the (self-excited) oscillation, Hz.
    pub frequency_hz: Option<f64>,
    /// Where `zeta0` comes from (`DampingReport::zeta0_source`): the annotations credit the
    /// identified equation only when it is [`Zeta0Source::Model`]. `None`: not reported.
    pub zeta0_source: Option<Zeta0Source>,
    /// Predicted amplitude of the limit cycle, in [`Self::amplitude_unit`].
    pub limit_cycle_amplitude: Option<f64>,
    /// The unit of the gate's signal and of `limit_cycle_amplitude` (`N` in force mode, `m` in
    /// displacement mode); empty: not said.
    pub amplitude_unit: &'a str,
    /// Predicted time until the amplitude limit is reached, seconds.
    pub time_to_limit: Option<f64>,
    /// The identified equation of motion, as text.
    pub equation: &'a str,
    /// The gate's trend of `zeta0` up to and including this window (see
    /// [`crate::analysis::DampingTrend`]); `None` = not enough windows with an interval yet.
    /// Drives `GateDampingDeclining`.
    pub trend: Option<TrendEstimate>,
}

/// One alert instance, as Alertmanager understands it.
#[derive(Debug, Clone, PartialEq)]
pub struct Alert {
    /// [`ALERT_NEGATIVE_DAMPING`], [`ALERT_DAMPING_DECLINING`] or [`ALERT_DATA_STALE`].
    pub name: String,
    /// `alertname`, `gate`, `severity`.
    pub labels: BTreeMap<String, String>,
    /// `summary`, `description`, and for negative damping `damping_ratio`, `zeta0_source`,
    /// `frequency_hz`, `limit_cycle_amplitude`, `time_to_limit_seconds`, `equation` (each only
    /// when known).
    pub annotations: BTreeMap<String, String>,
    /// When the condition started (first negative window, or detection of staleness).
    pub starts_at: SystemTime,
    /// Set when the alert resolved.
    pub ends_at: Option<SystemTime>,
    /// Alertmanager's fingerprint of the labels (FNV-1a 64 over sorted labels, 16 hex chars).
    pub fingerprint: String,
}

impl Alert {
    fn new(
        name: &str,
        gate: &str,
        severity: &str,
        annotations: BTreeMap<String, String>,
        starts_at: SystemTime,
    ) -> Alert {
        let mut labels = BTreeMap::new();
        labels.insert("alertname".to_string(), name.to_string());
        labels.insert("gate".to_string(), gate.to_string());
        labels.insert("severity".to_string(), severity.to_string());
        let fingerprint = fingerprint(&labels);
        Alert {
            name: name.to_string(),
            labels,
            annotations,
            starts_at,
            ends_at: None,
            fingerprint,
        }
    }

    /// The `gate` label.
    pub fn gate(&self) -> &str {
        self.labels.get("gate").map(String::as_str).unwrap_or("")
    }

    /// `"firing"` or `"resolved"` (resolved iff `ends_at` is set).
    pub fn status(&self) -> &'static str {
        if self.ends_at.is_some() {
            "resolved"
        } else {
            "firing"
        }
    }
}

/// JSON view for the daemon's HTTP API: `{name, status, labels, annotations, startsAt,
/// endsAt (null while firing), fingerprint}`, timestamps in RFC 3339.
impl Serialize for Alert {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut m = serializer.serialize_map(Some(7))?;
        m.serialize_entry("name", &self.name)?;
        m.serialize_entry("status", self.status())?;
        m.serialize_entry("labels", &self.labels)?;
        m.serialize_entry("annotations", &self.annotations)?;
        m.serialize_entry("startsAt", &rfc3339(self.starts_at))?;
        m.serialize_entry("endsAt", &self.ends_at.map(rfc3339))?;
        m.serialize_entry("fingerprint", &self.fingerprint)?;
        m.end()
    }
}

/// A transition that must be notified.
#[derive(Debug, Clone, PartialEq)]
pub enum AlertEvent {
    /// An alert started firing.
    Firing(Alert),
    /// An alert resolved; its `ends_at` is set.
    Resolved(Alert),
}

impl AlertEvent {
    /// The alert of the event.
    pub fn alert(&self) -> &Alert {
        match self {
            AlertEvent::Firing(a) | AlertEvent::Resolved(a) => a,
        }
    }

    /// The alert of the event, by value.
    pub fn into_alert(self) -> Alert {
        match self {
            AlertEvent::Firing(a) | AlertEvent::Resolved(a) => a,
        }
    }

    /// Whether this is a `Firing` event.
    pub fn is_firing(&self) -> bool {
        matches!(self, AlertEvent::Firing(_))
    }

    /// `"firing"` or `"resolved"`.
    pub fn status(&self) -> &'static str {
        if self.is_firing() {
            "firing"
        } else {
            "resolved"
        }
    }
}

/// Alertmanager's label-set fingerprint (`prometheus/common/model.LabelSet.Fingerprint`):
/// FNV-1a 64 over the labels sorted by name, each name and value followed by the byte 0xff,
/// printed as 16 lowercase hex digits.
pub fn fingerprint(labels: &BTreeMap<String, String>) -> String {
    const OFFSET: u64 = 14_695_981_039_346_656_037;
    const PRIME: u64 = 1_099_511_628_211;
    const SEPARATOR: u8 = 0xff;
    let mut h = OFFSET;
    let mut add = |bytes: &[u8]| {
        for &b in bytes {
            h ^= u64::from(b);
            h = h.wrapping_mul(PRIME);
        }
    };
    // BTreeMap iterates in byte order of the names, like Go's sort of strings.
    for (name, value) in labels {
        add(name.as_bytes());
        add(&[SEPARATOR]);
        add(value.as_bytes());
        add(&[SEPARATOR]);
    }
    format!("{h:016x}")
}

/// RFC 3339 with milliseconds, UTC (`2024-05-01T12:00:00.000Z`). Times before 1970 or after
/// year 9999 are clamped (the formatter cannot represent them), so this never panics.
pub fn rfc3339(t: SystemTime) -> String {
    const MAX_SECS: u64 = 253_402_300_799; // 9999-12-31T23:59:59Z
    let clamped = match t.duration_since(UNIX_EPOCH) {
        Err(_) => UNIX_EPOCH,
        Ok(d) if d.as_secs() > MAX_SECS => UNIX_EPOCH + Duration::new(MAX_SECS, 999_000_000),
        Ok(_) => t,
    };
    humantime::format_rfc3339_millis(clamped).to_string()
}

/// The base of the at-once bar ([`at_once_ratio`], which never lies below [`AT_ONCE_FLOOR`]): how
/// far above its ambient level a window must stand before it alone may fire
/// `GateNegativeDamping` (`fire_at_once_probability`), the ratio at which a window shows that the
/// gate has left its ambient state ([`crate::analysis::DEPARTED_FROM_AMBIENT`]). Why: on a stable
/// +0.5 % lock gate a free-vibration model read -0.6 to -2.5 % with intervals 0.2 to 0.7 points
/// wide on about one window an hour at the ambient level (`docs/alerts.md`, "One window at
/// once"); a gate that self-excites leaves its ambient level within the window that shows it.
pub const AT_ONCE_MIN_AMBIENT_RATIO: f64 = crate::analysis::DEPARTED_FROM_AMBIENT;

/// How much further above [`AT_ONCE_MIN_AMBIENT_RATIO`] the at-once bar lies than the gate's
/// departure ratio does ([`at_once_ratio`]): twice as far.
pub const AT_ONCE_MARGIN_FACTOR: f64 = 2.0;

/// The lowest at-once bar on any gate ([`at_once_ratio`]): 3.5, the ratio above which a stable
/// +0.5 % lock gate (50 cycles a window) is expected to page by chance at most once in 20 days.
///
/// # Why 3.5 and not the departure ratio's 3
/// A chance page needs two things: a window that far above the level, and a model that reads
/// it as growth with 97.5 % confidence. In nine days of the lock gate at +0.5 %
/// (`bench warning --gates lock --scenarios stable-low --hours 24 --trace`, seeds 1 to 9)
/// windows stood at least 2.5, 2.75, 3 and 3.25 times above the level 17.7, 5.1, 1.6 and 0.3
/// times a day: the rate falls about e-fold for each 0.21 of ratio (4.85 per unit, fitted from
/// 2.5 to 3). Of the 14 windows from 3 up, 4 were reported by the model with their 95 %
/// interval below zero (29 %). At the bar of 3 that is `1.56 x 0.29 = 0.45` pages a day, and
/// the replay of those days paged 4 times (seeds 1, 6 twice, 7). For at most 0.05 a day (a
/// quiet day 95 % of the time) the bar must stand `ln(0.45 / 0.05) / 4.85 = 0.45` higher:
/// 3.5 (3.3, tried first, left seed 7's window at 3.35 and one page in nine days). The cost on
/// the lock gate's onset ramp (20 seeds): 4 of its 20 first at-once windows stood at 3.16 to
/// 3.48 times the level; three page 5 s later, still when the damping reaches -1 %, and one
/// (3.48) 5 s after it. The lab gate's onset windows stand 4.6 times or more above its level
/// when they fire, so its onset does not move.
pub const AT_ONCE_FLOOR: f64 = 3.5;

/// The ratio above its ambient level from which one window may fire `GateNegativeDamping` at
/// once, for a gate whose departure ratio is `departure` (`None`: unknown, 3):
/// `3 + 2 (departure - 3)`, at least [`AT_ONCE_FLOOR`] (3.5). That is 3.5 where the windows
/// hold about 38 cycles or more (the lab and lock gates), 4.68 where they hold 20 (a 2 Hz gate
/// with 10 s windows).
///
/// # Why further than the departure ratio
/// The departure ratio makes a stable gate's chance excursions as rare on every gate as on the
/// lock gate at 3. An at-once page needs the model to read that excursion as growth as well, and
/// the fewer cycles a window holds, the more often it does: on stable +0.5 % gates, of the
/// windows at least twice the level, 12 % of the lock gate's (50 cycles a window, 12 h) and 21 % of a
/// 2 Hz barrier gate's (20 cycles) had a model interval below zero. At the departure ratio the
/// barrier gate paged 4 times in 8 days of stream (`bench warning --gates barrier --scenarios
/// stable-low --hours 24`, seeds 1 to 8), each on an excursion 3.92 to 4.17 times its level;
/// none of its windows in those days stood 4.6 times above it. By the floor's reckoning (its
/// windows stood 3.5 times above the level 5.9 times a day, falling e-fold per 0.29 of ratio,
/// and the model read 31 % of those from 3 up as growth) 4.68 means 0.03 chance pages a day. A slow
/// gate can afford the wait: a 5 s hop holds 10 of its cycles, in which an onset at -1 % grows
/// 1.9-fold (the lab gate's 52 cycles: 26-fold). Measured cost on the barrier's onset (20
/// seeds): `GateNegativeDamping` 5 to 10 s later on 7 seeds, and on the first burst 5 s later
/// on 2 (docs/benchmarks.md, "The at-once bar on a slow gate (session 42)").
/// A site overrides it per gate with `fire_at_once_min_ratio`.
pub fn at_once_ratio(departure: Option<f64>) -> f64 {
    let d = departure.unwrap_or(AT_ONCE_MIN_AMBIENT_RATIO);
    let margin = AT_ONCE_MARGIN_FACTOR * (d - AT_ONCE_MIN_AMBIENT_RATIO).max(0.0);
    (AT_ONCE_MIN_AMBIENT_RATIO + margin).max(AT_ONCE_FLOOR)
}

/// How one window reads under a gate's rules.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reading {
    /// Untrusted, or no (finite) damping ratio, or no (finite) interval: no evidence.
    Unknown,
    /// The interval lies below `fire_below` (or `P(zeta0 < fire_below) >= fire_probability`);
    /// `at_once` when `P(zeta0 < fire_below) >= fire_at_once_probability`.
    Negative { at_once: bool },
    /// Neither negative nor good: hysteresis band, or an interval too wide to tell.
    Band,
    /// `P(zeta0 >= clear_above) >= resolve_probability` (and the window is not negative).
    Good,
}

fn classify(obs: &Observation, rules: &AlertRules) -> Reading {
    match classify_interval(obs, rules) {
        Reading::Negative { at_once } => Reading::Negative { at_once },
        // not negative by its interval, but a steady cycle or a growing oscillation far above
        // the ambient level: the sign is the regime's (never at once: two such windows, or one
        // and a confident one)
        _ if regime_evidence(obs, rules).is_some() => Reading::Negative { at_once: false },
        other => other,
    }
}

/// How far above its ambient level a window of this gate must stand to fire at once, and for
/// a limit-cycle or growing window to read negative by its regime.
fn at_once_bar(obs: &Observation, rules: &AlertRules) -> f64 {
    rules
        .fire_at_once_min_ratio
        .unwrap_or_else(|| at_once_ratio(obs.departure_ratio))
}

/// What a window read negative by its regime alone shows (the alert's `evidence` annotation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum RegimeEvidence {
    /// A steady cycle far above the ambient level (`fire_on_limit_cycle`).
    LimitCycle,
    /// A growing oscillation far above the ambient level (`fire_on_growth`).
    Growth,
}

impl RegimeEvidence {
    /// The `evidence` annotation's value.
    pub(super) fn as_str(self) -> &'static str {
        match self {
            RegimeEvidence::LimitCycle => "limit_cycle",
            RegimeEvidence::Growth => "growth",
        }
    }
}

/// Whether the window reads negative by its regime alone, and as what: the spectrum
/// classified it a limit cycle (with the rules' `fire_on_limit_cycle`) or self-excited (with
/// `fire_on_growth`), and it stands at least the at-once bar above the gate's ambient level.
/// Whatever its interval and the fit's trust: a gate that holds a steady oscillation, or whose
/// oscillation grows, several times above its own ambient level is self-excited whatever the
/// size of its damping, and the first such windows' readings are wide or untrusted (a lone
/// first cycle window always is). Why not on a stable gate: its windows stand 3.5 times above
/// its level a few times a week at most, and then as a noise-driven excursion, whose envelope
/// is Rayleigh's, neither a cycle's nor one that grows by three standard errors
/// (docs/alerts.md, "A steady cycle far above the ambient level", "A growing oscillation far
/// above the ambient level").
fn regime_evidence(obs: &Observation, rules: &AlertRules) -> Option<RegimeEvidence> {
    let far = obs
        .ambient_ratio
        .is_some_and(|r| r >= at_once_bar(obs, rules));
    if !far {
        None
    } else if rules.fire_on_limit_cycle && obs.limit_cycle {
        Some(RegimeEvidence::LimitCycle)
    } else if rules.fire_on_growth && obs.growing {
        Some(RegimeEvidence::Growth)
    } else {
        None
    }
}

/// What the window shows when it reads negative by its regime and not by its interval: what
/// the alert's annotations then say (`evidence = "limit_cycle"` or `"growth"`).
pub(super) fn negative_by_regime_only(
    obs: &Observation,
    rules: &AlertRules,
) -> Option<RegimeEvidence> {
    regime_evidence(obs, rules)
        .filter(|_| !matches!(classify_interval(obs, rules), Reading::Negative { .. }))
}

/// The reading of the window's interval alone.
fn classify_interval(obs: &Observation, rules: &AlertRules) -> Reading {
    let (Some(z), Some((low, high))) = (obs.zeta0, obs.zeta0_interval) else {
        return Reading::Unknown;
    };
    if !(obs.trusted && z.is_finite() && low.is_finite() && high.is_finite()) || low > high {
        return Reading::Unknown;
    }
    let negative = match rules.fire_probability {
        Some(p) => AlertRules::probability_below(low, high, rules.fire_below) >= p,
        None => high < rules.fire_below,
    };
    if negative {
        let departed = obs
            .ambient_ratio
            .is_some_and(|r| r >= at_once_bar(obs, rules));
        Reading::Negative {
            at_once: departed && rules.fires_at_once(low, high),
        }
    } else if rules.reads_good(low, high) {
        Reading::Good
    } else {
        Reading::Band
    }
}

/// The counting part of a gate's damping state machine.
#[derive(Debug, Clone)]
enum Phase {
    Ok,
    Pending { negatives: u32, since: SystemTime },
    Firing { alert: Alert, good: u32 },
}

#[derive(Debug, Clone)]
struct GateTrack {
    phase: Phase,
    displayed: GateState,
    last_seen: Option<SystemTime>,
    stale: Option<Alert>,
    declining: Declining,
}

impl GateTrack {
    fn new() -> Self {
        GateTrack {
            phase: Phase::Ok,
            displayed: GateState::Unknown,
            last_seen: None,
            stale: None,
            declining: Declining::default(),
        }
    }
}

/// The alert state of all gates.
#[derive(Debug, Clone)]
pub struct AlertEngine {
    defaults: AlertRules,
    overrides: HashMap<String, AlertRules>,
    gates: BTreeMap<String, GateTrack>,
}

impl AlertEngine {
    /// An engine with `rules` for every gate without an override.
    pub fn new(rules: AlertRules) -> Self {
        AlertEngine {
            defaults: rules,
            overrides: HashMap::new(),
            gates: BTreeMap::new(),
        }
    }

    /// Per-gate override of the rules. Takes effect from the next call concerning the gate;
    /// counters in progress are kept, and an alert already firing keeps its labels (so its
    /// fingerprint) until it resolves.
    pub fn set_rules(&mut self, gate: &str, rules: AlertRules) {
        self.overrides.insert(gate.to_string(), rules);
    }

    /// The rules in force for `gate`.
    pub fn rules(&self, gate: &str) -> &AlertRules {
        self.overrides.get(gate).unwrap_or(&self.defaults)
    }

    /// Feed one identification result of `gate`. Returns the transitions to notify (at most one
    /// per alert: `GateDampingDeclining` first, then `GateNegativeDamping`).
    ///
    /// This does not touch the staleness clock: call [`AlertEngine::data_seen`] when samples
    /// arrive (re-identifying an old window must not hide that the gate went silent).
    pub fn observe(&mut self, gate: &str, obs: &Observation, now: SystemTime) -> Vec<AlertEvent> {
        let rules = self.overrides.get(gate).unwrap_or(&self.defaults);
        let track = track_mut(&mut self.gates, gate);
        let mut events = Vec::new();
        events.extend(track.declining.observe(gate, rules, obs, now));
        match classify(obs, rules) {
            Reading::Unknown => {
                track.displayed = GateState::Unknown;
                match &mut track.phase {
                    // An unknown window breaks the streak of consecutive negative windows.
                    Phase::Pending { .. } => track.phase = Phase::Ok,
                    // ... and the streak of consecutive good windows; the alert keeps firing.
                    Phase::Firing { good, .. } => *good = 0,
                    Phase::Ok => {}
                }
            }
            Reading::Negative { at_once } => match &mut track.phase {
                Phase::Ok => {
                    if rules.for_windows() <= 1 || at_once {
                        let alert = damping_alert(gate, rules, obs, now);
                        events.push(AlertEvent::Firing(alert.clone()));
                        track.phase = Phase::Firing { alert, good: 0 };
                        track.displayed = GateState::Firing;
                    } else {
                        track.phase = Phase::Pending {
                            negatives: 1,
                            since: now,
                        };
                        track.displayed = GateState::Pending;
                    }
                }
                Phase::Pending { negatives, since } => {
                    *negatives = negatives.saturating_add(1);
                    if *negatives >= rules.for_windows() || at_once {
                        let alert = damping_alert(gate, rules, obs, *since);
                        events.push(AlertEvent::Firing(alert.clone()));
                        track.phase = Phase::Firing { alert, good: 0 };
                        track.displayed = GateState::Firing;
                    } else {
                        track.displayed = GateState::Pending;
                    }
                }
                Phase::Firing { alert, good } => {
                    *good = 0;
                    // Keep labels and startsAt; refresh the figures for re-sends.
                    alert.annotations = damping_annotations(gate, rules, obs);
                    track.displayed = GateState::Firing;
                }
            },
            Reading::Band => match &mut track.phase {
                Phase::Firing { good, .. } => {
                    *good = 0;
                    track.displayed = GateState::Firing;
                }
                Phase::Ok | Phase::Pending { .. } => {
                    track.phase = Phase::Ok;
                    track.displayed = GateState::Ok;
                }
            },
            Reading::Good => match &mut track.phase {
                Phase::Firing { alert, good } => {
                    *good = good.saturating_add(1);
                    if *good >= rules.resolve_windows() {
                        let mut resolved = alert.clone();
                        resolved.ends_at = Some(now);
                        events.push(AlertEvent::Resolved(resolved));
                        track.phase = Phase::Ok;
                        track.displayed = GateState::Resolved;
                    } else {
                        track.displayed = GateState::Firing;
                    }
                }
                Phase::Ok | Phase::Pending { .. } => {
                    track.phase = Phase::Ok;
                    track.displayed = GateState::Ok;
                }
            },
        }
        events
    }

    /// Samples of `gate` arrived at `now`: restarts its staleness clock (the gate counts as seen
    /// from now on) and resolves its `GateDataStale` alert if one is firing.
    pub fn data_seen(&mut self, gate: &str, now: SystemTime) -> Vec<AlertEvent> {
        let track = track_mut(&mut self.gates, gate);
        track.last_seen = Some(now);
        match track.stale.take() {
            Some(mut alert) => {
                alert.ends_at = Some(now);
                vec![AlertEvent::Resolved(alert)]
            }
            None => Vec::new(),
        }
    }

    /// Fire `GateDataStale` for every gate seen at least once (via [`AlertEngine::data_seen`])
    /// whose last samples are at least `stale_after_seconds` old. Fires once per silence.
    /// A clock that went backwards counts as no time elapsed.
    pub fn check_stale(&mut self, now: SystemTime) -> Vec<AlertEvent> {
        let mut events = Vec::new();
        for (gate, track) in self.gates.iter_mut() {
            let rules = self.overrides.get(gate).unwrap_or(&self.defaults);
            let (Some(last), None, Some(after)) =
                (track.last_seen, track.stale.as_ref(), rules.stale_after())
            else {
                continue;
            };
            let elapsed = now.duration_since(last).unwrap_or(Duration::ZERO);
            if elapsed < after {
                continue;
            }
            let alert = stale_alert(gate, rules, last, elapsed, now);
            events.push(AlertEvent::Firing(alert.clone()));
            track.stale = Some(alert);
            // The last identified state no longer describes the gate.
            track.displayed = GateState::Unknown;
        }
        events
    }

    /// Displayed state of `gate`'s damping alert; `None` for a gate never observed nor seen.
    pub fn state(&self, gate: &str) -> Option<GateState> {
        self.gates.get(gate).map(|t| t.displayed)
    }

    /// Whether `gate` has a firing `GateNegativeDamping` alert (its displayed state may be
    /// `unknown` meanwhile, after an untrusted window).
    pub fn is_firing(&self, gate: &str) -> bool {
        matches!(
            self.gates.get(gate).map(|t| &t.phase),
            Some(Phase::Firing { .. })
        )
    }

    /// Names of all gates known to the engine, sorted.
    pub fn gates(&self) -> Vec<String> {
        self.gates.keys().cloned().collect()
    }

    /// Every firing alert, by gate (sorted), then `GateNegativeDamping`, `GateDataStale`,
    /// `GateDampingDeclining`, for periodic re-sending.
    pub fn firing(&self) -> Vec<Alert> {
        let mut out = Vec::new();
        for track in self.gates.values() {
            if let Phase::Firing { alert, .. } = &track.phase {
                out.push(alert.clone());
            }
            if let Some(alert) = &track.stale {
                out.push(alert.clone());
            }
            if let Some(alert) = track.declining.alert() {
                out.push(alert.clone());
            }
        }
        out
    }

    /// The firing alerts of one gate (damping first, then stale, then the declining warning): what a per-gate view needs,
    /// without copying every gate's alerts as [`AlertEngine::firing`] does.
    pub fn firing_of(&self, gate: &str) -> Vec<Alert> {
        let Some(track) = self.gates.get(gate) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        if let Phase::Firing { alert, .. } = &track.phase {
            out.push(alert.clone());
        }
        out.extend(track.stale.clone());
        // the warning too: the gate's view (API, bench) showed every firing alert but this one
        out.extend(track.declining.alert().cloned());
        out
    }

    /// Whether `gate`'s `GateDataStale` alert is firing.
    pub fn is_stale(&self, gate: &str) -> bool {
        self.gates.get(gate).is_some_and(|t| t.stale.is_some())
    }

    /// Forget `gate` (removed from the configuration): resolves its firing alerts at `now` and
    /// drops its state and rule override.
    pub fn remove_gate(&mut self, gate: &str, now: SystemTime) -> Vec<AlertEvent> {
        self.overrides.remove(gate);
        let Some(track) = self.gates.remove(gate) else {
            return Vec::new();
        };
        let mut events = Vec::new();
        if let Phase::Firing { mut alert, .. } = track.phase {
            alert.ends_at = Some(now);
            events.push(AlertEvent::Resolved(alert));
        }
        if let Some(mut alert) = track.stale {
            alert.ends_at = Some(now);
            events.push(AlertEvent::Resolved(alert));
        }
        if let Some(mut alert) = track.declining.into_alert() {
            alert.ends_at = Some(now);
            events.push(AlertEvent::Resolved(alert));
        }
        events
    }

    /// Whether `gate` has a firing `GateDampingDeclining` warning.
    pub fn is_declining(&self, gate: &str) -> bool {
        self.gates
            .get(gate)
            .is_some_and(|t| t.declining.alert().is_some())
    }
}

fn track_mut<'m>(gates: &'m mut BTreeMap<String, GateTrack>, gate: &str) -> &'m mut GateTrack {
    if !gates.contains_key(gate) {
        gates.insert(gate.to_string(), GateTrack::new());
    }
    gates
        .get_mut(gate)
        .expect("invariant: the gate was inserted just above")
}

#[cfg(test)]
mod interval_tests;
#[cfg(test)]
mod tests;
