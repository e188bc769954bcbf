//! Prometheus metrics, one typed struct registered once in its own [`Registry`].
//!
//! Label values are bounded: `gate` by `server.max_gates`, `route` by the route templates
//! (axum `MatchedPath`, never the raw URI; unmatched requests are `route="unmatched"`), `status`
//! by HTTP, `reason`, `state`, `outcome` and `coefficient` by code or model.

use prometheus::{
    Encoder, GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, Opts,
    Registry, TextEncoder,
};

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
    /// `gatewatch_last_identification_timestamp_seconds{gate}`.
    pub last_identification: GaugeVec,
    /// `gatewatch_samples_ingested_total{gate}`.
    pub samples_ingested: IntCounterVec,
    /// `gatewatch_window_fill_ratio{gate}`.
    pub window_fill_ratio: GaugeVec,
    /// `gatewatch_window_gaps_total{gate}`.
    pub window_gaps: IntCounterVec,
    /// `gatewatch_samples_rejected_total{reason}`.
    pub samples_rejected: IntCounterVec,
    /// `gatewatch_identification_duration_seconds`.
    pub identification_duration: Histogram,
    /// `gatewatch_identification_jobs_replaced_total`.
    pub jobs_replaced: IntCounter,
    /// `gatewatch_identification_failures_total{reason}`.
    pub identification_failures: IntCounterVec,
    /// `gatewatch_http_requests_total{route,status}`.
    pub http_requests: IntCounterVec,
    /// `gatewatch_http_request_duration_seconds{route}`.
    pub http_duration: HistogramVec,
    /// `gatewatch_notifications_total{outcome}`.
    pub notifications: IntCounterVec,
    /// `gatewatch_tcp_connections_rejected_total`.
    pub tcp_connections_rejected: IntCounter,
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
    /// Declared or implied rate more than 1 % off the gate's `rate_hz`.
    RateMismatch,
    /// Within half a period of the newest sample.
    Duplicate,
    /// Older than the newest sample.
    OutOfOrder,
    /// A raw TCP line that cannot be parsed or is too long.
    BadLine,
}

impl RejectReason {
    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            RejectReason::Invalid => "invalid",
            RejectReason::BodyTooLarge => "body_too_large",
            RejectReason::Overloaded => "overloaded",
            RejectReason::UnknownGate => "unknown_gate",
            RejectReason::TooManyGates => "too_many_gates",
            RejectReason::NonFinite => "non_finite",
            RejectReason::RateMismatch => "rate_mismatch",
            RejectReason::Duplicate => "duplicate",
            RejectReason::OutOfOrder => "out_of_order",
            RejectReason::BadLine => "bad_line",
        }
    }
}

/// Alert states exported in `gatewatch_alert_state`.
pub const ALERT_STATES: &[&str] = &["ok", "pending", "firing", "resolved", "unknown"];

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
        let tcp_connections_rejected = IntCounter::new(
            "gatewatch_tcp_connections_rejected_total",
            "Raw TCP connections closed because the connection limit was reached.",
        )
        .expect("valid metric");
        registry
            .register(Box::new(tcp_connections_rejected.clone()))
            .expect("unique metric");
        let m = Metrics {
            damping_ratio: gauge(
                "gatewatch_damping_ratio",
                "Identified damping ratio at rest (zeta0).",
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
            window_gaps: counter(
                "gatewatch_window_gaps_total",
                "Gaps (> 1.5 sample periods) that restarted the window.",
                &["gate"],
            ),
            samples_rejected: counter(
                "gatewatch_samples_rejected_total",
                "Samples rejected or dropped, by reason.",
                &["reason"],
            ),
            identification_duration,
            jobs_replaced,
            identification_failures: counter(
                "gatewatch_identification_failures_total",
                "Identification jobs that failed, by reason.",
                &["reason"],
            ),
            http_requests: counter(
                "gatewatch_http_requests_total",
                "HTTP requests by route template and status.",
                &["route", "status"],
            ),
            http_duration: histogram(
                "gatewatch_http_request_duration_seconds",
                "HTTP request duration by route template.",
                &["route"],
                HTTP_BUCKETS,
            ),
            notifications: counter(
                "gatewatch_notifications_total",
                "Alert notification batches: queued to the notifier, then delivered, failed or dropped per target.",
                &["outcome"],
            ),
            tcp_connections_rejected,
            registry,
        };
        // every outcome is exported from the start, so rate() works from the first increment
        for o in NOTIFICATION_OUTCOMES {
            m.notifications.with_label_values(&[o]);
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

    /// Counts `n` samples (or requests, where no sample could be read) rejected for `reason`
    /// in `gatewatch_samples_rejected_total`; nothing when `n` is 0.
    pub fn reject(&self, reason: RejectReason, n: u64) {
        if n > 0 {
            self.samples_rejected
                .with_label_values(&[reason.as_str()])
                .inc_by(n);
        }
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

/// Outcomes of `gatewatch_notifications_total`: `queued` (batches of alert events handed to the
/// notifier), then per target and batch `delivered`, `failed` (given up after retries) and
/// `dropped` (queue full, or abandoned at the shutdown deadline).
pub const NOTIFICATION_OUTCOMES: &[&str] = &["queued", "delivered", "failed", "dropped"];

/// The notifier's counters as last exported, to turn its totals into counter increments.
#[derive(Debug, Default)]
pub struct NotificationCounts {
    last: std::sync::Mutex<crate::alert::notify::StatsSnapshot>,
}

impl NotificationCounts {
    /// Adds what the notifier counted since the last call to `gatewatch_notifications_total`.
    pub fn sync(&self, metrics: &Metrics, now: crate::alert::notify::StatsSnapshot) {
        let mut last = super::sync::lock(&self.last);
        for (outcome, new, old) in [
            ("delivered", now.delivered, last.delivered),
            ("failed", now.failed, last.failed),
            ("dropped", now.dropped, last.dropped),
        ] {
            metrics
                .notifications
                .with_label_values(&[outcome])
                .inc_by(new.saturating_sub(old));
        }
        *last = now;
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}
