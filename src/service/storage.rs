//! The daemon's side of the store ([`crate::store`]): opening it at start, restoring the alert
//! states and the outbox, and turning identifications and alert transitions into writes.
//!
//! Everything here talks to the [`Store`] trait and the [`StoreWriter`] thread, never to
//! SQLite: the writes leave the caller's thread at once (bounded queue), the alert transitions
//! are handed to the notifier only once written ("written before sent"), and a failed write
//! degrades to delivery from memory, counted and logged.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use super::clock::unix_seconds;
use super::metrics::Metrics;
use super::sync::lock;
use crate::alert::notify::outbox::{self, OutboxEntry, TargetInfo};
use crate::alert::notify::NotifierHandle;
use crate::alert::{AlertEngine, AlertEvent, GateSnapshot};
use crate::analysis::WindowAnalysis;
use crate::store::{
    IdentificationRecord, NatsOptions, NatsStore, NewOutboxRow, SqliteStore, StorageBackend,
    StorageConfig, Store, StoreError, StoreWriter, Then, WriteBatch, WriteResult,
};

/// The store as the daemon holds it.
pub struct Persistence {
    /// For reads (history, start-up).
    pub store: Arc<dyn Store>,
    /// For writes.
    pub writer: StoreWriter,
    /// The number of the next batch of transitions.
    batch: AtomicU64,
    /// The last alert state per gate the store confirmed written, so an unchanged state is not
    /// rewritten. Updated by the writer thread after the commit ([`Persistence::submit`]), not
    /// when the write is queued: a state whose write failed (a full store, a foreign lock, a
    /// full queue) was taken as written and never written again until it changed, so the file
    /// kept the older state for good, and the next start restored that one.
    written: Arc<Mutex<HashMap<String, String>>>,
    /// The SQLite store behind `store`, for its checkpoint.
    sqlite: Option<Arc<SqliteStore>>,
    /// The NATS store behind `store`, for the release of its owner lease.
    nats: Option<Arc<NatsStore>>,
    /// The writer's error counters as last exported to Prometheus.
    counts: StoreCounts,
}

impl std::fmt::Debug for Persistence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Persistence").finish_non_exhaustive()
    }
}

impl Persistence {
    /// Opens the store of `config.backend` (the SQLite file at `path`, or the NATS server at
    /// `config.nats_url`) and starts its writer thread. `sample_lead` is the gates' bound on
    /// how far ahead of the clock a sample may be (`Config::sample_lead_bound`), which lets
    /// the NATS store read a history range from its start only. The error names the file or
    /// the server; there is no in-memory fallback.
    pub fn open(
        path: &Path,
        config: &StorageConfig,
        sample_lead: Option<Duration>,
    ) -> Result<Persistence, StoreError> {
        if config.backend == StorageBackend::Nats {
            return Persistence::open_nats(config, sample_lead);
        }
        let store = Arc::new(SqliteStore::open(path, config.max_size_mb)?);
        tracing::info!(path = %path.display(), "store opened");
        let writer = StoreWriter::start(store.clone(), config.retention(), config.max_history_rows)
            .map_err(|e| StoreError::Open {
                path: path.display().to_string(),
                message: format!("cannot start the writer thread: {e}"),
            })?;
        let mut p = Persistence::with(store.clone(), writer);
        p.sqlite = Some(store);
        Ok(p)
    }

    /// Connects to the NATS store of `config`, taking its prefix's owner lease (refused when
    /// another daemon holds it), and starts its writer thread.
    fn open_nats(
        config: &StorageConfig,
        sample_lead: Option<Duration>,
    ) -> Result<Persistence, StoreError> {
        let options = NatsOptions {
            prefix: config.nats_prefix.clone(),
            owner_lease: Some(config.nats_lease()),
            sample_lead,
            ..NatsOptions::new(
                &config.nats_url,
                config.retention(),
                config.max_history_rows,
            )
        };
        let store = Arc::new(NatsStore::open(&options)?);
        tracing::info!(location = %store.location(), "store opened");
        let writer = StoreWriter::start(store.clone(), config.retention(), config.max_history_rows)
            .map_err(|e| StoreError::Open {
                path: store.location(),
                message: format!("cannot start the writer thread: {e}"),
            })?;
        let mut p = Persistence::with(store.clone(), writer);
        p.nats = Some(store);
        Ok(p)
    }

