//! The per-gate alert state machine: pure (no tokio, no I/O), time passed in explicitly.
//!
//! See `docs/alerts.md` for the state diagram and the reasons behind every transition.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::ser::SerializeMap;
use serde::{Deserialize, Serialize, Serializer};

/// `alertname` of the alert raised when a gate's identified damping at rest is negative.
pub const ALERT_NEGATIVE_DAMPING: &str = "GateNegativeDamping";
/// `alertname` of the alert raised when a gate stopped sending samples.
pub const ALERT_DATA_STALE: &str = "GateDataStale";

/// Thresholds and timing of the alert rules (global, or per gate via
/// [`AlertEngine::set_rules`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlertRules {
    /// `zeta0` strictly below this counts as negative damping (default 0.0).
    pub fire_below: f64,
    /// Hysteresis: a firing alert resolves only on windows with `zeta0 >= clear_above`
    /// (default 0.005).
    pub clear_above: f64,
    /// Consecutive negative trusted windows before firing (default 2; 0 acts as 1).
    pub for_windows: u32,
    /// Consecutive windows with `zeta0 >= clear_above` before resolving (default 2; 0 acts as 1).
    pub resolve_windows: u32,
    /// No samples for this long (wall clock) fires `GateDataStale` (default 30). A value that
    /// is not a positive finite number disables the staleness check.
    pub stale_after_seconds: f64,
    /// Value of the `severity` label (default "critical").
    pub severity: String,
}

impl Default for AlertRules {
    fn default() -> Self {
        AlertRules {
            fire_below: 0.0,
            clear_above: 0.005,
            for_windows: 2,
            resolve_windows: 2,
            stale_after_seconds: 30.0,
            severity: "critical".to_string(),
        }
    }
}

/// A rule set that makes no sense (see [`AlertRules::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RulesError {
    /// A threshold is NaN or infinite.
    #[error("alert rule `{0}` must be a finite number")]
    NotFinite(&'static str),
    /// `clear_above < fire_below`: there would be no hysteresis band, windows could be
    /// negative and "good" at once.
    #[error("alert rule clear_above ({clear_above}) must be >= fire_below ({fire_below})")]
    ClearBelowFire { fire_below: f64, clear_above: f64 },
    /// `stale_after_seconds` is not a positive finite number.
    #[error("alert rule stale_after_seconds must be a positive finite number, got {0}")]
    BadStaleAfter(f64),
    /// The severity label is empty.
    #[error("alert rule severity must not be empty")]
    EmptySeverity,
}

impl AlertRules {
    /// Check the rules for consistency. The engine never panics on invalid rules (it behaves as
    /// documented on each field), but a daemon should reject them when loading its config.
    pub fn validate(&self) -> Result<(), RulesError> {
        if !self.fire_below.is_finite() {
            return Err(RulesError::NotFinite("fire_below"));
        }
        if !self.clear_above.is_finite() {
            return Err(RulesError::NotFinite("clear_above"));
        }
        if self.clear_above < self.fire_below {
            return Err(RulesError::ClearBelowFire {
                fire_below: self.fire_below,
                clear_above: self.clear_above,
            });
        }
        if !(self.stale_after_seconds.is_finite() && self.stale_after_seconds > 0.0) {
            return Err(RulesError::BadStaleAfter(self.stale_after_seconds));
        }
        if self.severity.trim().is_empty() {
            return Err(RulesError::EmptySeverity);
        }
        Ok(())
    }

    fn for_windows(&self) -> u32 {
        self.for_windows.max(1)
    }

    fn resolve_windows(&self) -> u32 {
        self.resolve_windows.max(1)
    }

    fn stale_after(&self) -> Option<Duration> {
        if self.stale_after_seconds.is_finite() && self.stale_after_seconds > 0.0 {
            Duration::try_from_secs_f64(self.stale_after_seconds).ok()
        } else {
            None
        }
    }
}

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
    /// Whether the identification is trustworthy enough to act on.
    pub trusted: bool,
    /// Frequency of the (self-excited) oscillation, Hz.
    pub frequency_hz: Option<f64>,
    /// Predicted amplitude of the limit cycle.
    pub limit_cycle_amplitude: Option<f64>,
    /// Predicted time until the amplitude limit is reached, seconds.
    pub time_to_limit: Option<f64>,
    /// The identified equation of motion, as text.
    pub equation: &'a str,
}

/// One alert instance, as Alertmanager understands it.
#[derive(Debug, Clone, PartialEq)]
pub struct Alert {
    /// [`ALERT_NEGATIVE_DAMPING`] or [`ALERT_DATA_STALE`].
    pub name: String,
    /// `alertname`, `gate`, `severity`.
    pub labels: BTreeMap<String, String>,
    /// `summary`, `description`, and for negative damping `damping_ratio`, `frequency_hz`,
    /// `limit_cycle_amplitude`, `time_to_limit_seconds`, `equation` (each only when known).
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

/// How one window reads under a gate's rules.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reading {
    /// Untrusted, or no (finite) damping ratio.
    Unknown,
    /// `zeta0 < fire_below`.
    Negative,
    /// `fire_below <= zeta0 < clear_above`: hysteresis band.
    Band,
    /// `zeta0 >= clear_above` (and not negative).
    Good,
}

