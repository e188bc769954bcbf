//! Shared daemon state: the gates (windows, latest identification), the alert engine, the worker
//! pool and the notifier. This is the ONE module that talks to the alert engine
//! ([`crate::alert::AlertEngine`]) and its notifier ([`crate::alert::notify`]).
//!
//! Alert semantics the daemon relies on: the staleness clock of a gate restarts only on
//! `data_seen`, called on every accepted ingestion (and once when a gate is created); an
//! identification never feeds it. `AlertEngine::is_firing` is the truth about
//! `GateNegativeDamping` (shown as `firing` in the API), while the displayed `state()` may be
//! `unknown` after an untrusted window or while the data is stale.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, Weak};
use std::time::{Duration, SystemTime};

use serde::Serialize;

use super::clock::unix_seconds;
use super::config::{Config, GateConfig};
use super::ingest::{BadRequest, Batch};
use super::log_limit::{BatchLog, LogLimiter};
use super::metrics::{Metrics, NotificationCounts, RejectReason};
use super::storage::{identification_record, Persistence};
use super::sync::lock;
use super::window::{history_samples, Window};
use super::window_span::CycleSpan;
use super::worker::{Job, JobOutcome, Submitted, WindowAnalyzer, WorkerPool};
use crate::alert::notify::{spawn_notifier_with_ack, NotifierHandle};
use crate::alert::{Alert, AlertEngine, AlertEvent, GateState, Observation};
use crate::analysis::{
    AmbientLevel, AnalysisError, CycleAmplitude, DampingTrend, TrendEstimate, WindowAnalysis,
    ZetaPools,
};
use crate::data::MAX_ABS_VALUE;

pub use super::window::RATE_TOLERANCE;

/// Gates named at most in one log line about many (the restored gates left out at start by
/// `server.max_gates`): the line stays readable, its count says how many there were.
const LOGGED_GATES: usize = 20;

/// Why a request's samples were refused (nothing was applied).
#[derive(Debug, Clone, PartialEq)]
pub enum IngestError {
    /// 400 with details.
    BadRequest(BadRequest),
    /// 404: the gate is not configured and `accept_unknown_gates = false`.
    UnknownGate(String),
    /// 400: accepting the gate would exceed `server.max_gates`.
    TooManyGates(RefusedGate),
}

/// The gate [`IngestError::TooManyGates`] refused, and where it was in the request.
#[derive(Debug, Clone, PartialEq)]
pub struct RefusedGate {
    /// The gate id.
    pub gate: String,
    /// Its first line (line protocol).
    pub line: Option<usize>,
    /// Its batch among `batches` of the request (JSON: the array element).
    pub batch: usize,
    /// The request's batches.
    pub batches: usize,
}

/// What an accepted request did.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct IngestSummary {
    /// Samples appended.
    pub accepted: u64,
    /// Duplicates dropped.
    pub duplicate: u64,
    /// Out-of-order samples dropped.
    pub out_of_order: u64,
    /// Windows submitted for identification.
    pub jobs: u64,
}

/// A gate's failed identifications are logged at most once per this interval, with the number
/// held back: a window that cannot be analysed (a constant signal) fails every
/// `identify_every_seconds`, and logged a warning each time (17 280 lines a day per gate at 5 s,
/// 1.1 million at 64 gates). Every failure is still counted
/// (`gatewatch_identification_failures_total`) and the gate's view shows the last error. The
/// same interval bounds a gate's sample-rate warnings (a source at the wrong rate mismatches
/// every window; each is counted in `gatewatch_samples_rejected_total{reason="rate_mismatch"}`).
pub const FAILURE_LOG_INTERVAL: Duration = Duration::from_secs(60);

struct GateEntry {
    config: GateConfig,
    window: Window,
    latest: Option<WindowAnalysis>,
    last_identification: Option<SystemTime>,
    /// `(start, end)` sample times of the window of `latest`.
    latest_window: Option<(f64, f64)>,
    /// Sample time of the end of the last window whose job finished (succeeded or failed).
    analysed_until: Option<f64>,
    last_error: Option<String>,
    /// Its failed identifications' warnings, at most one per [`FAILURE_LOG_INTERVAL`].
    failure_log: LogLimiter,
    /// Its sample-rate mismatches' warnings, at most one per [`FAILURE_LOG_INTERVAL`].
    rate_log: LogLimiter,
    /// Its warnings that a window held too few cycles to be evidence
    /// (`analysis::refuse_few_cycles`), at most one per [`FAILURE_LOG_INTERVAL`].
    cycles_log: LogLimiter,
    /// Trend of `zeta0` over the last `alert.trend_horizon_seconds` (GateDampingDeclining).
    trend: DampingTrend,
    /// Its latest estimate, for the API.
    trend_estimate: Option<TrendEstimate>,
    /// The gate's ambient level (each report's `ambient_ratio`).
    level: AmbientLevel,
    /// The gate's pooled model-free estimates (`None`: pooling off).
    pools: Option<ZetaPools>,
    /// The damping law of the gate's last growth, which reads its limit cycle's amplitude.
    cycle: CycleAmplitude,
    /// How much of the history an identification reads (`window_cycles` of the gate's
    /// frequency, at least the window).
    span: CycleSpan,
    /// Wall-clock time of the last samples (or of creation): gate expiry is counted from it.
    last_data: SystemTime,
    /// Created by `accept_unknown_gates` (not a `[gates.*]` table): such a gate expires after
    /// `server.unknown_gate_expiry_seconds` of silence, configured gates never do.
    unknown: bool,
    /// Whether the expiry holds this silent unknown gate because one of its alerts that silence
    /// does not resolve fires (`expiry::holding_alert`): the hold is logged once, when it
    /// begins, not once a second; the gate's next samples end it.
    held: bool,
    /// Whether its silence pages (`GateDataStale`): always for a configured gate, and for a
    /// restored one (it was streaming before the restart); for a gate created by
    /// `accept_unknown_gates` once its window has filled. A stray sender's few samples (a typo
    /// in a gate's name, a test) are not a sensor that died, and paged critical within
    /// `stale_after_seconds` until the gate expired (docs/alerts.md, "GateDataStale").
    stale_armed: bool,
    /// Which life of the gate this entry is ([`Job::generation`]): an expired gate that sends
    /// again gets a new entry with a new number, so a job of its earlier life still in flight
    /// reports on nothing.
    generation: u64,
}

