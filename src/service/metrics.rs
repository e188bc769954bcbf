//! Prometheus metrics, one typed struct registered once in its own [`Registry`].
//!
//! Label values are bounded: `gate` by `server.max_gates`, `route` by the route templates
//! (axum `MatchedPath`, never the raw URI; unmatched requests are `route="unmatched"`), `code`
//! by HTTP, `reason`, `state`, `alertname`, `target`, `outcome` and `coefficient` by code or
//! model. Counters whose label values are known in advance are created at 0 at start-up (per
//! gate: when the gate is created), so `rate()` and `increase()` see their first event.
//!
//! One unit per counter: `gatewatch_samples_rejected_total` counts samples (a TCP line is one
//! sample), `gatewatch_ingest_requests_rejected_total` counts whole requests refused before any
//! sample could be read (body too large, unparseable, overloaded).

use std::collections::HashMap;

use prometheus::core::{Collector, MetricVec, MetricVecBuilder};
use prometheus::{
    Encoder, Gauge, GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec,
    Opts, Registry, TextEncoder,
};

use crate::alert::notify::{StatsSnapshot, TargetType};
use crate::alert::{ALERT_DAMPING_DECLINING, ALERT_DATA_STALE, ALERT_NEGATIVE_DAMPING};
use crate::analysis::TrendEstimate;

/// Buckets of the identification duration, seconds (a window takes 0.1 s to a minute).
const IDENTIFICATION_BUCKETS: &[f64] =
    &[0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0];
/// Buckets of the HTTP request duration, seconds.
const HTTP_BUCKETS: &[f64] = &[0.001, 0.005, 0.01, 0.05, 0.1, 0.5, 1.0, 5.0, 30.0];

