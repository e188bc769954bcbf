//! Alerting: turn the damping ratio of each identified gate window into alerts that
//! Alertmanager (or any receiver written for Alertmanager's webhook) understands.
//!
//! Two halves:
//! - [`engine`] (re-exported here): the per-gate state machine. Pure: no tokio, no I/O, the
//!   current time is always passed in, so every transition is unit-tested with explicit times.
//!   It decides *when* `GateNegativeDamping` fires and resolves (with `for`/hysteresis rules)
//!   decided on each window's 95 % interval, when `GateDampingDeclining` warns that the trend
//!   of `zeta0` heads for the threshold, and when `GateDataStale` fires because a gate stopped
//!   sending samples.
//! - [`notify`]: delivery of the resulting [`AlertEvent`]s to webhooks (Alertmanager webhook
//!   format, version 4) and to Alertmanager's `POST /api/v2/alerts`, with per-target bounded
//!   queues, retries with exponential backoff, periodic re-sending of firing alerts and a
//!   flushing shutdown.
//!
//! The semantics (state diagram, every transition and why) are documented in `docs/alerts.md`.
//!
//! Typical wiring in the daemon:
//! ```no_run
//! # async fn demo() {
//! use std::sync::{Arc, Mutex};
//! use std::time::{Duration, SystemTime};
//! use gatewatch::alert::{AlertEngine, AlertRules, Observation};
//! use gatewatch::alert::notify::{spawn_notifier, NotifyConfig};
//!
//! let engine = Arc::new(Mutex::new(AlertEngine::new(AlertRules::default())));
//! let snap = engine.clone();
//! let (notifier, _task) = spawn_notifier(NotifyConfig::default(), move || {
//!     snap.lock().map(|e| e.firing()).unwrap_or_default()
//! });
//! // on every identified window:
//! let obs = Observation { zeta0: Some(-0.012), zeta0_interval: Some((-0.02, -0.004)), trusted: true, frequency_hz: Some(10.4),
//!     ..Default::default() };
//! let events = engine.lock().unwrap().observe("g1", &obs, SystemTime::now());
//! notifier.notify(events);
//! // at exit:
//! notifier.shutdown(Duration::from_secs(5)).await;
//! # }
//! ```

pub mod engine;
pub mod notify;

pub use engine::persist::{AlertRecord, GateSnapshot, PhaseSnapshot};
pub use engine::{
    at_once_ratio, fingerprint, Alert, AlertEngine, AlertEvent, AlertRules, GateState, Observation,
    RulesError, ALERT_DAMPING_DECLINING, ALERT_DATA_STALE, ALERT_NEGATIVE_DAMPING, AT_ONCE_FLOOR,
    AT_ONCE_MARGIN_FACTOR, AT_ONCE_MIN_AMBIENT_RATIO,
};