    /// Wraps any store (tests, another implementation).
    pub fn with(store: Arc<dyn Store>, writer: StoreWriter) -> Persistence {
        Persistence {
            store,
            writer,
            batch: AtomicU64::new(1),
            written: Arc::new(Mutex::new(HashMap::new())),
            sqlite: None,
            nats: None,
            counts: StoreCounts::default(),
        }
    }

    /// Brings `gatewatch_store_write_errors_total` and `gatewatch_store_pruned_rows_total` up to date with the writer's counters.
    pub fn sync_metrics(&self, metrics: &Metrics) {
        self.counts.sync(metrics, &self.writer.stats());
    }

    /// Frames of a damaged `-wal` file SQLite dropped when the store was opened (0 when none,
    /// or not SQLite): `gatewatch_store_restore_skipped_total{what="wal_frame"}`.
    pub fn wal_frames_dropped(&self) -> u64 {
        self.sqlite.as_ref().map_or(0, |s| s.wal_frames_dropped())
    }

    /// Writes the WAL into the database file (at shutdown, after [`StoreWriter::close`]), so a
    /// copy of the `.db` file alone is complete, waiting at most `within` for a lock another
    /// connection holds (what is left of the shutdown deadline). A store that is not SQLite has
    /// nothing to do.
    pub fn checkpoint(&self, within: std::time::Duration) -> Result<(), StoreError> {
        match &self.sqlite {
            Some(s) => s.checkpoint_within(within),
            None => Ok(()),
        }
    }

    /// Releases the NATS store's owner lease (at shutdown, after [`StoreWriter::close`]: nothing
    /// is written after it), so the next daemon takes the prefix at once. A failure is logged:
    /// the lease then expires by itself. A store that is not NATS has nothing to do.
    pub fn release(&self) {
        if let Some(s) = &self.nats {
            if let Err(e) = s.release() {
                tracing::warn!("{e}; the next daemon on the prefix waits for the lease to expire");
            }
        }
    }

    /// Restores every persisted gate state into `engine` (at start, before any window).
    /// A state that does not decode is logged naming the gate and the file, counted in
    /// `gatewatch_store_restore_skipped_total{what="alert_state"}`, and skipped (the gate
    /// starts fresh); so is the state of a gate whose id is not valid ([`restorable_gate`]),
    /// which is never restored.
    pub fn restore_alerts(
        &self,
        engine: &mut AlertEngine,
        now: SystemTime,
        metrics: &Metrics,
    ) -> usize {
        let states = match self.store.alert_states() {
            Ok(s) => s,
            Err(e) => {
                tracing::error!("cannot read the alert states, starting without them: {e}");
                return 0;
            }
        };
        let mut n = 0;
        let mut written = lock(&self.written);
        for (gate, json) in states {
            if !restorable_gate(&gate, "alert state", &self.store.location()) {
                metrics
                    .store_restore_skipped
                    .with_label_values(&["alert_state"])
                    .inc();
                continue;
            }
            match serde_json::from_str::<GateSnapshot>(&json) {
                Ok(snap) => {
                    engine.restore_gate(&gate, snap, now);
                    written.insert(gate, json);
                    n += 1;
                }
                Err(e) => {
                    metrics
                        .store_restore_skipped
                        .with_label_values(&["alert_state"])
                        .inc();
                    tracing::error!(
                        %gate,
                        store = %self.store.location(),
                        "stored alert state of gate {gate} in {} does not decode, the gate starts \
                         without it: {e}",
                        self.store.location()
                    )
                }
            }
        }
        n
    }