/// Every metric of the daemon.
#[derive(Debug, Clone)]
pub struct Metrics {
    registry: Registry,
    /// `gatewatch_damping_ratio{gate}`.
    pub damping_ratio: GaugeVec,
    /// `gatewatch_damping_trusted{gate}`: 1 when the latest window's `zeta0` is trusted, 0 when
    /// not (an untrusted window still sets `gatewatch_damping_ratio`, which a rule or a panel
    /// should then not read as the gate's damping).
    pub damping_trusted: GaugeVec,
    /// `gatewatch_damping_ratio_lower{gate}`: lower end of zeta0's 95 % interval.
    pub damping_ratio_lower: GaugeVec,
    /// `gatewatch_damping_ratio_upper{gate}`: upper end of zeta0's 95 % interval.
    pub damping_ratio_upper: GaugeVec,
    /// `gatewatch_damping_ratio_trend_per_second{gate}`: slope of zeta0's robust trend.
    pub damping_ratio_trend: GaugeVec,
    /// `gatewatch_damping_zero_crossing_seconds{gate}`: predicted sample time left until zeta0
    /// crosses `fire_below` (confident figure); absent when the trend is not significantly
    /// declining.
    pub damping_zero_crossing: GaugeVec,
    /// `gatewatch_equivalent_damping_ratio{gate}`.
    pub equivalent_damping_ratio: GaugeVec,
    /// `gatewatch_frequency_hertz{gate}`.
    pub frequency_hertz: GaugeVec,
    /// `gatewatch_fit_nmae{gate}`.
    pub fit_nmae: GaugeVec,
    /// `gatewatch_model_coefficient{gate,coefficient}`.
    pub model_coefficient: GaugeVec,
    /// `gatewatch_alert_state{gate,state}`.
    pub alert_state: GaugeVec,
    /// `gatewatch_alert_firing{gate,alertname}`: 1 while gatewatch's own alert fires.
    pub alert_firing: GaugeVec,
    /// `gatewatch_amplitude{gate}`: the window's vibration amplitude, signal units.
    pub amplitude: GaugeVec,
    /// `gatewatch_build_info{version}`, always 1.
    pub build_info: GaugeVec,
    /// `gatewatch_last_identification_timestamp_seconds{gate}`.
    pub last_identification: GaugeVec,
    /// `gatewatch_samples_ingested_total{gate}`.
    pub samples_ingested: IntCounterVec,
    /// `gatewatch_window_fill_ratio{gate}`.
    pub window_fill_ratio: GaugeVec,
    /// `gatewatch_identification_record_seconds{gate}`: the record the last identification read
    /// (the window, or `window_cycles` of a slow gate: `service::window_span`).
    pub identification_record_seconds: GaugeVec,
    /// `gatewatch_window_gaps_total{gate}`.
    pub window_gaps: IntCounterVec,
    /// `gatewatch_samples_rejected_total{reason}`: samples.
    pub samples_rejected: IntCounterVec,
    /// `gatewatch_ingest_requests_rejected_total{reason}`: requests.
    pub requests_rejected: IntCounterVec,
    /// `gatewatch_identification_duration_seconds`.
    pub identification_duration: Histogram,
    /// `gatewatch_identification_jobs_replaced_total`.
    pub jobs_replaced: IntCounter,
    /// `gatewatch_identification_longest_running_seconds`: how long the identification in
    /// flight the longest has run (0: none runs), set at each scrape. Past
    /// `server.identification_timeout_seconds` its worker counts as stuck.
    pub longest_running: Gauge,
    /// `gatewatch_identification_failures_total{reason}`.
    pub identification_failures: IntCounterVec,
    /// `gatewatch_identifications_total{gate,path}`: windows identified, by path ("tracked" or
    /// "full"; two values per gate, and gates are bounded by `max_gates`).
    pub identifications: IntCounterVec,
    /// `gatewatch_http_requests_total{route,code}`.
    pub http_requests: IntCounterVec,
    /// `gatewatch_http_request_duration_seconds{route}`.
    pub http_duration: HistogramVec,
    /// `gatewatch_notifications_queued_total`: batches of alert events handed to the notifier.
    pub notifications_queued: IntCounter,
    /// `gatewatch_notifications_total{target,outcome}`: per target, batches delivered, failed
    /// or dropped.
    pub notifications: IntCounterVec,
    /// `gatewatch_tcp_connections_rejected_total{reason}`: raw TCP connections closed at
    /// accept ([`TCP_CONNECTION_REJECT_REASONS`]).
    pub tcp_connections_rejected: IntCounterVec,
    /// `gatewatch_http_connections_rejected_total`: closed at accept, over
    /// `server.max_http_connections`.
    pub http_connections_rejected: IntCounter,
    /// `gatewatch_health_connections_rejected_total`: closed at accept by the health listener
    /// (`server.health_listen`), over its [`HEALTH_MAX_CONNECTIONS`](super::config::HEALTH_MAX_CONNECTIONS).
    pub health_connections_rejected: IntCounter,
    /// `gatewatch_http_connections_cut_total{listener,reason}`: HTTP connections closed while
    /// their answer was being sent ([`Cut`](super::listen::Cut)), per listener
    /// ([`HTTP_LISTENERS`]).
    pub http_connections_cut: IntCounterVec,
    /// `gatewatch_gates_expired_total`: gates created by `accept_unknown_gates` forgotten after
    /// `server.unknown_gate_expiry_seconds` of silence.
    pub gates_expired: IntCounter,
    /// `gatewatch_gates_deleted_total`: gates an operator forgot through
    /// `DELETE /api/v1/gates/{id}`. Apart from the expiry's count, which says that senders
    /// went away by themselves: a rule or a dashboard watching that should not see an
    /// operator's clean-up as senders vanishing.
    pub gates_deleted: IntCounter,
    /// `gatewatch_store_write_errors_total{reason}`: store writes lost ([`STORE_WRITE_ERRORS`]).
    pub store_write_errors: IntCounterVec,
    /// `gatewatch_store_pruned_rows_total{reason}`: history rows deleted ([`STORE_PRUNE_REASONS`]).
    pub store_pruned_rows: IntCounterVec,
    /// `gatewatch_store_restore_skipped_total{what}`: stored rows that did not decode at start
    /// ([`STORE_RESTORE_SKIPPED`]).
    pub store_restore_skipped: IntCounterVec,
}

/// Why samples were rejected or dropped: the `reason` label of
/// `gatewatch_samples_rejected_total`. An enum, so the label values are bounded by code and
/// every place that rejects counts the same way ([`Metrics::reject`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RejectReason {
    /// Unparseable request body (JSON, line protocol, not UTF-8).
    Invalid,
    /// Body over `server.body_limit_bytes`.
    BodyTooLarge,
    /// More than `server.max_concurrent_ingest` ingestion requests at once.
    Overloaded,
    /// Gate not configured while `accept_unknown_gates = false`.
    UnknownGate,
    /// A new gate beyond `server.max_gates`.
    TooManyGates,
    /// A non-finite time or value.
    NonFinite,
    /// A finite value beyond the analysis' bound (`data::MAX_ABS_VALUE`, 1e100): every window
    /// holding it would fail.
    OutOfRange,
    /// Declared or implied rate more than 1 % off the gate's `rate_hz`.
    RateMismatch,
    /// Within half a period of the newest sample.
    Duplicate,
    /// Older than the newest sample.
    OutOfOrder,
    /// A raw TCP line that cannot be parsed or is too long.
    BadLine,
    /// A sample time more than the gate's `max_future_seconds` ahead of the daemon's clock.
    TooFarInFuture,
    /// A sample time more than the gate's `max_past_seconds` behind the daemon's clock.
    TooOld,
}

