//! TEMPORARY stand-in for `crate::alert` (written in another branch), with the same signatures and
//! the least behaviour: a trivial per-gate state machine and a notifier that only logs.
//!
//! The integrator deletes this file and changes the single `use` line in `service/mod.rs`
//! (`use alert_shim as alert_impl;` -> `use crate::alert as alert_impl;`).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::time::{Duration, SystemTime};

use serde::{Deserialize, Serialize};

/// Alert rules of one gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlertRules {
    /// Fire when zeta0 is below this.
    pub fire_below: f64,
    /// Clear when zeta0 is above this.
    pub clear_above: f64,
    /// Consecutive windows below `fire_below` before firing.
    pub for_windows: u32,
    /// Consecutive windows above `clear_above` before resolving.
    pub resolve_windows: u32,
    /// Seconds without data before GateDataStale.
    pub stale_after_seconds: f64,
    /// Severity label.
    pub severity: String,
}

impl Default for AlertRules {
    fn default() -> Self {
        AlertRules {
            fire_below: 0.0,
            clear_above: 0.005,
            for_windows: 2,
            resolve_windows: 3,
            stale_after_seconds: 30.0,
            severity: "critical".into(),
        }
    }
}

/// State of a gate's alert.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GateState {
    Ok,
    Pending,
    Firing,
    Resolved,
    Unknown,
}

/// What one identification says.
#[derive(Debug, Clone)]
pub struct Observation<'a> {
    pub zeta0: Option<f64>,
    pub trusted: bool,
    pub frequency_hz: Option<f64>,
    pub limit_cycle_amplitude: Option<f64>,
    pub time_to_limit: Option<f64>,
    pub equation: &'a str,
}

/// A firing alert.
#[derive(Debug, Clone, Serialize)]
pub struct Alert {
    pub gate: String,
    pub name: String,
    pub severity: String,
    pub since: SystemTime,
}

/// A state change.
#[derive(Debug, Clone, Serialize)]
pub struct AlertEvent {
    pub gate: String,
    pub name: String,
    pub state: GateState,
    pub at: SystemTime,
}

#[derive(Debug)]
struct Entry {
    rules: AlertRules,
    state: GateState,
    below: u32,
    above: u32,
    last_data: Option<SystemTime>,
    stale: bool,
    since: SystemTime,
}

/// Per-gate alert state machines.
#[derive(Debug)]
pub struct AlertEngine {
    rules: AlertRules,
    gates: BTreeMap<String, Entry>,
}

impl AlertEngine {
    pub fn new(rules: AlertRules) -> Self {
        AlertEngine {
            rules,
            gates: BTreeMap::new(),
        }
    }

    fn entry(&mut self, gate: &str) -> &mut Entry {
        let rules = self.rules.clone();
        self.gates.entry(gate.to_string()).or_insert(Entry {
            rules,
            state: GateState::Unknown,
            below: 0,
            above: 0,
            last_data: None,
            stale: false,
            since: SystemTime::UNIX_EPOCH,
        })
    }

    pub fn set_rules(&mut self, gate: &str, rules: AlertRules) {
        self.entry(gate).rules = rules;
    }

    pub fn observe(
        &mut self,
        gate: &str,
        obs: &Observation<'_>,
        now: SystemTime,
    ) -> Vec<AlertEvent> {
        let e = self.entry(gate);
        let before = e.state;
        match obs.zeta0.filter(|_| obs.trusted) {
            None => {}
            Some(z) if z < e.rules.fire_below => {
                e.below += 1;
                e.above = 0;
                if e.below >= e.rules.for_windows.max(1) {
                    e.state = GateState::Firing;
                } else if e.state != GateState::Firing {
                    e.state = GateState::Pending;
                }
            }
            Some(z) => {
                e.below = 0;
                if z > e.rules.clear_above {
                    e.above += 1;
                }
                if e.state == GateState::Firing {
                    if e.above >= e.rules.resolve_windows.max(1) {
                        e.state = GateState::Resolved;
                    }
                } else {
                    e.state = GateState::Ok;
                }
            }
        }
        if e.state != before {
            e.since = now;
            vec![AlertEvent {
                gate: gate.into(),
                name: "GateSelfExcited".into(),
                state: e.state,
                at: now,
            }]
        } else {
            Vec::new()
        }
    }

    pub fn data_seen(&mut self, gate: &str, now: SystemTime) -> Vec<AlertEvent> {
        let e = self.entry(gate);
        e.last_data = Some(now);
        if e.stale {
            e.stale = false;
            return vec![AlertEvent {
                gate: gate.into(),
                name: "GateDataStale".into(),
                state: GateState::Resolved,
                at: now,
            }];
        }
        Vec::new()
    }

    pub fn check_stale(&mut self, now: SystemTime) -> Vec<AlertEvent> {
        let mut out = Vec::new();
        for (gate, e) in self.gates.iter_mut() {
            let Some(last) = e.last_data else { continue };
            let age = now.duration_since(last).unwrap_or(Duration::ZERO);
            if !e.stale && age.as_secs_f64() > e.rules.stale_after_seconds {
                e.stale = true;
                e.state = GateState::Unknown;
                out.push(AlertEvent {
                    gate: gate.clone(),
                    name: "GateDataStale".into(),
                    state: GateState::Firing,
                    at: now,
                });
            }
        }
        out
    }

    pub fn state(&self, gate: &str) -> Option<GateState> {
        self.gates.get(gate).map(|e| e.state)
    }

    pub fn firing(&self) -> Vec<Alert> {
        self.gates
            .iter()
            .filter(|(_, e)| e.state == GateState::Firing || e.stale)
            .map(|(g, e)| Alert {
                gate: g.clone(),
                name: if e.stale {
                    "GateDataStale"
                } else {
                    "GateSelfExcited"
                }
                .into(),
                severity: e.rules.severity.clone(),
                since: e.since,
            })
            .collect()
    }
}

pub mod notify {
    //! Shim notifier: logs the events.
    use super::{Alert, AlertEvent};
    use serde::{Deserialize, Serialize};
    use std::time::Duration;
    use tokio::sync::mpsc;
    use tokio::task::JoinHandle;

    /// Where notifications go.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields, default)]
    pub struct NotifyConfig {
        /// Webhook URLs.
        pub webhooks: Vec<String>,
        /// Alertmanager base URL.
        pub alertmanager_url: Option<String>,
    }

    /// Sends events to the notifier task without blocking.
    #[derive(Debug, Clone)]
    pub struct NotifierHandle {
        tx: mpsc::Sender<Vec<AlertEvent>>,
    }

    impl NotifierHandle {
        pub fn notify(&self, events: Vec<AlertEvent>) {
            if !events.is_empty() {
                let _ = self.tx.try_send(events);
            }
        }

        pub async fn shutdown(self, deadline: Duration) {
            drop(self.tx);
            let _ = deadline;
        }
    }

    pub fn spawn_notifier<F>(
        config: NotifyConfig,
        snapshot_fn: F,
    ) -> (NotifierHandle, JoinHandle<()>)
    where
        F: Fn() -> Vec<Alert> + Send + Sync + 'static,
    {
        let (tx, mut rx) = mpsc::channel::<Vec<AlertEvent>>(1024);
        let task = tokio::spawn(async move {
            let _ = (&config, &snapshot_fn);
            while let Some(events) = rx.recv().await {
                for e in events {
                    tracing::info!(gate = %e.gate, alert = %e.name, state = ?e.state, "alert event");
                }
            }
        });
        (NotifierHandle { tx }, task)
    }
}
