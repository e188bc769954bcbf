//! The once-a-second tick: unknown gates that stopped sending expire, silent gates raise
//! `GateDataStale`, a stuck identification is logged.

#[allow(unused_imports)]
use super::*;

impl AppState {
    /// Once a second: logs stuck identifications, forgets expired unknown gates, raises
    /// GateDataStale for silent gates.
    pub fn tick(&self, now: SystemTime) {
        self.log_stuck_workers();
        let mut inner = lock(&self.inner);
        let (mut events, mut expired) = self.expire_unknown_gates(&mut inner, now);
        if self.restart_expiry_due(&inner, now) {
            let (e, x) = self.expire_restored_orphans(&mut inner, now);
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
        let write =
            crate::service::storage::states_write(self.persistence.as_deref(), &inner.alerts);
        drop(inner);
        self.notify_and_write(events, write);
        // The resolved alerts' delivery sets their series once more: an expired gate leaves
        // none behind (label cardinality stays bounded by the live gates).
        for id in &expired {
            self.metrics.remove_gate(id);
        }
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
    fn expire_restored_orphans(
        &self,
        inner: &mut Inner,
        now: SystemTime,
    ) -> (Vec<AlertEvent>, Vec<String>) {
        inner.orphans_swept = true;
        let orphans: Vec<String> = inner
            .alerts
            .gates()
            .into_iter()
            .filter(|g| !inner.gates.contains_key(g))
            .collect();
        let mut events = Vec::new();
        let mut lines = BatchLog::new();
        for id in &orphans {
            events.extend(inner.alerts.remove_gate(id, now));
            self.metrics.remove_gate(id);
            self.metrics.gates_expired.inc();
            if lines.allow(|| "expired".into()) {
                tracing::info!(
                    gate = %id,
                    "alert state restored at start for a gate that did not send again expired \
                     (server.unknown_gate_expiry_seconds)"
                );
            }
        }
        if let Some((held_back, _)) = lines.held_back() {
            tracing::info!(
                held_back,
                "more restored alert states expired, not logged one by one \
                 (gatewatch_gates_expired_total counts each)"
            );
        }
        (events, orphans)
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
    /// until a restart. Returns the resolved alerts' events and the expired gates.
    fn expire_unknown_gates(
        &self,
        inner: &mut Inner,
        now: SystemTime,
    ) -> (Vec<AlertEvent>, Vec<String>) {
        let expiry = self.config.server.unknown_gate_expiry_seconds;
        if expiry <= 0.0 {
            return (Vec::new(), Vec::new());
        }
        let expiry = Duration::from_secs_f64(expiry);
        let expired: Vec<String> = inner
            .gates
            .iter()
            .filter(|(_, e)| {
                e.unknown && now.duration_since(e.last_data).unwrap_or(Duration::ZERO) >= expiry
            })
            .map(|(id, _)| id.clone())
            .collect();
        let mut events = Vec::new();
        let mut lines = BatchLog::new();
        for id in &expired {
            inner.gates.remove(id);
            self.pool().forget(id);
            events.extend(inner.alerts.remove_gate(id, now));
            self.metrics.remove_gate(id);
            self.metrics.gates_expired.inc();
            if lines.allow(|| "expired".into()) {
                tracing::info!(gate = %id, "unknown gate expired (server.unknown_gate_expiry_seconds)");
            }
        }
        if let Some((held_back, _)) = lines.held_back() {
            tracing::info!(
                held_back,
                "more unknown gates expired in the same sweep, not logged one by one \
                 (gatewatch_gates_expired_total counts each)"
            );
        }
        (events, expired)
    }
}