impl RejectReason {
    /// Every reason, for the counters' initial 0.
    pub const ALL: [RejectReason; 13] = [
        RejectReason::Invalid,
        RejectReason::BodyTooLarge,
        RejectReason::Overloaded,
        RejectReason::UnknownGate,
        RejectReason::TooManyGates,
        RejectReason::NonFinite,
        RejectReason::OutOfRange,
        RejectReason::RateMismatch,
        RejectReason::Duplicate,
        RejectReason::OutOfOrder,
        RejectReason::BadLine,
        RejectReason::TooFarInFuture,
        RejectReason::TooOld,
    ];

    /// Whether the reason refuses a whole request before any sample is read (counted in
    /// requests), rather than samples.
    pub fn is_request(self) -> bool {
        matches!(
            self,
            RejectReason::Invalid | RejectReason::BodyTooLarge | RejectReason::Overloaded
        )
    }

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            RejectReason::Invalid => "invalid",
            RejectReason::BodyTooLarge => "body_too_large",
            RejectReason::Overloaded => "overloaded",
            RejectReason::UnknownGate => "unknown_gate",
            RejectReason::TooManyGates => "too_many_gates",
            RejectReason::NonFinite => "non_finite",
            RejectReason::OutOfRange => "out_of_range",
            RejectReason::RateMismatch => "rate_mismatch",
            RejectReason::Duplicate => "duplicate",
            RejectReason::OutOfOrder => "out_of_order",
            RejectReason::BadLine => "bad_line",
            RejectReason::TooFarInFuture => "too_far_in_future",
            RejectReason::TooOld => "too_old",
        }
    }
}

/// Alert states exported in `gatewatch_alert_state`.
pub const ALERT_STATES: &[&str] = &["ok", "pending", "firing", "resolved", "unknown"];

/// gatewatch's own alerts, the `alertname` values of `gatewatch_alert_firing`.
pub const ALERT_NAMES: &[&str] = &[
    ALERT_NEGATIVE_DAMPING,
    ALERT_DAMPING_DECLINING,
    ALERT_DATA_STALE,
];

/// Reasons of `gatewatch_identification_failures_total`: the analysis refused its settings
/// or the window, the analysis panicked, or the job queue was full.
pub const IDENTIFICATION_FAILURES: &[&str] = &["settings", "window", "panic", "queue_full"];

/// Reasons of `gatewatch_store_write_errors_total`, in write requests (one identification, or
/// one alert transition with its state): `failed` when SQLite refused the transaction (disk
/// full, I/O error, the `storage.max_size_mb` bound; `/readyz` fails until a write succeeds), `queue_full` when the writer's queue
/// (`store::STORE_QUEUE_CAPACITY`) had no room, `file_gone` when the store's file was deleted
/// or replaced under the daemon, or the NATS store's owner lease was lost to another daemon
/// (`Store::check`; `/readyz` fails meanwhile). Either way the
/// daemon goes on from memory.
pub const STORE_WRITE_ERRORS: &[&str] = &["failed", "queue_full", "file_gone"];

/// Reasons of `gatewatch_store_pruned_rows_total`: `age` (`retention_days`), `rows`
/// (`max_history_rows`), `size` (`max_size_mb`: the oldest history pruned to stay under it).
pub const STORE_PRUNE_REASONS: &[&str] = &["age", "rows", "size"];

/// What was skipped at start: the `what` label of `gatewatch_store_restore_skipped_total` (a
/// gate's alert state, which then starts fresh; one of the windows its analysis memory is
/// rebuilt from; or a frame of the store's `-wal` file SQLite dropped because an earlier frame
/// was damaged, counted in frames, the WAL kept beside the store as `FILE-wal.damaged-SECS`).
pub const STORE_RESTORE_SKIPPED: &[&str] = &["alert_state", "history", "wal_frame"];
/// The `listener` label of `gatewatch_http_connections_cut_total`: `http` is `server.listen`,
/// `health` is `server.health_listen` (its series stay 0 while that listener is off). Apart so
/// that a probe or a scrape cut on the health port is not read as an API client's.
pub const HTTP_LISTENERS: [&str; 2] = ["http", "health"];

