//! Export and restore of a gate's alert state, so a restarted daemon resumes where it stopped:
//! a firing alert stays firing with its original `startsAt` and fingerprint, a pending streak
//! keeps its count, and the first windows after the restart continue the counters instead of
//! starting them over (no spurious re-fire, no spurious resolve). Pure: the store keeps the
//! JSON, the engine never sees it.

use std::collections::BTreeMap;
use std::time::SystemTime;

use serde::{Deserialize, Serialize};

use super::trend_alert::Declining;
use super::{track_mut, Alert, AlertEngine, GateState, GateTrack, Phase};

/// An [`Alert`] in a form that round-trips exactly (times as seconds + nanoseconds since the
/// epoch). Also the payload of an outbox row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlertRecord {
    /// `alertname`.
    pub name: String,
    /// Labels.
    pub labels: BTreeMap<String, String>,
    /// Annotations.
    pub annotations: BTreeMap<String, String>,
    /// `startsAt`.
    pub starts_at: SystemTime,
    /// `endsAt` (resolved alerts).
    pub ends_at: Option<SystemTime>,
    /// Alertmanager's fingerprint.
    pub fingerprint: String,
}

impl From<&Alert> for AlertRecord {
    fn from(a: &Alert) -> Self {
        AlertRecord {
            name: a.name.clone(),
            labels: a.labels.clone(),
            annotations: a.annotations.clone(),
            starts_at: a.starts_at,
            ends_at: a.ends_at,
            fingerprint: a.fingerprint.clone(),
        }
    }
}

impl From<AlertRecord> for Alert {
    fn from(r: AlertRecord) -> Self {
        Alert {
            name: r.name,
            labels: r.labels,
            annotations: r.annotations,
            starts_at: r.starts_at,
            ends_at: r.ends_at,
            fingerprint: r.fingerprint,
        }
    }
}

/// The counting part of a gate's damping state machine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "phase", rename_all = "lowercase")]
pub enum PhaseSnapshot {
    /// No negative streak.
    Ok,
    /// `negatives` consecutive negative windows, the first at `since`.
    Pending {
        /// Consecutive negative trusted windows so far.
        negatives: u32,
        /// Time of the first (the future alert's `startsAt`).
        since: SystemTime,
    },
    /// `GateNegativeDamping` firing; `good` consecutive good windows so far.
    Firing {
        /// The firing alert.
        alert: AlertRecord,
        /// Consecutive good windows (`AlertRules::resolve_probability`).
        good: u32,
    },
}

/// Everything the engine knows about one gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GateSnapshot {
    /// The damping state machine.
    #[serde(flatten)]
    pub phase: PhaseSnapshot,
    /// The displayed state.
    pub displayed: GateState,
    /// When samples last arrived.
    pub last_seen: Option<SystemTime>,
    /// The firing `GateDataStale` alert, if any.
    pub stale: Option<AlertRecord>,
    /// The firing `GateDampingDeclining` warning, if any (its streak counters restart: the trend
    /// is rebuilt from the windows after the restart).
    #[serde(default)]
    pub declining: Option<AlertRecord>,
}

impl AlertEngine {
    /// The state of `gate`, for persisting; `None` for a gate the engine does not know.
    pub fn export_gate(&self, gate: &str) -> Option<GateSnapshot> {
        let t = self.gates.get(gate)?;
        let phase = match &t.phase {
            Phase::Ok => PhaseSnapshot::Ok,
            Phase::Pending { negatives, since } => PhaseSnapshot::Pending {
                negatives: *negatives,
                since: *since,
            },
            Phase::Firing { alert, good } => PhaseSnapshot::Firing {
                alert: alert.into(),
                good: *good,
            },
        };
        Some(GateSnapshot {
            phase,
            displayed: t.displayed,
            last_seen: t.last_seen,
            stale: t.stale.as_ref().map(AlertRecord::from),
            declining: t.declining.alert().map(AlertRecord::from),
        })
    }

    /// Replaces the state of `gate` by `snap` (at start, before any window). The staleness
    /// clock restarts at `now` (the daemon was down, the sensor gets the same grace as at a
    /// first start), except when `GateDataStale` was firing: it stays firing with its
    /// `startsAt` until samples arrive. Returns nothing to notify: the restored firing alerts
    /// are the ones in the outbox and in [`AlertEngine::firing`], re-sent by the caller.
    pub fn restore_gate(&mut self, gate: &str, snap: GateSnapshot, now: SystemTime) {
        let track = track_mut(&mut self.gates, gate);
        *track = GateTrack {
            phase: match snap.phase {
                PhaseSnapshot::Ok => Phase::Ok,
                PhaseSnapshot::Pending { negatives, since } => Phase::Pending { negatives, since },
                PhaseSnapshot::Firing { alert, good } => Phase::Firing {
                    alert: alert.into(),
                    good,
                },
            },
            displayed: snap.displayed,
            last_seen: if snap.stale.is_some() {
                snap.last_seen
            } else {
                Some(now)
            },
            stale: snap.stale.map(Alert::from),
            declining: match snap.declining {
                Some(alert) => Declining::Firing {
                    alert: alert.into(),
                    calm: 0,
                },
                None => Declining::Quiet,
            },
        };
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, UNIX_EPOCH};