struct Inner {
    gates: BTreeMap<String, GateEntry>,
    alerts: AlertEngine,
    /// Memories rebuilt from the store at start for gates without an entry yet (unknown gates
    /// until they send again), at most `max_gates`; taken by `ensure_gate`, and dropped at the
    /// first tick `server.unknown_gate_expiry_seconds` after the start.
    resumed: BTreeMap<String, super::resume::GateMemory>,
    /// When the start was (for dropping `resumed` and expiring restored alert states).
    started: SystemTime,
    /// Whether the alert states restored at start for gates without an entry were expired
    /// (`expiry::expire_restored_orphans`, once).
    orphans_swept: bool,
    /// The generation of the next gate entry made (`GateEntry::generation`).
    next_generation: u64,
}

/// The state shared by handlers, listeners and workers.
pub struct AppState {
    /// The configuration in force.
    pub config: Arc<Config>,
    /// Metrics.
    pub metrics: Metrics,
    inner: Mutex<Inner>,
    pool: OnceLock<WorkerPool>,
    notifier: NotifierHandle,
    notifier_task: Mutex<Option<tokio::task::JoinHandle<()>>>,
    notification_counts: NotificationCounts,
    /// Listeners up.
    pub listeners_up: AtomicBool,
    /// Permits of ingestion requests in progress (`server.max_concurrent_ingest`).
    pub ingest_permits: Arc<tokio::sync::Semaphore>,
    /// The store (`[storage]`), when the daemon has one (`serve`, `demo`); `None` keeps
    /// everything in memory (library use, in-process tests).
    pub persistence: Option<Arc<Persistence>>,
    /// Warnings of windows dropped on a full job queue, at most one per
    /// [`FAILURE_LOG_INTERVAL`] for the daemon (each is counted in the failures metric).
    queue_full_log: Mutex<LogLimiter>,
}

impl std::fmt::Debug for AppState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AppState").finish_non_exhaustive()
    }
}

/// Lower-case name of an alert state (label value of `gatewatch_alert_state`).
pub fn state_name(s: GateState) -> &'static str {
    s.as_str()
}

mod expiry;
mod view;

pub use expiry::{ForgetError, Forgotten};
pub use view::{GateSummary, GateView, IdentificationView, WindowView};

impl AppState {
    /// Creates the state, the notifier task and the worker pool. Needs a tokio runtime.
    pub fn new(
        config: Config,
        analyzer: Arc<dyn WindowAnalyzer>,
    ) -> std::io::Result<Arc<AppState>> {
        Self::with_persistence(config, analyzer, None)
    }

    /// [`AppState::new`] with a store: the alert states and the undelivered notifications are
    /// restored from it (blocking reads: call off the async executor, e.g. in
    /// `spawn_blocking`), and every transition is written before it is sent.
    pub fn with_persistence(
        mut config: Config,
        analyzer: Arc<dyn WindowAnalyzer>,
        persistence: Option<Persistence>,
    ) -> std::io::Result<Arc<AppState>> {
        let persistence = persistence.map(Arc::new);
        if persistence.is_some() {
            config.notify.outbox_max_age = Some(config.storage.notification_max_age());
        }
        let ack = super::storage::ack(persistence.as_ref());
        let config = Arc::new(config);
        let threads = config.server.effective_worker_threads();
        let queue = config.server.effective_job_queue();
        let state = Arc::new_cyclic(|weak: &Weak<AppState>| {
            let w = weak.clone();
            let (notifier, task) = spawn_notifier_with_ack(
                config.notify.clone(),
                move || {
                    w.upgrade()
                        .map(|s| lock(&s.inner).alerts.firing())
                        .unwrap_or_default()
                },
                ack,
            );
            AppState {
                config: config.clone(),
                metrics: Metrics::new(),
                inner: Mutex::new(Inner {
                    gates: BTreeMap::new(),
                    alerts: AlertEngine::new(config.defaults.alert.clone()),
                    resumed: BTreeMap::new(),
                    started: SystemTime::now(),
                    orphans_swept: false,
                    next_generation: 0,
                }),
                pool: OnceLock::new(),
                notifier,
                notifier_task: Mutex::new(Some(task)),
                notification_counts: NotificationCounts::default(),
                listeners_up: AtomicBool::new(false),
                ingest_permits: Arc::new(tokio::sync::Semaphore::new(
                    config.server.max_concurrent_ingest,
                )),
                persistence: persistence.clone(),
                queue_full_log: Mutex::new(LogLimiter::new(FAILURE_LOG_INTERVAL)),
            }
        });
        let weak = Arc::downgrade(&state);
        // before the configured gates get their entries, which take their memories
        let resumed = match &state.persistence {
            Some(p) if config.storage.resume_analysis => {
                super::resume::read(p.store.as_ref(), &config, analyzer.as_ref())
            }
            _ => BTreeMap::new(),
        };
        let skipped: usize = resumed.values().map(|m| m.skipped).sum();
        state
            .metrics
            .store_restore_skipped
            .with_label_values(&["history"])
            .inc_by(skipped as u64);
        if let Some(p) = &state.persistence {
            state
                .metrics
                .store_restore_skipped
                .with_label_values(&["wal_frame"])
                .inc_by(p.wal_frames_dropped());
        }
        lock(&state.inner).resumed = resumed;
        let pool = WorkerPool::start(
            threads,
            queue,
            analyzer,
            Arc::new(move |job: &Job, outcome: JobOutcome, elapsed: Duration| {
                if let Some(s) = weak.upgrade() {
                    s.on_result(job, outcome, elapsed);
                }
            }),
        )?;
        let _ = state.pool.set(pool);
        // configured gates exist from the start, so a silent sensor goes stale
        {
            let now = SystemTime::now();
            let mut inner = lock(&state.inner);
            for id in config.gates.keys() {
                state.ensure_gate(&mut inner, id, now, true);
            }
            if let Some(p) = &state.persistence {
                super::storage::resume(&state.metrics, p, &mut inner.alerts, &state.notifier, now);
                state.materialise_restored(&mut inner, p, now);
            }
        }
        Ok(state)
    }