/// Reasons of `gatewatch_tcp_connections_rejected_total`, in connections closed at accept
/// before a byte is read: `connection_limit` when `server.max_tcp_connections` are already
/// served (an overloaded or leaking client: raise the limit or fix the client), `not_allowed`
/// when the client's address is outside `server.tcp_allowed_networks` (a refused client: widen
/// the list or move the client). Two causes with two remedies, so one label each.
pub const TCP_CONNECTION_REJECT_REASONS: &[&str] = &[TCP_CONNECTION_LIMIT, TCP_NOT_ALLOWED];
/// `reason="connection_limit"` of `gatewatch_tcp_connections_rejected_total`.
pub const TCP_CONNECTION_LIMIT: &str = "connection_limit";
/// `reason="not_allowed"` of `gatewatch_tcp_connections_rejected_total`.
pub const TCP_NOT_ALLOWED: &str = "not_allowed";

/// Outcomes of `gatewatch_notifications_total`, per target and batch: `delivered`, `failed`
/// (given up after retries, or refused) and `dropped` (queue full, or abandoned at the shutdown
/// deadline).
pub const NOTIFICATION_OUTCOMES: &[&str] = &["delivered", "failed", "dropped"];

impl Metrics {
    /// Creates and registers every metric.
    pub fn new() -> Metrics {
        let registry = Registry::new();
        let gauge = |name: &str, help: &str, labels: &[&str]| {
            let g = GaugeVec::new(Opts::new(name, help), labels).expect("valid metric");
            registry
                .register(Box::new(g.clone()))
                .expect("unique metric");
            g
        };
        let counter = |name: &str, help: &str, labels: &[&str]| {
            let c = IntCounterVec::new(Opts::new(name, help), labels).expect("valid metric");
            registry
                .register(Box::new(c.clone()))
                .expect("unique metric");
            c
        };
        let histogram = |name: &str, help: &str, labels: &[&str], buckets: &[f64]| {
            let h = HistogramVec::new(
                HistogramOpts::new(name, help).buckets(buckets.to_vec()),
                labels,
            )
            .expect("valid metric");
            registry
                .register(Box::new(h.clone()))
                .expect("unique metric");
            h
        };
        let identification_duration = Histogram::with_opts(
            HistogramOpts::new(
                "gatewatch_identification_duration_seconds",
                "Wall time of one window identification.",
            )
            .buckets(IDENTIFICATION_BUCKETS.to_vec()),
        )
        .expect("valid metric");
        registry
            .register(Box::new(identification_duration.clone()))
            .expect("unique metric");
        let jobs_replaced = IntCounter::new(
            "gatewatch_identification_jobs_replaced_total",
            "Pending identification jobs replaced by a newer window of the same gate.",
        )
        .expect("valid metric");
        registry
            .register(Box::new(jobs_replaced.clone()))
            .expect("unique metric");
        let http_connections_rejected = IntCounter::new(
            "gatewatch_http_connections_rejected_total",
            "HTTP connections closed at accept because server.max_http_connections was reached.",
        )
        .expect("valid metric");
        registry
            .register(Box::new(http_connections_rejected.clone()))
            .expect("unique metric");
        let health_connections_rejected = IntCounter::new(
            "gatewatch_health_connections_rejected_total",
            format!(
                "Connections closed at accept by the health listener (server.health_listen) because its {} connections were taken.",
                super::config::HEALTH_MAX_CONNECTIONS
            ),
        )
        .expect("valid metric");
        registry
            .register(Box::new(health_connections_rejected.clone()))
            .expect("unique metric");
        let gates_expired = IntCounter::new(
            "gatewatch_gates_expired_total",
            "Gates created by accept_unknown_gates forgotten after server.unknown_gate_expiry_seconds without data.",
        )
        .expect("valid metric");
        registry
            .register(Box::new(gates_expired.clone()))
            .expect("unique metric");
        let gates_deleted = IntCounter::new(
            "gatewatch_gates_deleted_total",
            "Gates forgotten by DELETE /api/v1/gates/{id} (an operator's clean-up, not an expiry).",
        )
        .expect("valid metric");
        registry
            .register(Box::new(gates_deleted.clone()))
            .expect("unique metric");
        let longest_running = Gauge::new(
            "gatewatch_identification_longest_running_seconds",
            "How long the identification running the longest has run, seconds (0: none runs); past server.identification_timeout_seconds its worker is stuck and /healthz fails.",
        )
        .expect("valid metric");
        registry
            .register(Box::new(longest_running.clone()))
            .expect("unique metric");
        let notifications_queued = IntCounter::new(
            "gatewatch_notifications_queued_total",
            "Batches of alert events handed to the notifier (each then goes to every target).",
        )
        .expect("valid metric");
        registry
            .register(Box::new(notifications_queued.clone()))
            .expect("unique metric");
        // process_cpu_seconds_total, process_resident_memory_bytes, process_open_fds, ...
        // read from /proc/self: the prometheus crate has the collector on Linux only.
        #[cfg(target_os = "linux")]
        registry
            .register(Box::new(
                prometheus::process_collector::ProcessCollector::for_self(),
            ))
            .expect("unique metric");
        let m = Metrics {
            damping_ratio: gauge(
                "gatewatch_damping_ratio",
                "Identified damping ratio at rest (zeta0).",
                &["gate"],
            ),
            // Two gauges rather than one with a `bound` label: summing or averaging a metric over
            // its labels must stay meaningful (Prometheus naming guide), a rule can say
            // `gatewatch_damping_ratio_upper < 0` without label matching, and Grafana fills the
            // band between two series directly.
            damping_trusted: gauge(
                "gatewatch_damping_trusted",
                "1 when the latest window's damping ratio is trusted, 0 when not.",
                &["gate"],
            ),
            damping_ratio_lower: gauge(
                "gatewatch_damping_ratio_lower",
                "Lower end of the 95 % interval of the damping ratio at rest (absent without an interval).",
                &["gate"],
            ),
            damping_ratio_upper: gauge(
                "gatewatch_damping_ratio_upper",
                "Upper end of the 95 % interval of the damping ratio at rest (absent without an interval).",
                &["gate"],
            ),
            damping_ratio_trend: gauge(
                "gatewatch_damping_ratio_trend_per_second",
                "Slope of the robust trend of the damping ratio at rest, per second of sample time.",
                &["gate"],
            ),
            damping_zero_crossing: gauge(
                "gatewatch_damping_zero_crossing_seconds",
                "Predicted sample time until the damping ratio crosses the alert threshold, at the slope's one-sided 95 % bound (absent when not declining).",
                &["gate"],
            ),
            equivalent_damping_ratio: gauge(
                "gatewatch_equivalent_damping_ratio",
                "Equivalent damping ratio at the amplitude of the window.",
                &["gate"],
            ),
            frequency_hertz: gauge(
                "gatewatch_frequency_hertz",
                "Dominant frequency of the window.",
                &["gate"],
            ),
            fit_nmae: gauge(
                "gatewatch_fit_nmae",
                "Normalised mean absolute error of the identified model.",
                &["gate"],
            ),
            model_coefficient: gauge(
                "gatewatch_model_coefficient",
                "Identified model coefficient.",
                &["gate", "coefficient"],
            ),
            alert_state: gauge(
                "gatewatch_alert_state",
                "1 for the current alert state of the gate, 0 for the others.",
                &["gate", "state"],
            ),
            alert_firing: gauge(
                "gatewatch_alert_firing",
                "1 while gatewatch's own alert (alertname) fires for the gate, 0 otherwise.",
                &["gate", "alertname"],
            ),
            amplitude: gauge(
                "gatewatch_amplitude",
                "Vibration amplitude at the end of the window: the identified model's largest |y| over its last period, in the signal's unit.",
                &["gate"],
            ),
            build_info: gauge(
                "gatewatch_build_info",
                "Always 1; the labels say which gatewatch is running.",
                &["version"],
            ),
            last_identification: gauge(
                "gatewatch_last_identification_timestamp_seconds",
                "Unix time of the gate's last successful identification.",
                &["gate"],
            ),
            samples_ingested: counter(
                "gatewatch_samples_ingested_total",
                "Samples accepted into the window.",
                &["gate"],
            ),
            window_fill_ratio: gauge(
                "gatewatch_window_fill_ratio",
                "Held fraction of a full window.",
                &["gate"],
            ),
            identification_record_seconds: gauge(
                "gatewatch_identification_record_seconds",
                "Seconds of sample time the last identification read: the window, or window_cycles of a slow gate.",
                &["gate"],
            ),
            window_gaps: counter(
                "gatewatch_window_gaps_total",
                "Gaps (> 1.5 sample periods) that restarted the window.",
                &["gate"],
            ),
            samples_rejected: counter(
                "gatewatch_samples_rejected_total",
                "Samples rejected or dropped, by reason (a raw TCP line is one sample).",
                &["reason"],
            ),
            requests_rejected: counter(
                "gatewatch_ingest_requests_rejected_total",
                "Ingestion requests refused before any sample was read, by reason.",
                &["reason"],
            ),
            identification_duration,
            jobs_replaced,
            longest_running,
            identification_failures: counter(
                "gatewatch_identification_failures_total",
                "Identification jobs that failed, by reason.",
                &["reason"],
            ),
            identifications: counter(
                "gatewatch_identifications_total",
                "Windows identified per gate, by path: tracked from the previous model or full.",
                &["gate", "path"],
            ),
            http_requests: counter(
                "gatewatch_http_requests_total",
                "HTTP requests by route template and status code.",
                &["route", "code"],
            ),
            http_duration: histogram(
                "gatewatch_http_request_duration_seconds",
                "HTTP request duration by route template.",
                &["route"],
                HTTP_BUCKETS,
            ),
            notifications_queued,
            notifications: counter(
                "gatewatch_notifications_total",
                "Alert notification batches per target kind: delivered, failed or dropped.",
                &["target", "outcome"],
            ),
            tcp_connections_rejected: counter(
                "gatewatch_tcp_connections_rejected_total",
                "Raw TCP connections closed at accept, by reason: connection_limit (server.max_tcp_connections) or not_allowed (client outside server.tcp_allowed_networks).",
                &["reason"],
            ),
            http_connections_rejected,
            health_connections_rejected,
            http_connections_cut: counter(
                "gatewatch_http_connections_cut_total",
                "HTTP connections closed while their answer was being sent, by listener (http: server.listen; health: server.health_listen) and reason: send_timeout (the client took none of it for server.request_timeout_seconds) or transfer_limit (a history answer still being sent at 10 x server.request_timeout_seconds).",
                &["listener", "reason"],
            ),
            gates_expired,
            gates_deleted,
            store_write_errors: counter(
                "gatewatch_store_write_errors_total",
                "Store write requests lost (history, alert state, outbox), by reason; the daemon goes on from memory.",
                &["reason"],
            ),
            store_pruned_rows: counter(
                "gatewatch_store_pruned_rows_total",
                "History rows deleted by the store's bounds: age (retention), rows, size.",
                &["reason"],
            ),
            store_restore_skipped: counter(
                "gatewatch_store_restore_skipped_total",
                "Stored rows that did not decode at start and were skipped: a gate's alert state (the gate starts fresh), a window of its rebuilt memory, or a WAL frame SQLite dropped after a damaged one.",
                &["what"],
            ),
            registry,
        };
        m.build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1.0);
        // every known label set is exported from the start, so rate() works from the first
        // increment
        for t in TargetType::ALL {
            for o in NOTIFICATION_OUTCOMES {
                m.notifications.with_label_values(&[t.as_str(), o]);
            }
        }
        for r in RejectReason::ALL {
            if r.is_request() {
                m.requests_rejected.with_label_values(&[r.as_str()]);
            } else {
                m.samples_rejected.with_label_values(&[r.as_str()]);
            }
        }
        for r in IDENTIFICATION_FAILURES {
            m.identification_failures.with_label_values(&[r]);
        }
        for r in TCP_CONNECTION_REJECT_REASONS {
            m.tcp_connections_rejected.with_label_values(&[r]);
        }
        for listener in HTTP_LISTENERS {
            for c in super::listen::Cut::ALL {
                m.http_connections_cut
                    .with_label_values(&[listener, c.as_str()]);
            }
        }
        for r in STORE_WRITE_ERRORS {
            m.store_write_errors.with_label_values(&[r]);
        }
        for r in STORE_PRUNE_REASONS {
            m.store_pruned_rows.with_label_values(&[r]);
        }
        for w in STORE_RESTORE_SKIPPED {
            m.store_restore_skipped.with_label_values(&[w]);
        }
        m
    }

    /// The text exposition format.
    pub fn render(&self) -> String {
        let mut out = String::new();
        if let Err(e) = TextEncoder::new().encode_utf8(&self.registry.gather(), &mut out) {
            tracing::error!(error = %e, "metrics encoding failed");
        }
        out
    }

    /// Content type of [`Metrics::render`].
    pub fn content_type(&self) -> String {
        TextEncoder::new().format_type().to_string()
    }

    /// Counts `n` rejected for `reason`: requests in `gatewatch_ingest_requests_rejected_total`
    /// when the reason refuses a whole request ([`RejectReason::is_request`]), else samples in
    /// `gatewatch_samples_rejected_total`; nothing when `n` is 0.
    pub fn reject(&self, reason: RejectReason, n: u64) {
        if n > 0 {
            let counter = if reason.is_request() {
                &self.requests_rejected
            } else {
                &self.samples_rejected
            };
            counter.with_label_values(&[reason.as_str()]).inc_by(n);
        }
    }

    /// Exports a new gate's series at their initial value: its counters at 0, and
    /// `gatewatch_alert_firing` at 1 for the alerts in `firing` (the gate's alerts the engine
    /// already holds: restored from the store at start) and 0 for the others. A gate entry made
    /// after the restart used to set all of them to 0, and the shipped rule
    /// `gatewatch_alert_firing == 1` resolved on a gate whose alert was still firing.
    pub fn init_gate(&self, gate: &str, firing: &[&str]) {
        self.samples_ingested.with_label_values(&[gate]);
        self.window_gaps.with_label_values(&[gate]);
        for name in ALERT_NAMES {
            let on = firing.contains(name);
            self.set_alert_firing(gate, name, on);
        }
    }

    /// Exports a window's interval and the gate's trend. A missing interval, trend or predicted
    /// crossing removes the series (absent, not a stale or made-up value: no evidence).
    pub fn set_trend(
        &self,
        gate: &str,
        interval: Option<(f64, f64)>,
        trend: Option<&TrendEstimate>,
    ) {
        let put = |g: &GaugeVec, v: Option<f64>| match v.filter(|v| v.is_finite()) {
            Some(v) => g.with_label_values(&[gate]).set(v),
            // Err only when the series did not exist: nothing to remove.
            None => drop(g.remove_label_values(&[gate])),
        };
        put(&self.damping_ratio_lower, interval.map(|i| i.0));
        put(&self.damping_ratio_upper, interval.map(|i| i.1));
        put(&self.damping_ratio_trend, trend.map(|t| t.slope_per_second));
        put(
            &self.damping_zero_crossing,
            trend.and_then(|t| t.crossing_seconds_confident),
        );
    }

    /// Removes `gate`'s predictions while its data are stale (`GateDataStale` fires);
    /// [`Metrics::set_trend`] sets them again with the gate's next identification.
    ///
    /// Only `gatewatch_damping_zero_crossing_seconds` goes. It counts sample seconds from the
    /// end of the gate's last window, and is read as "from now" (the shipped rule's "Predicted
    /// to cross the threshold in 2m 14s"), so frozen while the gate is silent it turns false a
    /// little more every second. The trend's slope
    /// (`gatewatch_damping_ratio_trend_per_second`) stays: it describes the windows already
    /// identified, as `gatewatch_damping_ratio` and its interval do, and does not age with the
    /// clock; `gatewatch_last_identification_timestamp_seconds` dates all three.
    pub fn clear_predictions(&self, gate: &str) {
        // Err only when the series did not exist: nothing to remove.
        drop(self.damping_zero_crossing.remove_label_values(&[gate]));
    }

    /// Removes a forgotten gate's series (label cardinality stays bounded by live gates): every
    /// series of every vector with a `gate` label whose value is `gate`. The series are found
    /// by reading each vector, not from a list of label values, because some values are not
    /// known here: `coefficient` depends on the gate's model (an expired gate used to leave its
    /// `gatewatch_model_coefficient` series behind). A series that was never created is no
    /// error. Runs once per forgotten gate, not per request.
    pub fn remove_gate(&self, gate: &str) {
        for g in [
            &self.damping_ratio,
            &self.damping_trusted,
            &self.damping_ratio_lower,
            &self.damping_ratio_upper,
            &self.damping_ratio_trend,
            &self.damping_zero_crossing,
            &self.equivalent_damping_ratio,
            &self.frequency_hertz,
            &self.fit_nmae,
            &self.model_coefficient,
            &self.alert_state,
            &self.alert_firing,
            &self.amplitude,
            &self.last_identification,
            &self.window_fill_ratio,
            &self.identification_record_seconds,
        ] {
            remove_series_of(g, gate);
        }
        for c in [
            &self.samples_ingested,
            &self.window_gaps,
            &self.identifications,
        ] {
            remove_series_of(c, gate);
        }
    }

    /// Sets `gatewatch_alert_firing{gate,alertname}`.
    pub fn set_alert_firing(&self, gate: &str, alertname: &str, firing: bool) {
        self.alert_firing
            .with_label_values(&[gate, alertname])
            .set(if firing { 1.0 } else { 0.0 });
    }

    /// Sets `gatewatch_alert_state{gate,*}`: 1 for `state`, 0 for the others.
    pub fn set_alert_state(&self, gate: &str, state: &str) {
        for s in ALERT_STATES {
            self.alert_state
                .with_label_values(&[gate, s])
                .set(if *s == state { 1.0 } else { 0.0 });
        }
    }
}