    /// Hands the undelivered notifications of the store to the notifier. Entries of targets no
    /// longer configured are deleted with a warning.
    pub fn resume_outbox(&self, notifier: &NotifierHandle) -> usize {
        let rows = match self.store.outbox() {
            Ok(r) => r,
            Err(e) => {
                tracing::error!("cannot read the outbox: {e}");
                return 0;
            }
        };
        let targets = notifier.targets();
        let mut entries = Vec::new();
        let mut orphans = Vec::new();
        let mut max_batch = 0;
        for r in rows {
            max_batch = max_batch.max(r.row.batch);
            let Some(i) = targets.iter().position(|t| t.key == r.row.target) else {
                tracing::warn!(target = %r.row.target, "outbox entry for a target no longer configured, dropped");
                orphans.push(r.id);
                continue;
            };
            match outbox::decode(
                r.id,
                r.row.batch,
                &r.row.status,
                r.row.created,
                &r.row.payload,
            ) {
                Ok(e) => entries.push((i, e)),
                Err(e) => {
                    tracing::error!("{e}; dropped");
                    orphans.push(r.id);
                }
            }
        }
        self.batch.fetch_max(max_batch + 1, Ordering::Relaxed);
        if !orphans.is_empty() {
            self.writer.submit(
                WriteBatch {
                    delivered: orphans,
                    ..Default::default()
                },
                None,
            );
        }
        let n = entries.len();
        notifier.notify_entries(entries);
        n
    }

    /// The alert state of `gate` to write, when it changed since the last write.
    pub fn changed_state(&self, engine: &AlertEngine, gate: &str) -> Option<(String, String)> {
        let mut snap = engine.export_gate(gate)?;
        // the staleness clock restarts at restore unless the stale alert fires: not worth a
        // write per ingestion
        if snap.stale.is_none() {
            snap.last_seen = None;
        }
        let json = serde_json::to_string(&snap).ok()?;
        if lock(&self.written).get(gate) == Some(&json) {
            return None;
        }
        Some((gate.to_string(), json))
    }

    /// Queues `batch` on the writer, then runs `then` with the result (on the writer thread).
    /// The alert states of a batch the store took are recorded as written, and its forgotten
    /// gates as not; a failed batch records nothing, so its states are written again with the
    /// next batch (each window's, and each tick's). Until then a state may be queued twice,
    /// which writes the same row twice: harmless, and only while a write is in flight or failing.
    pub fn submit(&self, batch: WriteBatch, then: Option<Then>) {
        if batch.alert_states.is_empty() && batch.forget_gates.is_empty() {
            self.writer.submit(batch, then);
            return;
        }
        let states = batch.alert_states.clone();
        let forgotten = batch.forget_gates.clone();
        let written = Arc::clone(&self.written);
        self.writer.submit(
            batch,
            Some(Box::new(move |result: WriteResult| {
                if result.is_ok() {
                    let mut w = lock(&written);
                    // in the batch's order: a state and the deletion of its gate in one batch
                    // are applied as the store applied them (states, then deletions)
                    for (gate, json) in states {
                        w.insert(gate, json);
                    }
                    for gate in &forgotten {
                        w.remove(gate);
                    }
                }
                if let Some(then) = then {
                    then(result);
                }
            })),
        );
    }

    /// Writes `extra` and the outbox rows of `events`, then (on the writer thread) hands the
    /// entries to the notifier, with their ids, or without when the write failed.
    pub fn persist_and_notify(
        &self,
        notifier: &NotifierHandle,
        events: Vec<AlertEvent>,
        mut extra: WriteBatch,
    ) {
        let now = SystemTime::now();
        let batch = self.batch.fetch_add(1, Ordering::Relaxed);
        let targets: Vec<TargetInfo> = notifier.targets().to_vec();
        let mut entries = Vec::new();
        for event in &events {
            let payload = outbox::encode(event);
            for (i, t) in targets.iter().enumerate() {
                extra.outbox.push(NewOutboxRow {
                    target: t.key.clone(),
                    fingerprint: event.alert().fingerprint.clone(),
                    status: event.status().to_string(),
                    created: unix_seconds(now),
                    batch,
                    payload: payload.clone(),
                    supersedes: outbox::supersedes(t.is_alertmanager, event.is_firing()),
                });
                entries.push((
                    i,
                    OutboxEntry {
                        id: None,
                        batch,
                        event: event.clone(),
                        created: now,
                    },
                ));
            }
        }
        let notifier = notifier.clone();
        self.submit(
            extra,
            Some(Box::new(move |result| {
                if let Ok(ids) = result {
                    for ((_, e), id) in entries.iter_mut().zip(ids) {
                        e.id = Some(id);
                    }
                }
                notifier.notify_entries(entries);
            })),
        );
    }
}

