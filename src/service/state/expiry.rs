//! Forgetting gates. The once-a-second tick: unknown gates that stopped sending expire (unless
//! an alert that silence does not resolve holds them), silent gates raise `GateDataStale`, a
//! stuck identification is logged. And `DELETE /api/v1/gates/{id}`, by which an operator
//! forgets an auto-accepted gate at once: the same forgetting ([`AppState::forget`]) as the
//! expiry's, so the two cannot drift apart.

#[allow(unused_imports)]
use super::*;

use crate::alert::{ALERT_DAMPING_DECLINING, ALERT_NEGATIVE_DAMPING};
use crate::store::WriteBatch;

/// Why `DELETE /api/v1/gates/{id}` ([`AppState::forget_gate`]) forgot nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ForgetError {
    /// The daemon has neither a gate nor an alert state of that name (404).
    Unknown,
    /// A `[gates.ID]` table: the configuration makes the gate at every start and pages when it
    /// goes silent, so only the configuration can remove it (409).
    Configured,
}

/// What [`AppState::forget_gate`] forgot: the body of `DELETE /api/v1/gates/{id}`'s 200.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Forgotten {
    /// The gate id.
    pub gate: String,
    /// The alerts that were firing and were resolved (names, in the order notified:
    /// `GateNegativeDamping`, `GateDataStale`, `GateDampingDeclining`); empty when none fired.
    pub resolved: Vec<String>,
}

/// The firing alert that keeps a silent auto-accepted gate (or a restored alert state without
/// a gate) from expiring, if any. `GateNegativeDamping`: the gate was self-excited when its data
/// stopped, and silence is no evidence of recovery (a failing sensor or cable is as likely on a
/// vibrating gate as anywhere); expiring resolved the alert, told Alertmanager and the webhooks
/// "resolved", removed the series, and nothing paged any more. `GateDampingDeclining` too: it
/// says the damping is falling towards self-excitation, and the data stopping takes away the
/// evidence, not the decline; expiring also threw away the trend the warning stands on. A
/// `pending` damping alert does not hold: nothing has paged that the expiry would resolve.
fn holding_alert(alerts: &AlertEngine, gate: &str) -> Option<&'static str> {
    if alerts.is_firing(gate) {
        Some(ALERT_NEGATIVE_DAMPING)
    } else if alerts.is_declining(gate) {
        Some(ALERT_DAMPING_DECLINING)
    } else {
        None
    }
}

impl AppState {
    /// Once a second: logs stuck identifications, forgets expired unknown gates, raises
    /// GateDataStale for silent gates.
    pub fn tick(&self, now: SystemTime) {
        self.log_stuck_workers();
        let mut inner = lock(&self.inner);
        let mut write = WriteBatch::default();
        let (mut events, mut expired) = self.expire_unknown_gates(&mut inner, now, &mut write);
        if self.restart_expiry_due(&inner, now) {
            let (e, x) = self.expire_restored_orphans(&mut inner, now, &mut write);
            events.extend(e);
            expired.extend(x);
        }
        self.drop_unclaimed_memories(&mut inner, now);
        events.extend(inner.alerts.check_stale(now));
        for e in &events {
            let g = e.alert().gate();
            if expired.iter().any(|x| x == g) {
                continue;
            }
            let state = inner.alerts.state(g).unwrap_or(GateState::Unknown);
            self.metrics.set_alert_state(g, state_name(state));
            // a silent gate predicts nothing: its zero crossing would stay frozen while the
            // time it counts down passes (`Metrics::clear_predictions`); the next window sets
            // it again
            if let AlertEvent::Firing(a) = e {
                if a.name == crate::alert::ALERT_DATA_STALE {
                    self.metrics.clear_predictions(g);
                }
            }
        }
        write.append(crate::service::storage::states_write(
            self.persistence.as_deref(),
            &inner.alerts,
        ));
        // under the lock, as everywhere (`AppState::notify_and_write`): a window's write
        // queued after this forget would restore the gate, and samples of an expired gate's
        // name arriving meanwhile make a new gate, whose series the removal below would take
        // away
        self.notify_and_write(&inner, events, write);
        // The resolved alerts' delivery sets their series once more: an expired gate leaves
        // none behind (label cardinality stays bounded by the live gates).
        for id in &expired {
            self.metrics.remove_gate(id);
        }
        drop(inner);
    }