/// Removes every series of `v` whose `gate` label is `gate`, whatever its other labels.
fn remove_series_of<T: MetricVecBuilder>(v: &MetricVec<T>, gate: &str) {
    for family in v.collect() {
        for m in family.get_metric() {
            let labels: HashMap<&str, &str> = m
                .get_label()
                .iter()
                .map(|l| (l.name(), l.value()))
                .collect();
            if labels.get("gate") == Some(&gate) {
                // Err only if the series went meanwhile: nothing left to remove
                let _ = v.remove(&labels);
            }
        }
    }
}

/// The notifier's counters as last exported, to turn its totals into counter increments.
#[derive(Debug, Default)]
pub struct NotificationCounts {
    last: std::sync::Mutex<StatsSnapshot>,
}

impl NotificationCounts {
    /// Adds what the notifier counted since the last call to `gatewatch_notifications_total`.
    pub fn sync(&self, metrics: &Metrics, now: StatsSnapshot) {
        let mut last = super::sync::lock(&self.last);
        for target in TargetType::ALL {
            let (new, old) = (now.of(target), last.of(target));
            for (outcome, new, old) in [
                ("delivered", new.delivered, old.delivered),
                ("failed", new.failed, old.failed),
                ("dropped", new.dropped, old.dropped),
            ] {
                metrics
                    .notifications
                    .with_label_values(&[target.as_str(), outcome])
                    .inc_by(new.saturating_sub(old));
            }
        }
        *last = now;
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(crossing: Option<f64>) -> TrendEstimate {
        TrendEstimate {
            windows: 60,
            span_seconds: 300.0,
            level: 0.01,
            level_stderr: 0.001,
            level_slope_covariance: 0.0,
            band_slope_stderr: 3e-6,
            band_quantile: 1.96,
            slope_per_second: -2e-5,
            slope_stderr: 3e-6,
            slope_upper: -1.5e-5,
            threshold: 0.0,
            crossing_seconds: Some(500.0),
            crossing_seconds_confident: crossing,
        }
    }

    #[test]
    fn interval_and_trend_series_come_and_go_with_the_evidence() {
        let m = Metrics::new();
        m.set_trend("g1", Some((0.004, 0.016)), Some(&estimate(Some(666.0))));
        let text = m.render();
        assert!(text.contains("gatewatch_damping_ratio_lower{gate=\"g1\"} 0.004"));
        assert!(text.contains("gatewatch_damping_ratio_upper{gate=\"g1\"} 0.016"));
        let slope = text
            .lines()
            .find_map(|l| l.strip_prefix("gatewatch_damping_ratio_trend_per_second{gate=\"g1\"} "))
            .and_then(|v| v.parse::<f64>().ok());
        assert_eq!(slope, Some(-2e-5));
        assert!(text.contains("gatewatch_damping_zero_crossing_seconds{gate=\"g1\"} 666"));
        // no longer declining: the crossing disappears, the slope stays
        m.set_trend("g1", Some((0.004, 0.016)), Some(&estimate(None)));
        let text = m.render();
        assert!(!text.contains("gatewatch_damping_zero_crossing_seconds{"));
        assert!(text.contains("gatewatch_damping_ratio_trend_per_second{gate=\"g1\"}"));
        // a window without an interval and no trend: no band, no slope (no evidence)
        m.set_trend("g1", None, None);
        let text = m.render();
        assert!(!text.contains("gatewatch_damping_ratio_lower{"));
        assert!(!text.contains("gatewatch_damping_ratio_upper{"));
        assert!(!text.contains("gatewatch_damping_ratio_trend_per_second{"));
    }

    #[test]
    fn the_warning_is_an_alert_name_from_the_start() {
        let m = Metrics::new();
        m.init_gate("g1", &[]);
        let text = m.render();
        assert!(text
            .contains("gatewatch_alert_firing{alertname=\"GateDampingDeclining\",gate=\"g1\"} 0"));
    }
}