    use super::*;
    use crate::alert::{AlertEvent, AlertRules, Observation};

    fn t(s: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(1_700_000_000 + s)
    }

    fn obs(z: f64) -> Observation<'static> {
        Observation {
            zeta0: Some(z),
            // a sharp interval: the engine decides on the interval (no interval, no evidence)
            zeta0_interval: Some((z - 0.0005, z + 0.0005)),
            trusted: true,
            ..Default::default()
        }
    }

    /// Through JSON, as the store keeps it.
    fn reborn(e: &AlertEngine, gate: &str, now: SystemTime) -> AlertEngine {
        let json = serde_json::to_string(&e.export_gate(gate).expect("known")).expect("json");
        let snap: GateSnapshot = serde_json::from_str(&json).expect("parse");
        let mut fresh = AlertEngine::new(AlertRules::counting());
        fresh.restore_gate(gate, snap, now);
        fresh
    }

    #[test]
    fn a_firing_alert_resumes_with_its_start_and_resolves_only_after_resolve_windows() {
        let mut e = AlertEngine::new(AlertRules::counting());
        e.data_seen("g", t(0));
        e.observe("g", &obs(-0.02), t(5));
        let fired = e.observe("g", &obs(-0.02), t(10));
        let AlertEvent::Firing(original) = &fired[0] else {
            panic!("fired: {fired:?}")
        };
        // one good window before the crash: the counter is kept
        assert!(e.observe("g", &obs(0.03), t(15)).is_empty());
        let mut r = reborn(&e, "g", t(600));
        assert!(r.is_firing("g"));
        assert_eq!(r.firing(), e.firing(), "same alert, same startsAt");
        assert_eq!(r.firing()[0].starts_at, t(5));
        // a negative window after the restart does not re-fire
        assert!(r.observe("g", &obs(-0.01), t(605)).is_empty());
        // recovered while down: resolves through resolve_windows trusted good windows
        assert!(r.observe("g", &obs(0.03), t(610)).is_empty());
        let resolved = r.observe("g", &obs(0.03), t(615));
        match &resolved[..] {
            [AlertEvent::Resolved(a)] => {
                assert_eq!(a.fingerprint, original.fingerprint);
                assert_eq!(a.starts_at, original.starts_at);
                assert_eq!(a.ends_at, Some(t(615)));
            }
            other => panic!("expected one resolve, got {other:?}"),
        }
        // without the export the restarted engine would have had nothing to resolve
        let mut amnesic = AlertEngine::new(AlertRules::counting());
        amnesic.observe("g", &obs(0.03), t(610));
        assert!(amnesic.observe("g", &obs(0.03), t(615)).is_empty());
    }

    #[test]
    fn a_pending_streak_and_a_stale_alert_survive() {
        let mut e = AlertEngine::new(AlertRules::counting());
        e.data_seen("g", t(0));
        e.observe("g", &obs(-0.02), t(5));
        let stale = e.check_stale(t(100));
        assert_eq!(stale.len(), 1);
        let mut r = reborn(&e, "g", t(200));
        assert_eq!(r.state("g"), e.state("g"));
        // the stale alert is still firing and is not fired again
        assert!(r.check_stale(t(300)).is_empty());
        assert_eq!(r.firing().len(), 1);
        // the second negative window completes the streak begun before the restart
        let fired = r.observe("g", &obs(-0.02), t(205));
        assert!(matches!(&fired[..], [AlertEvent::Firing(a)] if a.starts_at == t(5)));
        // samples resolve the stale alert
        assert!(matches!(
            &r.data_seen("g", t(210))[..],
            [AlertEvent::Resolved(_)]
        ));
    }

    #[test]
    fn the_staleness_clock_restarts_at_restore_when_not_stale() {
        let mut e = AlertEngine::new(AlertRules::counting());
        e.data_seen("g", t(0));
        let mut r = reborn(&e, "g", t(1000));
        assert!(r.check_stale(t(1010)).is_empty(), "grace after restart");
        assert_eq!(r.check_stale(t(1031)).len(), 1);
    }
}