    /// Logs, once per job, each identification that has run past
    /// `server.identification_timeout_seconds` (`/healthz` fails while it runs).
    fn log_stuck_workers(&self) {
        let timeout = self.config.server.identification_timeout_seconds;
        for o in self
            .pool()
            .newly_overdue(self.config.server.identification_timeout())
        {
            tracing::error!(
                gate = %o.gate,
                end_index = o.end_index,
                running_seconds = (o.running.as_secs_f64() * 10.0).round() / 10.0,
                identification_timeout_seconds = timeout,
                "an identification has run past its timeout: its worker is stuck, the gate is \
                 not identified while it runs, and /healthz fails (a liveness probe restarts \
                 the daemon)"
            );
        }
    }

    /// Whether `server.unknown_gate_expiry_seconds` (0: never) has passed since the start and
    /// the start's leftovers (restored alert states, rebuilt memories) are still to be swept.
    fn restart_expiry_due(&self, inner: &Inner, now: SystemTime) -> bool {
        let expiry = self.config.server.unknown_gate_expiry_seconds;
        if inner.orphans_swept || expiry <= 0.0 {
            return false;
        }
        let since = now.duration_since(inner.started).unwrap_or(Duration::ZERO);
        since >= Duration::from_secs_f64(expiry)
    }

    /// Once, `server.unknown_gate_expiry_seconds` after the start: forgets the alert states
    /// restored from the store for gates that have no entry, that is unknown gates of an
    /// earlier run that did not send since the start (configured gates get their entry at
    /// start). They expire as if the daemon had not restarted: their firing alerts (a
    /// `GateDataStale` above all) resolve and their series go. Without it, a restart kept such
    /// a gate's alerts firing for ever, with no gate behind them in the API to explain them.
    /// A state whose `GateNegativeDamping` or `GateDampingDeclining` fires is held as a silent
    /// gate is ([`holding_alert`]): it stays, alerts and series, until the gate sends again or
    /// an operator forgets it (`DELETE /api/v1/gates/{id}`); this sweep runs once, so the hold
    /// is logged once.
    fn expire_restored_orphans(
        &self,
        inner: &mut Inner,
        now: SystemTime,
        write: &mut WriteBatch,
    ) -> (Vec<AlertEvent>, Vec<String>) {
        inner.orphans_swept = true;
        let orphans: Vec<String> = inner
            .alerts
            .gates()
            .into_iter()
            .filter(|g| !inner.gates.contains_key(g))
            .collect();
        let mut events = Vec::new();
        let mut expired = Vec::new();
        let mut lines = BatchLog::new();
        let mut held = BatchLog::new();
        for id in orphans {
            if let Some(alert) = holding_alert(&inner.alerts, &id) {
                if held.allow(|| "held".into()) {
                    tracing::warn!(
                        gate = %id,
                        alert,
                        "alert state restored at start for a gate that did not send again is \
                         held, not expired (server.unknown_gate_expiry_seconds): its alert is \
                         firing, and silence is no evidence of recovery; it stays until the gate \
                         sends again, or forget it with DELETE /api/v1/gates/{{id}} (a sensor \
                         taken out of service)"
                    );
                }
                continue;
            }
            events.extend(self.forget(inner, &id, now, write));
            self.metrics.gates_expired.inc();
            if lines.allow(|| "expired".into()) {
                tracing::info!(
                    gate = %id,
                    "alert state restored at start for a gate that did not send again expired \
                     (server.unknown_gate_expiry_seconds)"
                );
            }
            expired.push(id);
        }
        if let Some((held_back, _)) = lines.held_back() {
            tracing::info!(
                held_back,
                "more restored alert states expired, not logged one by one \
                 (gatewatch_gates_expired_total counts each)"
            );
        }
        if let Some((held_back, _)) = held.held_back() {
            tracing::warn!(
                held_back,
                "more restored alert states held by a firing alert, not logged one by one \
                 (the gate list shows them firing)"
            );
        }
        (events, expired)
    }