fn classify(obs: &Observation, rules: &AlertRules) -> Reading {
    match obs.zeta0 {
        Some(z) if obs.trusted && z.is_finite() => {
            if z < rules.fire_below {
                Reading::Negative
            } else if z >= rules.clear_above {
                Reading::Good
            } else {
                Reading::Band
            }
        }
        _ => Reading::Unknown,
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
}

impl GateTrack {
    fn new() -> Self {
        GateTrack {
            phase: Phase::Ok,
            displayed: GateState::Unknown,
            last_seen: None,
            stale: None,
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

    /// Feed one identification result of `gate`. Returns the transitions to notify (at most one).
    ///
    /// This does not touch the staleness clock: call [`AlertEngine::data_seen`] when samples
    /// arrive (re-identifying an old window must not hide that the gate went silent).
    pub fn observe(&mut self, gate: &str, obs: &Observation, now: SystemTime) -> Vec<AlertEvent> {
        let rules = self.overrides.get(gate).unwrap_or(&self.defaults);
        let track = track_mut(&mut self.gates, gate);
        let mut events = Vec::new();
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
            Reading::Negative => match &mut track.phase {
                Phase::Ok => {
                    if rules.for_windows() <= 1 {
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
                    if *negatives >= rules.for_windows() {
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

    /// Every firing alert (both kinds), sorted by gate then alert name, for periodic re-sending.
    pub fn firing(&self) -> Vec<Alert> {
        let mut out = Vec::new();
        for track in self.gates.values() {
            if let Phase::Firing { alert, .. } = &track.phase {
                out.push(alert.clone());
            }
            if let Some(alert) = &track.stale {
                out.push(alert.clone());
            }
        }
        out
    }

    /// The firing alerts of one gate (damping first, then stale): what a per-gate view needs,
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
        events
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

fn finite(x: Option<f64>) -> Option<f64> {
    x.filter(|v| v.is_finite())
}

/// A percentage with one decimal, or one significant digit below 1 %.
fn fmt_percent(ratio: f64) -> String {
    let p = ratio * 100.0;
    let a = p.abs();
    if a >= 1.0 || a == 0.0 {
        format!("{p:.1}")
    } else {
        let decimals = (-a.log10()).ceil().clamp(1.0, 9.0) as usize;
        format!("{p:.decimals$}")
    }
}

fn fmt_hz(f: f64) -> String {
    if f.abs() >= 1.0 {
        format!("{f:.1}")
    } else {
        format!("{f:.3}")
    }
}

fn damping_annotations(
    gate: &str,
    rules: &AlertRules,
    obs: &Observation,
) -> BTreeMap<String, String> {
    let mut a = BTreeMap::new();
    let zeta = finite(obs.zeta0);
    let freq = finite(obs.frequency_hz);
    let amp = finite(obs.limit_cycle_amplitude);
    let ttl = finite(obs.time_to_limit);
    let pct = zeta.map(fmt_percent).unwrap_or_else(|| "?".to_string());
    let summary = match freq {
        Some(f) => format!(
            "gate {gate}: damping ratio {pct} % (self-excited vibration at {} Hz)",
            fmt_hz(f)
        ),
        None => format!("gate {gate}: damping ratio {pct} % (self-excited vibration)"),
    };
    let mut description = format!(
        "The equation of motion identified for gate {gate} has negative damping at rest \
         (damping ratio {pct} %, below {} %): oscillations grow by themselves.",
        fmt_percent(rules.fire_below)
    );
    if let Some(a) = amp {
        description.push_str(&format!(" Predicted limit-cycle amplitude: {a}."));
    }
    if let Some(t) = ttl {
        description.push_str(&format!(" Time to reach the amplitude limit: {t:.1} s."));
    }
    if !obs.equation.is_empty() {
        description.push_str(&format!(" Identified equation: {}", obs.equation));
    }
    a.insert("summary".to_string(), summary);
    a.insert("description".to_string(), description);
    if let Some(z) = zeta {
        a.insert("damping_ratio".to_string(), z.to_string());
    }
    if let Some(f) = freq {
        a.insert("frequency_hz".to_string(), f.to_string());
    }
    if let Some(v) = amp {
        a.insert("limit_cycle_amplitude".to_string(), v.to_string());
    }
    if let Some(t) = ttl {
        a.insert("time_to_limit_seconds".to_string(), t.to_string());
    }
    if !obs.equation.is_empty() {
        a.insert("equation".to_string(), obs.equation.to_string());
    }
    a
}

fn damping_alert(
    gate: &str,
    rules: &AlertRules,
    obs: &Observation,
    starts_at: SystemTime,
) -> Alert {
    Alert::new(
        ALERT_NEGATIVE_DAMPING,
        gate,
        &rules.severity,
        damping_annotations(gate, rules, obs),
        starts_at,
    )
}

fn stale_alert(
    gate: &str,
    rules: &AlertRules,
    last_seen: SystemTime,
    elapsed: Duration,
    now: SystemTime,
) -> Alert {
    let secs = elapsed.as_secs();
    let mut a = BTreeMap::new();
    a.insert(
        "summary".to_string(),
        format!("gate {gate}: no data for {secs} s"),
    );
    a.insert(
        "description".to_string(),
        format!(
            "No samples from gate {gate} since {} (limit {} s): its damping is not monitored.",
            rfc3339(last_seen),
            rules.stale_after_seconds
        ),
    );
    a.insert("last_seen".to_string(), rfc3339(last_seen));
    Alert::new(ALERT_DATA_STALE, gate, &rules.severity, a, now)
}

#[cfg(test)]
mod tests;