    /// The worker pool.
    pub fn pool(&self) -> &WorkerPool {
        self.pool.get().expect("pool is set in new")
    }

    /// Ready: listeners up, every worker running, and the store (when there is one) still
    /// writing to its file (not deleted or replaced under the daemon: `StoreWriter::healthy`;
    /// its last write did not fail: `StoreWriter::failing`).
    pub fn ready(&self) -> bool {
        self.not_ready().is_none()
    }

    /// Why the daemon is not ready (`/readyz` 503 says it), or `None` when it is: the listeners
    /// are not up (starting, or shutting down), the store's writes fail (a full disk, an I/O
    /// error: `StoreWriter::failing`, naming the file; cleared by the next write that
    /// succeeds, so not a liveness failure), or one of [`Self::unrecoverable`].
    pub fn not_ready(&self) -> Option<String> {
        let mut why = Vec::new();
        if !self.listeners_up.load(Ordering::SeqCst) {
            why.push("listeners not up (starting or shutting down)".to_string());
        }
        if let Some(failing) = self.persistence.as_ref().and_then(|p| p.writer.failing()) {
            why.push(failing);
        }
        why.extend(self.unrecoverable());
        (!why.is_empty()).then(|| why.join("; "))
    }

    /// Why the daemon cannot recover without a restart (`/healthz` 503 says it, so that an
    /// orchestrator's liveness probe restarts it), or `None`. Three states: an identification
    /// worker thread no longer runs (nothing restarts it: the gates' windows pile up unanalysed),
    /// one identification has run past `server.identification_timeout_seconds` (its worker is
    /// stuck: a thread cannot be stopped from outside, and its gate is not identified again
    /// while it runs; the state ends by itself if the job returns), or the store's file was deleted or replaced under the daemon (every write is refused
    /// until the same file is back at its path, which a deletion never brings) or the NATS
    /// store's prefix was taken by another daemon (its owner lease lost: nothing is written
    /// any more). Readiness alone failed there, and a pod out of its endpoints with a live
    /// `/healthz` was never restarted.
    pub fn unrecoverable(&self) -> Vec<String> {
        let mut why = Vec::new();
        let (running, wanted) = (
            self.pool().running_workers(),
            self.config.server.effective_worker_threads(),
        );
        // fewer only after a worker thread died, or once the shutdown closed the pool
        if running < wanted {
            why.push(format!(
                "{running} of {wanted} identification worker threads running"
            ));
        }
        let limit = &self.config.server;
        for o in self.pool().overdue(limit.identification_timeout()) {
            why.push(format!(
                "the identification of gate `{}` (window ending at sample {}) has run {:.1} s, \
                 past server.identification_timeout_seconds = {}: its worker is stuck",
                o.gate,
                o.end_index,
                o.running.as_secs_f64(),
                limit.identification_timeout_seconds
            ));
        }
        if let Some(p) = self.persistence.as_ref().filter(|p| !p.writer.healthy()) {
            why.push(match p.store.check() {
                // the NATS store's prefix taken by another daemon: the message names it
                Err(e) if e.is_owned() => format!("store {}: {e}", p.store.location()),
                _ => format!(
                    "store {}: the file was deleted or replaced under the daemon, every write \
                     is refused; restart gatewatch",
                    p.store.location()
                ),
            });
        }
        why
    }