    /// Drops the memories rebuilt at start that no gate took within
    /// `server.unknown_gate_expiry_seconds` (0: never): a gate silent that long would have
    /// expired, and its tracking model would be past `tracking.max_gap_windows` anyway.
    fn drop_unclaimed_memories(&self, inner: &mut Inner, now: SystemTime) {
        let expiry = self.config.server.unknown_gate_expiry_seconds;
        if inner.resumed.is_empty() || expiry <= 0.0 {
            return;
        }
        let since = now.duration_since(inner.started).unwrap_or(Duration::ZERO);
        if since >= Duration::from_secs_f64(expiry) {
            tracing::info!(
                gates = inner.resumed.len(),
                "memories rebuilt at start that no gate took are dropped"
            );
            inner.resumed.clear();
        }
    }

    /// Forgets the gates created by `accept_unknown_gates` that sent nothing for
    /// `server.unknown_gate_expiry_seconds` (0: never): their window, their alerts (resolved,
    /// so no `GateDataStale` is left firing for a gate nobody sends) and their metric series.
    /// Without it, anyone reaching an ingestion port could fill `max_gates` with junk gates
    /// until a restart. A gate with a firing `GateNegativeDamping` or `GateDampingDeclining` is
    /// held instead ([`holding_alert`]): it keeps its entry, its alerts (its `GateDataStale`
    /// goes on firing) and its series, and still counts against `server.max_gates`, until it
    /// sends again or an operator forgets it (`DELETE /api/v1/gates/{id}`). Each hold is logged
    /// once, when it begins. Returns the resolved alerts' events and the expired gates.
    fn expire_unknown_gates(
        &self,
        inner: &mut Inner,
        now: SystemTime,
        write: &mut WriteBatch,
    ) -> (Vec<AlertEvent>, Vec<String>) {
        let expiry = self.config.server.unknown_gate_expiry_seconds;
        if expiry <= 0.0 {
            return (Vec::new(), Vec::new());
        }
        let expiry = Duration::from_secs_f64(expiry);
        let silent: Vec<String> = inner
            .gates
            .iter()
            .filter(|(_, e)| {
                e.unknown && now.duration_since(e.last_data).unwrap_or(Duration::ZERO) >= expiry
            })
            .map(|(id, _)| id.clone())
            .collect();
        let mut events = Vec::new();
        let mut expired = Vec::new();
        let mut lines = BatchLog::new();
        let mut held = BatchLog::new();
        for id in silent {
            if let Some(alert) = holding_alert(&inner.alerts, &id) {
                let Some(e) = inner.gates.get_mut(&id) else {
                    continue; // listed from `inner.gates` above, under the same lock
                };
                if !std::mem::replace(&mut e.held, true) && held.allow(|| "held".into()) {
                    tracing::warn!(
                        gate = %id,
                        alert,
                        "unknown gate silent past server.unknown_gate_expiry_seconds is held, \
                         not expired: its alert is firing, and silence is no evidence of \
                         recovery; it keeps its alerts and series (and its place in \
                         server.max_gates) until it sends again, or forget it with \
                         DELETE /api/v1/gates/{{id}} (a sensor taken out of service)"
                    );
                }
                continue;
            }
            events.extend(self.forget(inner, &id, now, write));
            self.metrics.gates_expired.inc();
            if lines.allow(|| "expired".into()) {
                tracing::info!(gate = %id, "unknown gate expired (server.unknown_gate_expiry_seconds)");
            }
            expired.push(id);
        }
        if let Some((held_back, _)) = lines.held_back() {
            tracing::info!(
                held_back,
                "more unknown gates expired in the same sweep, not logged one by one \
                 (gatewatch_gates_expired_total counts each)"
            );
        }
        if let Some((held_back, _)) = held.held_back() {
            tracing::warn!(
                held_back,
                "more silent unknown gates held by a firing alert in the same sweep, not logged \
                 one by one (the gate list shows them firing and stale)"
            );
        }
        (events, expired)
    }