/// Whether gate `gate`, read from the store at `store` (its [`Store::location`]), may be
/// restored: its id is valid ([`valid_gate_id`]). When not, a warning names the id (quoted,
/// escaped, and cut when long: [`excerpt`]), what of it was stored (`what`) and the store, and
/// the caller skips it. Why: ingestion refuses such ids, but a store written by an older
/// version, or a SQLite file edited by hand, may hold a gate `..`, which was restored unchecked
/// (listed by the API, yet not readable at its URL).
///
/// [`valid_gate_id`]: super::config::valid_gate_id
/// [`excerpt`]: super::ingest::excerpt
pub fn restorable_gate(gate: &str, what: &str, store: &str) -> bool {
    if super::config::valid_gate_id(gate) {
        return true;
    }
    let shown = format!("{:?}", super::ingest::excerpt(gate));
    tracing::warn!(
        gate = %shown,
        store = %store,
        "stored {what} of gate {shown} in {store} skipped: not a valid gate id ({}); a store \
         written by an older version, or edited by hand?",
        super::config::GATE_ID_RULE
    );
    false
}

/// The history row of an identified window.
pub fn identification_record(
    gate: &str,
    time: SystemTime,
    window: (f64, f64),
    a: &WindowAnalysis,
) -> IdentificationRecord {
    let d = &a.damping;
    IdentificationRecord {
        gate: gate.to_string(),
        time: unix_seconds(time),
        window_start: window.0,
        window_end: window.1,
        equation: a.equation.clone(),
        coefficients: a.coefficients.clone(),
        damping: serde_json::to_value(d).unwrap_or(serde_json::Value::Null),
        verdict: serde_json::to_value(d.verdict)
            .ok()
            .and_then(|v| v.as_str().map(String::from))
            .unwrap_or_default(),
        fit_nmae: d.fit_nmae,
        path: a.path.as_str().to_string(),
    }
}

/// The acknowledgement callback of the notifier: settled outbox entries are deleted.
pub fn ack(persistence: Option<&Arc<Persistence>>) -> outbox::Ack {
    match persistence {
        Some(p) => {
            let writer = p.writer.clone();
            Arc::new(move |ids: Vec<i64>| {
                writer.submit(
                    WriteBatch {
                        delivered: ids,
                        ..Default::default()
                    },
                    None,
                )
            })
        }
        None => Arc::new(|_| {}),
    }
}

/// At start: the alert states back into the engine, the gauges set, the undelivered
/// notifications handed to the notifier and the firing alerts re-sent to Alertmanager at once.
pub fn resume(
    metrics: &super::metrics::Metrics,
    p: &Persistence,
    engine: &mut AlertEngine,
    notifier: &NotifierHandle,
    now: SystemTime,
) {
    let restored = p.restore_alerts(engine, now, metrics);
    for gate in engine.gates() {
        if let Some(s) = engine.state(&gate) {
            metrics.set_alert_state(&gate, s.as_str());
        }
    }
    let firing = engine.firing();
    for a in &firing {
        metrics.set_alert_firing(a.gate(), &a.name, true);
    }
    let pending = p.resume_outbox(notifier);
    if !firing.is_empty() {
        notifier.resend_now();
    }
    tracing::info!(
        gates = restored,
        firing = firing.len(),
        undelivered = pending,
        "alert state restored from the store"
    );
}