    /// The entry of gate `id`, made when it has none (`None` when the configuration does not
    /// accept the gate). `seen`: the sensor counts as seen now (a new gate, or samples
    /// arriving), which restarts its staleness clock and resolves a firing `GateDataStale`;
    /// false for a gate materialised at start from its restored alert state, whose clock
    /// [`AlertEngine::restore_gate`] already set (a `GateDataStale` restored firing stays
    /// firing until samples arrive).
    fn ensure_gate<'a>(
        &self,
        inner: &'a mut Inner,
        id: &str,
        now: SystemTime,
        seen: bool,
    ) -> Option<&'a mut GateEntry> {
        if !inner.gates.contains_key(id) {
            let cfg = self.config.gate(id)?.clone();
            inner.alerts.set_rules(id, cfg.alert.clone());
            let memory = inner.resumed.remove(id);
            let unknown = !self.config.gates.contains_key(id);
            let stale_armed = !unknown || !seen || memory.is_some();
            let (trend, trend_estimate, level, cycle) = match memory {
                Some(m) => {
                    if let Some(p) = m.previous {
                        self.pool().restore(id, p);
                    }
                    (m.trend, m.trend_estimate, m.level, m.cycle)
                }
                None => (
                    DampingTrend::new(cfg.alert.trend_horizon_seconds),
                    None,
                    AmbientLevel::default(),
                    CycleAmplitude::default(),
                ),
            };
            // the alerts restored for the gate stay firing on /metrics as in the API
            let firing: Vec<String> = inner
                .alerts
                .firing_of(id)
                .into_iter()
                .map(|a| a.name)
                .collect();
            let firing: Vec<&str> = firing.iter().map(String::as_str).collect();
            self.metrics.init_gate(id, &firing);
            if trend_estimate.is_some() {
                // the restored trend on the dashboard before the first window, as in the API
                self.metrics.set_trend(id, None, trend_estimate.as_ref());
                // restored with its GateDataStale firing: no prediction until it sends again
                if !seen && inner.alerts.is_stale(id) {
                    self.metrics.clear_predictions(id);
                }
            }
            // the sensor counts as seen at creation, so a gate that never sends goes stale
            let events = if seen && stale_armed {
                inner.alerts.data_seen(id, now)
            } else {
                Vec::new()
            };
            let state = inner.alerts.state(id).unwrap_or(GateState::Unknown);
            self.metrics.set_alert_state(id, state_name(state));
            self.notify(inner, events);
            let generation = inner.next_generation;
            inner.next_generation += 1;
            inner.gates.insert(
                id.to_string(),
                GateEntry {
                    generation,
                    window: Window::with_history(
                        cfg.rate_hz,
                        cfg.window_samples(),
                        cfg.every_samples(),
                        history_samples(cfg.window_samples()),
                    )
                    .staggered(cfg.stagger_samples(id)),
                    trend,
                    level,
                    // validated with the configuration: an error cannot happen here, and would
                    // only mean no pooling
                    pools: cfg.pooling.pools().ok().flatten(),
                    cycle,
                    span: CycleSpan::new(cfg.rate_hz, cfg.window_samples(), cfg.window_cycles),
                    config: cfg,
                    latest: None,
                    last_identification: None,
                    latest_window: None,
                    analysed_until: None,
                    last_error: None,
                    failure_log: LogLimiter::new(FAILURE_LOG_INTERVAL),
                    rate_log: LogLimiter::new(FAILURE_LOG_INTERVAL),
                    cycles_log: LogLimiter::new(FAILURE_LOG_INTERVAL),
                    trend_estimate,
                    last_data: now,
                    unknown,
                    held: false,
                    stale_armed,
                },
            );
        }
        inner.gates.get_mut(id)
    }

    /// At start, after the alert states are restored: gives the restored gates the
    /// configuration accepts (auto-accepted gates of the last run above all) their entries, so
    /// the API lists them and their alerts before their first new sample, as `/metrics` and
    /// Alertmanager show them. They count against `server.max_gates`: when more are restored
    /// than it leaves room for, the gates with a firing alert come first, then the most
    /// recently active (newest stored window), then by name; the rest are logged and keep only
    /// their alert state, which `expire_restored_orphans` forgets
    /// `server.unknown_gate_expiry_seconds` after the start unless they send again (each then
    /// gets its entry if there is room, like any new gate). A materialised auto-accepted gate
    /// that stays silent expires like any unknown gate: `last_data` is the start.
    fn materialise_restored(&self, inner: &mut Inner, p: &Persistence, now: SystemTime) {
        let mut restored: Vec<(bool, f64, String)> = inner
            .alerts
            .gates()
            .into_iter()
            .filter(|g| !inner.gates.contains_key(g) && self.config.gate(g).is_some())
            .map(|g| {
                let firing = !inner.alerts.firing_of(&g).is_empty();
                let newest = match p.store.latest_history_rows(&g, 1) {
                    Ok(rows) => rows.last().map_or(f64::NEG_INFINITY, |r| r.time),
                    Err(e) => {
                        tracing::warn!(gate = %g, store = %p.store.location(), "cannot read the gate's newest window, it ranks last among the restored gates: {e}");
                        f64::NEG_INFINITY
                    }
                };
                (firing, newest, g)
            })
            .collect();
        restored.sort_by(|a, b| {
            b.0.cmp(&a.0)
                .then(b.1.total_cmp(&a.1))
                .then_with(|| a.2.cmp(&b.2))
        });
        let room = self
            .config
            .server
            .max_gates
            .saturating_sub(inner.gates.len());
        let left: Vec<String> = restored.iter().skip(room).map(|r| r.2.clone()).collect();
        let made = restored.len() - left.len();
        for (_, _, g) in restored.into_iter().take(room) {
            self.ensure_gate(inner, &g, now, false);
        }
        if !left.is_empty() {
            tracing::warn!(
                max_gates = self.config.server.max_gates,
                materialised = made,
                left = left.len(),
                gates = %left.iter().take(LOGGED_GATES).cloned().collect::<Vec<_>>().join(","),
                "more gates restored from the store than server.max_gates leaves room for: \
                 these are not in the API until they send again (if there is room then); \
                 their alerts are forgotten server.unknown_gate_expiry_seconds after the start"
            );
        } else if made > 0 {
            tracing::info!(
                gates = made,
                "gates restored from the store are listed in the API"
            );
        }
    }

    fn notify(&self, held: &Inner, events: Vec<AlertEvent>) {
        self.notify_and_write(held, events, crate::store::WriteBatch::default());
    }

    /// [`AppState::notify`], and with a store: `extra` and the transitions written in one
    /// transaction before they are handed to the notifier.
    ///
    /// `_held` is the state under its lock, which the caller keeps until this returns: the
    /// writes and notifications are queued in the order the state changed. Why: `on_result`
    /// released the lock before it queued a window's write; a gate forgotten in between (its
    /// expiry, or `DELETE`) had its forget write queued first, and the late window write brought
    /// the gate's alert state back at the next start (a CI rehearsal at stop 59). Both queues
    /// are non-blocking (`Writer::submit` and `NotifierHandle::notify` are `try_send`s, a full
    /// queue counts a drop), and neither the store writer nor the notifier takes this lock
    /// while it holds one of its own, so holding it here cannot deadlock.
    fn notify_and_write(
        &self,
        _held: &Inner,
        events: Vec<AlertEvent>,
        extra: crate::store::WriteBatch,
    ) {
        if events.is_empty() {
            if let Some(p) = &self.persistence {
                p.submit(extra, None);
            }
            return;
        }
        // one line per event up to a bound, then one summary (log_limit.rs: a sweep where every
        // gate went stale logged one line per gate)
        let mut lines = BatchLog::new();
        for e in &events {
            let a = e.alert();
            self.metrics
                .set_alert_firing(a.gate(), &a.name, e.is_firing());
            if lines.allow(|| format!("{} {}", a.name, e.status())) {
                tracing::info!(
                    gate = a.gate(),
                    alert = %a.name,
                    status = e.status(),
                    summary = a.annotations.get("summary").map(String::as_str).unwrap_or(""),
                    "alert"
                );
            }
        }
        if let Some((held_back, by_kind)) = lines.held_back() {
            tracing::info!(
                held_back,
                by_kind = %by_kind,
                "more alerts in the same batch, not logged one by one (each is notified, stored \
                 and in gatewatch_alert_firing)"
            );
        }
        if let Some(p) = &self.persistence {
            p.persist_and_notify(&self.notifier, events, extra);
            self.metrics.notifications_queued.inc();
            return;
        }
        // one batch; a full queue drops it and counts it in the notifier's `dropped`
        if self.notifier.notify(events) {
            self.metrics.notifications_queued.inc();
        }
    }

    /// The Prometheus text exposition, with the notifier's counters brought up to date.
    pub fn render_metrics(&self) -> String {
        let longest = self.pool().longest_running().map(|(_, d)| d);
        self.metrics
            .longest_running
            .set(longest.unwrap_or_default().as_secs_f64());
        self.notification_counts
            .sync(&self.metrics, self.notifier.stats().snapshot());
        if let Some(p) = &self.persistence {
            p.sync_metrics(&self.metrics);
        }
        self.metrics.render()
    }

    /// Validates every batch, then applies them all (or none).
    ///
    /// Validation and application happen under ONE lock: the gate bound (`server.max_gates`)
    /// is checked against the gates that exist when the batches are applied, so concurrent
    /// requests creating new gates cannot together pass it.
    pub fn ingest(&self, batches: Vec<Batch>) -> Result<IngestSummary, IngestError> {
        let total: u64 = batches.iter().map(|b| b.samples.len() as u64).sum();
        let now = SystemTime::now();
        let mut summary = IngestSummary::default();
        let mut jobs = Vec::new();
        {
            let mut inner = lock(&self.inner);
            if let Err((reason, e)) = self.validate(&inner, &batches) {
                drop(inner);
                self.metrics.reject(reason, total);
                return Err(e);
            }
            for batch in batches {
                let Some(entry) = self.ensure_gate(&mut inner, &batch.gate, now, true) else {
                    continue; // validated above
                };
                entry.last_data = now;
                entry.held = false;
                let (stats, due, n_due) = entry.window.push_latest(batch.samples.iter().copied());
                let fill = entry.window.fill_ratio();
                let rate = entry.config.rate_hz;
                summary.accepted += stats.accepted;
                summary.duplicate += stats.duplicate;
                summary.out_of_order += stats.out_of_order;
                let g = batch.gate.as_str();
                self.metrics
                    .samples_ingested
                    .with_label_values(&[g])
                    .inc_by(stats.accepted);
                self.metrics
                    .window_fill_ratio
                    .with_label_values(&[g])
                    .set(fill);
                if stats.gaps > 0 {
                    self.metrics
                        .window_gaps
                        .with_label_values(&[g])
                        .inc_by(stats.gaps);
                }
                self.metrics
                    .reject(RejectReason::Duplicate, stats.duplicate);
                self.metrics
                    .reject(RejectReason::OutOfOrder, stats.out_of_order);
                if let Some(implied) = stats.implied_rate_hz {
                    self.metrics
                        .reject(RejectReason::RateMismatch, stats.rate_mismatch);
                    // a source at the wrong rate mismatches every window: one line a minute
                    if let Some(held_back) = entry.rate_log.allow(std::time::Instant::now()) {
                        tracing::warn!(
                            gate = g,
                            implied_rate_hz = implied,
                            rate_hz = rate,
                            samples = stats.rate_mismatch,
                            held_back,
                            "samples imply another sample rate than the gate's (more than 1 % off): their window was not identified and the window restarted; fix the source's rate or the gate's rate_hz"
                        );
                    }
                }
                // only the newest due window matters: older ones are replaced before queueing
                if let Some(w) = due {
                    if n_due > 1 {
                        self.metrics.jobs_replaced.inc_by(n_due - 1);
                    }
                    // a slow gate's identification reads more of the history than the window
                    let (t0, values) = match entry.span.slice(w.t0, &w.values, &w.history) {
                        (t0, read) if read.len() > w.values.len() => (t0, read.to_vec()),
                        _ => (w.t0, w.values),
                    };
                    jobs.push(Job {
                        gate: batch.gate.clone(),
                        t0,
                        rate_hz: rate,
                        values,
                        history: w.history,
                        end_index: w.end_index,
                        generation: entry.generation,
                        ambient_level: entry
                            .level
                            .level()
                            .map(|l| (l, entry.level.departure_ratio())),
                    });
                }
                // a gate created by accept_unknown_gates counts as a sensor once its window
                // has filled (`GateEntry::stale_armed`)
                entry.stale_armed |= fill >= 1.0;
                let events = if entry.stale_armed {
                    inner.alerts.data_seen(g, now)
                } else {
                    Vec::new()
                };
                if !events.is_empty() {
                    let state = inner.alerts.state(g).unwrap_or(GateState::Unknown);
                    self.metrics.set_alert_state(g, state_name(state));
                }
                self.notify(&inner, events);
            }
        }
        for job in jobs {
            summary.jobs += 1;
            self.submit(job);
        }
        Ok(summary)
    }

    /// Submits a job to the pool, counting replacements and drops.
    pub fn submit(&self, job: Job) {
        let gate = job.gate.clone();
        match self.pool().submit(job) {
            Submitted::Queued => {}
            Submitted::Replaced => self.metrics.jobs_replaced.inc(),
            Submitted::QueueFull => {
                if let Some(held_back) = lock(&self.queue_full_log).allow(std::time::Instant::now())
                {
                    tracing::warn!(%gate, held_back, "identification queue full, window dropped");
                }
                self.metrics
                    .identification_failures
                    .with_label_values(&["queue_full"])
                    .inc();
            }
            Submitted::Closed => {}
        }
    }

    /// Checks every batch against `inner` (the caller holds its lock and applies under the same
    /// lock); on error also gives the `samples_rejected_total` reason.
    fn validate(
        &self,
        inner: &MutexGuard<'_, Inner>,
        batches: &[Batch],
    ) -> Result<(), (RejectReason, IngestError)> {
        let mut new_gates: Vec<&str> = Vec::new();
        let now = super::clock::now_unix();
        for (k, b) in batches.iter().enumerate() {
            let Some(cfg) = self.config.gate(&b.gate) else {
                return Err((
                    RejectReason::UnknownGate,
                    IngestError::UnknownGate(b.gate.clone()),
                ));
            };
            if !inner.gates.contains_key(&b.gate) && !new_gates.contains(&b.gate.as_str()) {
                new_gates.push(&b.gate);
                if inner.gates.len() + new_gates.len() > self.config.server.max_gates {
                    return Err((
                        RejectReason::TooManyGates,
                        IngestError::TooManyGates(RefusedGate {
                            gate: b.gate.clone(),
                            line: b.lines.as_ref().and_then(|l| l.first().copied()),
                            batch: k,
                            batches: batches.len(),
                        }),
                    ));
                }
            }
            for (i, (t, v)) in b.samples.iter().enumerate() {
                if !v.is_finite() || !t.is_finite() {
                    let what = if v.is_finite() { "time" } else { "value" };
                    let got = if v.is_finite() { *t } else { *v };
                    let mut e = BadRequest::new(format!("sample {what} must be finite, got {got}"))
                        .field(b.values_field.clone());
                    match &b.lines {
                        Some(lines) => e.line = lines.get(i).copied(),
                        None => e.index = Some(i),
                    }
                    return Err((RejectReason::NonFinite, IngestError::BadRequest(e)));
                }
                // the analysis refuses the whole window holding such a value, for as long as
                // it is in the window (`TimeSeries::new`): refused here, by its sample, instead
                if v.abs() > MAX_ABS_VALUE {
                    let mut e = BadRequest::new(format!(
                        "sample value {v:e} is beyond +-{MAX_ABS_VALUE:e}, where the analysis \
                         overflows (a broken sensor or a unit error?)"
                    ))
                    .field(b.values_field.clone());
                    match &b.lines {
                        Some(lines) => e.line = lines.get(i).copied(),
                        None => e.index = Some(i),
                    }
                    return Err((RejectReason::OutOfRange, IngestError::BadRequest(e)));
                }
            }
            // before the window sees them: a far-future time would restart it (see ingest_checks)
            super::ingest_checks::check_times(b, cfg, now)
                .map_err(|(reason, e)| (reason, IngestError::BadRequest(e)))?;
            // line protocol whose unit cannot tell the gate's samples apart (`precision=s` at
            // 200 Hz) implies no rate: its lines are duplicates, counted as such
            let resolves = b
                .precision
                .is_none_or(|p| p.seconds_per_unit() * cfg.rate_hz <= 0.5);
            if let Some((rate, field)) = b.rate.as_ref().filter(|_| resolves) {
                if ((rate - cfg.rate_hz) / cfg.rate_hz).abs() > RATE_TOLERANCE {
                    let mut e = BadRequest::new(format!(
                        "sample rate {} Hz disagrees with the configured {} Hz of gate `{}` by more than 1 %",
                        // to a thousandth: times in ms implied 249.9999999988063 Hz
                        crate::number::Num((rate * 1e3).round() / 1e3),
                        crate::number::Num(cfg.rate_hz),
                        b.gate
                    ))
                    .field(field.clone());
                    // line protocol: the gate's first line
                    e.line = b.lines.as_ref().and_then(|l| l.first().copied());
                    return Err((RejectReason::RateMismatch, IngestError::BadRequest(e)));
                }
            }
        }
        Ok(())
    }

    fn on_result(&self, job: &Job, outcome: JobOutcome, elapsed: Duration) {
        self.metrics
            .identification_duration
            .observe(elapsed.as_secs_f64());
        let g = job.gate.as_str();
        let now = SystemTime::now();
        let window = (
            job.t0,
            job.t0 + job.values.len().saturating_sub(1) as f64 / job.rate_hz,
        );
        let mut inner = lock(&self.inner);
        let Some(e) = inner
            .gates
            .get_mut(g)
            .filter(|e| e.generation == job.generation)
        else {
            // the gate expired while its job ran (and may have come back since, as a new gate
            // with a new window of its own): nothing to report on
            return;
        };
        e.analysed_until = Some(window.1);
        match outcome {
            JobOutcome::Done(mut a) => {
                e.level.observe_span(&mut a.damping, window.0, window.1);
                crate::analysis::read_growing_window(&mut a.damping);
                if let Some(p) = e.pools.as_mut() {
                    p.apply(window.0, window.1, &mut a.damping);
                }
                e.cycle.observe(window.1, &mut a.damping);
                if !e.cycle.read_fall(window.1, &mut a.damping) {
                    crate::analysis::span_the_fall(&mut a.damping);
                }
                // a window of a few cycles is no evidence, whichever source read it: the gate
                // needs a longer window (one line a minute says so)
                if crate::analysis::refuse_few_cycles(&mut a.damping) {
                    if let Some(held_back) = e.cycles_log.allow(std::time::Instant::now()) {
                        tracing::warn!(
                            gate = g,
                            window_cycles = a.damping.window_cycles,
                            frequency_hz = a.damping.frequency_hz,
                            window_seconds = window.1 - window.0,
                            min_cycles = crate::analysis::MIN_WINDOW_CYCLES,
                            held_back,
                            "the window holds too few cycles of the gate's vibration for its damping to be evidence: reported untrusted, no alert; it lengthens to window_cycles once the gate's frequency is known, up to six window_seconds: if this goes on, lengthen [gates.ID] window_seconds (docs/operations.md \"A slow gate\")"
                        );
                    }
                }
                // the next windows read window_cycles of the gate's frequency, its pools span
                // at least three of them, and its history holds what the envelope reads
                if e.span.observe(a.damping.frequency_hz) {
                    let seconds = e.span.seconds();
                    let pool_seconds = e.pools.as_mut().map(|p| p.follow_window(seconds));
                    e.window.set_history(e.span.history_samples());
                    tracing::info!(
                        gate = g,
                        identification_seconds = seconds,
                        history_seconds = e.span.history_samples() as f64 / e.config.rate_hz,
                        frequency_hz = a.damping.frequency_hz,
                        window_cycles = e.config.window_cycles,
                        pool_max_seconds = pool_seconds,
                        "the gate's identifications read a new length of record, to hold window_cycles of its frequency"
                    );
                }
                let rules = inner.alerts.rules(g);
                let (fire_below, min_span) = (rules.fire_below, rules.trend_min_span_seconds);
                let trend = inner.gates.get_mut(g).and_then(|e| {
                    let reading = crate::analysis::trend_reading(&a.damping, window.1 - window.0);
                    e.trend_estimate = e.trend.observe(window.1, reading, fire_below);
                    e.trend_estimate
                });
                // a declining gate's interval reaches down to its trend's forecast
                // (docs/damping.md, "A declining gate's interval reaches down to its trend")
                if let (Some(t), Some(e)) = (&trend, inner.gates.get(g)) {
                    let (end, seconds) = (window.1, window.1 - window.0);
                    crate::analysis::reach_down_to_trend(
                        &mut a.damping,
                        t,
                        &e.trend,
                        end,
                        seconds,
                        min_span,
                    );
                }
                let d = &a.damping;
                let set = |gv: &prometheus::GaugeVec, v: Option<f64>| {
                    if let Some(v) = v.filter(|v| v.is_finite()) {
                        gv.with_label_values(&[g]).set(v);
                    }
                };
                set(&self.metrics.damping_ratio, d.zeta0);
                set(
                    &self.metrics.damping_trusted,
                    Some(if d.trusted { 1.0 } else { 0.0 }),
                );
                set(&self.metrics.equivalent_damping_ratio, d.zeta_eq);
                set(&self.metrics.frequency_hertz, d.frequency_hz);
                set(
                    &self.metrics.identification_record_seconds,
                    Some(job.values.len() as f64 / job.rate_hz),
                );
                set(&self.metrics.fit_nmae, Some(d.fit_nmae));
                set(&self.metrics.amplitude, d.amplitude);
                for (name, v) in &a.coefficients {
                    if v.is_finite() {
                        self.metrics
                            .model_coefficient
                            .with_label_values(&[g, name])
                            .set(*v);
                    }
                }
                self.metrics
                    .last_identification
                    .with_label_values(&[g])
                    .set(unix_seconds(now));
                self.metrics
                    .identifications
                    .with_label_values(&[g, a.path.as_str()])
                    .inc();
                self.metrics.set_trend(g, d.zeta0_interval, trend.as_ref());
                // a window that was in flight when its gate went silent: the gate still predicts
                // nothing, as the stale tick left it (`Metrics::clear_predictions`), until it
                // sends again
                if inner.alerts.is_stale(g) {
                    self.metrics.clear_predictions(g);
                }
                // the unit of the signal, hence of the limit cycle's amplitude
                let amplitude_unit = match self.config.gate(g).map(|c| c.signal) {
                    Some(crate::analysis::Signal::Force) => "N",
                    Some(crate::analysis::Signal::Displacement) => "m",
                    None => "",
                };
                let events = inner.alerts.observe(
                    g,
                    &Observation {
                        zeta0: d.zeta0,
                        // the window's own: the alert decides on the window's evidence
                        zeta0_interval: d.own_interval(),
                        trend,
                        trusted: d.trusted,
                        ambient_ratio: d.ambient_ratio,
                        departure_ratio: d.departure_ratio,
                        limit_cycle: d.regime == Some(crate::spectral::Regime::LimitCycle),
                        growing: d.regime == Some(crate::spectral::Regime::SelfExcited),
                        frequency_hz: d.frequency_hz,
                        zeta0_source: d.zeta0_source,
                        limit_cycle_amplitude: d.limit_cycle_amplitude,
                        amplitude_unit,
                        time_to_limit: d.time_to_limit,
                        equation: &a.equation,
                    },
                    now,
                );
                let state = inner.alerts.state(g).unwrap_or(GateState::Unknown);
                self.metrics.set_alert_state(g, state_name(state));
                let write = super::storage::window_write(
                    self.persistence.as_deref(),
                    &inner.alerts,
                    g,
                    identification_record(g, now, window, &a),
                );
                if let Some(e) = inner.gates.get_mut(g) {
                    e.latest = Some(*a);
                    e.last_identification = Some(now);
                    e.latest_window = Some(window);
                    e.last_error = None;
                }
                self.notify_and_write(&inner, events, write);
            }
            JobOutcome::Failed(err) => {
                let reason = match err {
                    AnalysisError::Settings(_) => "settings",
                    AnalysisError::Window(_) => "window",
                };
                self.metrics
                    .identification_failures
                    .with_label_values(&[reason])
                    .inc();
                // a window that cannot be analysed (a constant signal: a sensor stuck, a gate at
                // rest) fails again every `identify_every_seconds`: one line a minute per gate
                let held_back = inner.gates.get_mut(g).and_then(|e| {
                    e.last_error = Some(err.to_string());
                    e.failure_log.allow(std::time::Instant::now())
                });
                match held_back {
                    Some(held_back) => tracing::warn!(
                        gate = g,
                        error = %err,
                        held_back,
                        "identification failed (held_back: failures of the gate since its last \
                         such line, each counted in gatewatch_identification_failures_total)"
                    ),
                    None => tracing::debug!(gate = g, error = %err, "identification failed"),
                }
            }
            JobOutcome::Panicked(msg) => {
                tracing::error!(gate = g, panic = %msg, "identification panicked");
                self.metrics
                    .identification_failures
                    .with_label_values(&["panic"])
                    .inc();
                if let Some(e) = inner.gates.get_mut(g) {
                    e.last_error = Some("internal error in the identification".into());
                }
            }
        }
    }

    /// Alert state of a gate.
    pub fn alert_state(&self, gate: &str) -> Option<&'static str> {
        lock(&self.inner).alerts.state(gate).map(state_name)
    }

    /// One page of the gate list: at most `limit` gates whose ids sort after `after`, as small
    /// summaries, and the id to continue after when more remain. The lock is held only while
    /// this bounded page is copied; the caller serialises it without the lock, so a listing of
    /// thousands of gates holds up ingestion for one page's copy at most.
    pub fn gate_page(
        &self,
        after: Option<&str>,
        limit: usize,
    ) -> (Vec<GateSummary>, Option<String>) {
        use std::ops::Bound;
        let inner = lock(&self.inner);
        let lower = after.map_or(Bound::Unbounded, Bound::Excluded);
        let mut range = inner
            .gates
            .range::<str, _>((lower, Bound::Unbounded))
            .peekable();
        let mut page = Vec::with_capacity(limit.min(inner.gates.len()));
        while page.len() < limit {
            let Some((id, e)) = range.next() else { break };
            page.push(GateSummary {
                gate: id.clone(),
                alert_state: state_name(inner.alerts.state(id).unwrap_or(GateState::Unknown)),
                firing: inner.alerts.is_firing(id),
                stale: inner.alerts.is_stale(id),
                samples: e.window.len(),
                last_sample_time: e.window.last_time(),
                zeta0: e.latest.as_ref().and_then(|a| a.damping.zeta0),
                trusted: e.latest.as_ref().map(|a| a.damping.trusted),
            });
        }
        let next = match range.peek() {
            Some(_) => page.last().map(|g| g.gate.clone()),
            None => None,
        };
        (page, next)
    }

    /// Known gate ids.
    pub fn gate_ids(&self) -> Vec<String> {
        lock(&self.inner).gates.keys().cloned().collect()
    }

    /// One gate's view.
    pub fn gate_view(&self, id: &str) -> Option<GateView> {
        let inner = lock(&self.inner);
        let e = inner.gates.get(id)?;
        let w = &e.window;
        Some(GateView {
            gate: id.to_string(),
            alert_state: state_name(inner.alerts.state(id).unwrap_or(GateState::Unknown)),
            firing: inner.alerts.is_firing(id),
            alerts: inner.alerts.firing_of(id),
            window: WindowView {
                samples: w.len(),
                capacity: w.capacity(),
                span_seconds: w.span_seconds(),
                fill: w.fill_ratio(),
                last_sample_time: w.last_time(),
                samples_total: w.accepted_total(),
                rate_hz: e.config.rate_hz,
                stagger_seconds: w.offset() as f64 / e.config.rate_hz,
                identification_seconds: e.span.seconds(),
            },
            identification: e.latest.as_ref().map(|a| IdentificationView {
                time: e.last_identification.map(unix_seconds).unwrap_or(0.0),
                window_start: e.latest_window.map(|w| w.0).unwrap_or(0.0),
                window_end: e.latest_window.map(|w| w.1).unwrap_or(0.0),
                equation: a.equation.clone(),
                coefficients: a.coefficients.iter().cloned().collect(),
                damping: a.damping.clone(),
                seconds: a.seconds,
                path: a.path,
            }),
            last_error: e.last_error.clone(),
            analysed_until: e.analysed_until,
            // a silent gate predicts nothing, as on /metrics (`Metrics::clear_predictions`): its
            // crossing would stay frozen while the time it counts down passes
            trend: e.trend_estimate.map(|mut t| {
                if inner.alerts.is_stale(id) {
                    t.crossing_seconds = None;
                    t.crossing_seconds_confident = None;
                }
                t
            }),
        })
    }

    /// Stops the notifier: delivers what is queued (with retries) for at most `within`, then
    /// abandons the rest (counted as dropped). Returns whether everything was handled in time.
    /// Returns within `within` (plus scheduling): the dispatcher task is awaited only for what
    /// is left of it, and one that has not ended by then is left to the process exit.
    pub async fn shutdown_notifier(&self, within: Duration) -> bool {
        let deadline = tokio::time::Instant::now() + within;
        let clean = self.notifier.shutdown(within).await;
        let task = lock(&self.notifier_task).take();
        if let Some(task) = task {
            // after `shutdown` the dispatcher ends promptly (flushed or aborted)
            let _ = tokio::time::timeout_at(deadline, task).await;
        }
        self.notification_counts
            .sync(&self.metrics, self.notifier.stats().snapshot());
        clean
    }
}