    /// Forgets gate `id` as if it had never sent: its entry (window, identification, trend),
    /// the worker pool's pending job and tracking memory (`WorkerPool::forget`; a job in flight
    /// reports on nothing, `GateEntry::generation`), a memory rebuilt for it at start, its
    /// alerts and rule override, its stored alert state (added to `write`: else the next start
    /// restored it, firing alerts and all) and its metric series. Returns the resolved alerts'
    /// events, for the caller to write and notify; their delivery sets their
    /// `gatewatch_alert_firing` series once more, so the caller removes the gate's series
    /// again after it. The one forgetting of the expiry ([`Self::expire_unknown_gates`],
    /// [`Self::expire_restored_orphans`]) and of `DELETE /api/v1/gates/{id}`
    /// ([`Self::forget_gate`]); the callers count and log.
    fn forget(
        &self,
        inner: &mut Inner,
        id: &str,
        now: SystemTime,
        write: &mut WriteBatch,
    ) -> Vec<AlertEvent> {
        inner.gates.remove(id);
        inner.resumed.remove(id);
        self.pool().forget(id);
        let events = inner.alerts.remove_gate(id, now);
        write.append(crate::service::storage::forget_write(
            self.persistence.as_deref(),
            id,
        ));
        self.metrics.remove_gate(id);
        events
    }

    /// `DELETE /api/v1/gates/{id}`: forgets the auto-accepted gate `id` now, exactly as its
    /// expiry would (`AppState::forget`): its alerts resolved (written to the store and notified:
    /// Alertmanager and the webhooks get "resolved"), its stored alert state, series and worker
    /// memory gone; counted in `gatewatch_gates_deleted_total`. Also an alert state restored
    /// from the store with no gate entry. The operator's way out of a hold: a gate whose
    /// sensor was taken out of service with its `GateNegativeDamping` firing is never expired
    /// (silence is no evidence of recovery), and with a store it would page across restarts
    /// too. A configured gate is refused ([`ForgetError::Configured`]): the configuration
    /// would make it again at the next start, paging `GateDataStale`.
    pub fn forget_gate(&self, id: &str) -> Result<Forgotten, ForgetError> {
        if self.config.gates.contains_key(id) {
            return Err(ForgetError::Configured);
        }
        let now = SystemTime::now();
        let mut inner = lock(&self.inner);
        if !inner.gates.contains_key(id) && inner.alerts.state(id).is_none() {
            return Err(ForgetError::Unknown);
        }
        let mut write = WriteBatch::default();
        let events = self.forget(&mut inner, id, now, &mut write);
        self.metrics.gates_deleted.inc();
        let resolved: Vec<String> = events.iter().map(|e| e.alert().name.clone()).collect();
        tracing::info!(
            gate = %id,
            resolved = %resolved.join(","),
            "gate forgotten by DELETE /api/v1/gates/{{id}}, its firing alerts resolved"
        );
        // under the lock (`AppState::notify_and_write`): samples of the same name arriving
        // meanwhile make a new gate, whose series the removal below would take away
        self.notify_and_write(&inner, events, write);
        self.metrics.remove_gate(id);
        drop(inner);
        Ok(Forgotten {
            gate: id.to_string(),
            resolved,
        })
    }
}