/// What an identified window writes: its history row and the gate's alert state if changed.
pub fn window_write(
    p: Option<&Persistence>,
    engine: &AlertEngine,
    gate: &str,
    record: IdentificationRecord,
) -> WriteBatch {
    let Some(p) = p else {
        return WriteBatch::default();
    };
    WriteBatch {
        identifications: vec![record],
        alert_states: p.changed_state(engine, gate).into_iter().collect(),
        ..Default::default()
    }
}

/// What forgetting `gate` writes (its expiry, `DELETE /api/v1/gates/{id}`): the deletion of its
/// stored alert state. Without it the store kept the gate's last state, firing alerts and all,
/// and the next start restored them and sent them to Alertmanager again as firing, for a gate
/// the daemon had forgotten (and with a firing `GateNegativeDamping`, which holds a silent gate,
/// held it for ever). Its last written state is forgotten too (now, and again when the deletion
/// is committed, after any state of the gate queued before it), so a gate of the same name that
/// comes back has its first state written whatever it is.
pub fn forget_write(p: Option<&Persistence>, gate: &str) -> WriteBatch {
    let Some(p) = p else {
        return WriteBatch::default();
    };
    lock(&p.written).remove(gate);
    WriteBatch {
        forget_gates: vec![gate.to_string()],
        ..Default::default()
    }
}

/// The alert states that changed since they were last written (each tick).
pub fn states_write(p: Option<&Persistence>, engine: &AlertEngine) -> WriteBatch {
    let Some(p) = p else {
        return WriteBatch::default();
    };
    WriteBatch {
        alert_states: engine
            .gates()
            .iter()
            .filter_map(|g| p.changed_state(engine, g))
            .collect(),
        ..Default::default()
    }
}

/// The store writer's counters as last exported, to turn its totals into counter increments
/// (the store does not know Prometheus).
#[derive(Debug, Default)]
pub struct StoreCounts {
    last: std::sync::Mutex<[u64; 6]>,
}

impl StoreCounts {
    /// Adds what the writer counted since the last call to `gatewatch_store_write_errors_total`
    /// and `gatewatch_store_pruned_rows_total`.
    pub fn sync(&self, metrics: &Metrics, stats: &crate::store::StoreStats) {
        use std::sync::atomic::Ordering::Relaxed;
        let now = [
            stats.write_failed.load(Relaxed),
            stats.queue_full.load(Relaxed),
            stats.file_gone.load(Relaxed),
            stats.expired_rows.load(Relaxed),
            stats.over_size_rows.load(Relaxed),
            stats.over_bytes_rows.load(Relaxed),
        ];
        let mut last = super::sync::lock(&self.last);
        let counters = [
            (&metrics.store_write_errors, "failed"),
            (&metrics.store_write_errors, "queue_full"),
            (&metrics.store_write_errors, "file_gone"),
            (&metrics.store_pruned_rows, "age"),
            (&metrics.store_pruned_rows, "rows"),
            (&metrics.store_pruned_rows, "size"),
        ];
        for (i, (counter, reason)) in counters.into_iter().enumerate() {
            counter
                .with_label_values(&[reason])
                .inc_by(now[i].saturating_sub(last[i]));
        }
        *last = now;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::{DampingReport, Path};

    /// The history row says which path identified the window (it said `full` for every window
    /// until session 26, tracked ones included).
    #[test]
    fn the_record_keeps_the_identification_path() {
        for (path, name) in [(Path::Full, "full"), (Path::Tracked, "tracked")] {
            let a = WindowAnalysis {
                equation: "ydd + 0.1*yd + y = 0".into(),
                coefficients: vec![("c1".into(), 0.1)],
                damping: DampingReport::unknown(),
                evaluations: 1,
                seconds: 0.0,
                warm_start: vec![0.1],
                path,
            };
            let r = identification_record("g", SystemTime::UNIX_EPOCH, (0.0, 10.0), &a);
            assert_eq!(r.path, name);
            assert_eq!((r.window_start, r.window_end), (0.0, 10.0));
        }
    }
}
