//! Delivery of alert events to webhooks and Alertmanager (tokio + reqwest).
//!
//! Shape of the machinery started by [`spawn_notifier`]:
//!
//! ```text
//!  NotifierHandle::notify(events)      (never blocks: try_send, drop + count when full)
//!        |  bounded mpsc, capacity = queue_capacity
//!        v
//!   dispatcher task ---- every resend_interval: engine_snapshot() -> firing alerts
//!        |  one bounded queue per target (capacity = queue_capacity), try_send, drop when full
//!        +--> webhook target task       POST {webhook payload v4}          retries + backoff
//!        +--> webhook target task       ...
//!        +--> alertmanager target task  POST {base}/api/v2/alerts [array]  retries + backoff
//! ```
//!
//! Each target has its own task and queue, so a dead or hanging receiver only delays itself.
//! Webhooks receive transitions (firing, resolved) only; Alertmanager also receives the
//! re-sends of firing alerts, because it resolves an alert by itself when it has not been
//! re-sent within its `resolve_timeout`.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Deserialize;
use serde_json::{json, Map, Value};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::engine::{rfc3339, Alert, AlertEvent};

/// Default capacity of the notifier's queues (the handle's and each target's).
pub const DEFAULT_QUEUE_CAPACITY: usize = 1024;

/// `endsAt` of a firing alert in Alertmanager's webhook payload (Go's zero `time.Time`).
pub const ZERO_TIME: &str = "0001-01-01T00:00:00Z";

/// How often a failing target may log a warning; failures in between are logged at debug level
/// and counted in the next warning.
const WARN_EVERY: Duration = Duration::from_secs(60);

/// One webhook receiver (anything that understands Alertmanager's webhook format).
#[derive(Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebhookTarget {
    /// Full URL the payload is POSTed to.
    pub url: String,
    /// Sent as `Authorization: Bearer <token>` when set.
    #[serde(default)]
    pub bearer_token: Option<String>,
    /// The `receiver` field of the payload (default "gatewatch").
    #[serde(default = "default_receiver")]
    pub receiver: String,
}

fn default_receiver() -> String {
    "gatewatch".to_string()
}

impl std::fmt::Debug for WebhookTarget {
    // The token must not end up in logs.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebhookTarget")
            .field("url", &self.url)
            .field(
                "bearer_token",
                &self.bearer_token.as_ref().map(|_| "<redacted>"),
            )
            .field("receiver", &self.receiver)
            .finish()
    }
}

/// Where and how to deliver alerts.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NotifyConfig {
    /// Webhook receivers (Alertmanager webhook format, version 4).
    pub webhooks: Vec<WebhookTarget>,
    /// Alertmanager base URLs (e.g. `http://alertmanager:9093`); alerts are POSTed to
    /// `{base}/api/v2/alerts`.
    pub alertmanager_urls: Vec<String>,
    /// Re-send firing alerts to Alertmanager this often (default 60). Alertmanager resolves an
    /// alert that is not re-sent within its `resolve_timeout`. 0 (or not finite) disables.
    pub resend_interval_seconds: f64,
    /// Timeout of one HTTP request (default 10).
    pub timeout_seconds: f64,
    /// Attempts per delivery, the first included (default 6; 0 acts as 1).
    pub max_attempts: u32,
    /// Wait before the first retry (default 500 ms), doubling at each retry...
    pub initial_backoff_ms: u64,
    /// ...up to this (default 30000 ms).
    pub max_backoff_ms: u64,
    /// Capacity of the handle's queue and of each target's queue, in batches (default 1024;
    /// 0 acts as 1).
    pub queue_capacity: usize,
    /// This daemon's URL: `externalURL` of webhook payloads and `generatorURL` of every alert.
    pub external_url: String,
}

impl Default for NotifyConfig {
    fn default() -> Self {
        NotifyConfig {
            webhooks: Vec::new(),
            alertmanager_urls: Vec::new(),
            resend_interval_seconds: 60.0,
            timeout_seconds: 10.0,
            max_attempts: 6,
            initial_backoff_ms: 500,
            max_backoff_ms: 30_000,
            queue_capacity: DEFAULT_QUEUE_CAPACITY,
            external_url: String::new(),
        }
    }
}

/// A configuration that cannot work (see [`NotifyConfig::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NotifyConfigError {
    /// A target URL does not parse or is not http(s).
    #[error("invalid {what} URL {url:?}: {reason}")]
    BadUrl {
        what: &'static str,
        url: String,
        reason: String,
    },
    /// `timeout_seconds` is not a positive finite number.
    #[error("timeout_seconds must be a positive finite number, got {0}")]
    BadTimeout(f64),
    /// `resend_interval_seconds` is negative or NaN.
    #[error("resend_interval_seconds must be >= 0, got {0}")]
    BadResendInterval(f64),
}

impl NotifyConfig {
    /// Check URLs and durations. [`spawn_notifier`] never panics on a bad config (a bad URL
    /// makes every delivery to it fail), but a daemon should reject one at load time.
    pub fn validate(&self) -> Result<(), NotifyConfigError> {
        let check = |what: &'static str, url: &str| -> Result<(), NotifyConfigError> {
            let bad = |reason: String| NotifyConfigError::BadUrl {
                what,
                url: url.to_string(),
                reason,
            };
            let parsed = reqwest::Url::parse(url).map_err(|e| bad(e.to_string()))?;
            match parsed.scheme() {
                "http" | "https" => Ok(()),
                s => Err(bad(format!("scheme {s:?} is not http or https"))),
            }
        };
        for w in &self.webhooks {
            check("webhook", &w.url)?;
        }
        for u in &self.alertmanager_urls {
            check("alertmanager", u)?;
        }
        if !(self.timeout_seconds.is_finite() && self.timeout_seconds > 0.0) {
            return Err(NotifyConfigError::BadTimeout(self.timeout_seconds));
        }
        if self.resend_interval_seconds.is_nan() || self.resend_interval_seconds < 0.0 {
            return Err(NotifyConfigError::BadResendInterval(
                self.resend_interval_seconds,
            ));
        }
        Ok(())
    }

    fn timeout(&self) -> Duration {
        Duration::try_from_secs_f64(self.timeout_seconds)
            .ok()
            .filter(|d| !d.is_zero())
            .unwrap_or(Duration::from_secs(10))
    }

    fn resend_interval(&self) -> Option<Duration> {
        Duration::try_from_secs_f64(self.resend_interval_seconds)
            .ok()
            .filter(|d| !d.is_zero())
    }

    fn capacity(&self) -> usize {
        self.queue_capacity.max(1)
    }

    /// Wait before retry number `retry` (1 = first retry): `initial * 2^(retry-1)`, capped.
    pub fn backoff(&self, retry: u32) -> Duration {
        let factor = 1u64
            .checked_shl(retry.saturating_sub(1))
            .unwrap_or(u64::MAX);
        let ms = self
            .initial_backoff_ms
            .saturating_mul(factor)
            .min(self.max_backoff_ms);
        Duration::from_millis(ms)
    }
}

/// Delivery counters, shared with the daemon (turn them into Prometheus counters).
///
/// One unit is one batch for one target: a batch of events sent to two webhooks and one
/// Alertmanager that all succeed adds 3 to `delivered`. Re-sends to Alertmanager count too.
#[derive(Debug, Default)]
pub struct NotifierStats {
    /// Batches accepted by a target (2xx).
    pub delivered: AtomicU64,
    /// Batches given up after `max_attempts` (or a non-retryable answer such as 400).
    pub failed: AtomicU64,
    /// Batches dropped: queue full, notify after shutdown, or abandoned at the shutdown
    /// deadline.
    pub dropped: AtomicU64,
}

/// A copy of the counters at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatsSnapshot {
    pub delivered: u64,
    pub failed: u64,
    pub dropped: u64,
}

impl NotifierStats {
    /// Read all counters.
    pub fn snapshot(&self) -> StatsSnapshot {
        StatsSnapshot {
            delivered: self.delivered.load(Ordering::Relaxed),
            failed: self.failed.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
        }
    }

    fn drop_one(&self, why: &str) {
        let n = self.dropped.fetch_add(1, Ordering::Relaxed) + 1;
        // Rate limit: warn on the 1st, 2nd, 4th, 8th... drop.
        if n.is_power_of_two() {
            tracing::warn!(dropped_total = n, "alert notification dropped: {why}");
        } else {
            tracing::debug!(dropped_total = n, "alert notification dropped: {why}");
        }
    }
}

/// The sending side of the notifier. Cheap to clone; all clones feed the same tasks.
#[derive(Clone)]
pub struct NotifierHandle {
    inner: Arc<HandleInner>,
}

struct HandleInner {
    tx: Mutex<Option<mpsc::Sender<Vec<AlertEvent>>>>,
    stats: Arc<NotifierStats>,
    done: watch::Receiver<bool>,
    abort: watch::Sender<bool>,
}

impl std::fmt::Debug for NotifierHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NotifierHandle")
            .field("stats", &self.inner.stats.snapshot())
            .finish()
    }
}

impl NotifierHandle {
    /// Queue a batch of events for delivery to every target. Never blocks: when the queue is
    /// full, or after [`NotifierHandle::shutdown`], the batch is dropped and counted in
    /// `dropped`. Returns whether the batch was queued. An empty batch is ignored (`true`).
    pub fn notify(&self, events: Vec<AlertEvent>) -> bool {
        if events.is_empty() {
            return true;
        }
        let guard = match self.inner.tx.lock() {
            Ok(g) => g,
            Err(poisoned) => poisoned.into_inner(),
        };
        let Some(tx) = guard.as_ref() else {
            self.inner.stats.drop_one("notifier shut down");
            return false;
        };
        match tx.try_send(events) {
            Ok(()) => true,
            Err(mpsc::error::TrySendError::Full(_)) => {
                self.inner.stats.drop_one("notifier queue full");
                false
            }
            Err(mpsc::error::TrySendError::Closed(_)) => {
                self.inner.stats.drop_one("notifier stopped");
                false
            }
        }
    }

    /// The delivery counters.
    pub fn stats(&self) -> Arc<NotifierStats> {
        self.inner.stats.clone()
    }

    /// Stop accepting events, deliver what is queued (with retries) until `deadline` has
    /// passed, then abandon the rest (counted as dropped) and return. Returns `true` if
    /// everything queued was handled (delivered or failed) before the deadline. Idempotent.
    pub async fn shutdown(&self, deadline: Duration) -> bool {
        {
            let mut guard = match self.inner.tx.lock() {
                Ok(g) => g,
                Err(poisoned) => poisoned.into_inner(),
            };
            guard.take();
        }
        let mut done = self.inner.done.clone();
        // A dispatcher that ended without saying so (panicked) also counts as finished.
        let finished = tokio::time::timeout(deadline, done.wait_for(|d| *d))
            .await
            .is_ok();
        if !finished {
            tracing::warn!(
                ?deadline,
                "alert notifier: shutdown deadline reached, abandoning undelivered notifications"
            );
            self.inner.abort.send_replace(true);
        }
        finished
    }
}

/// Start the notifier: a dispatcher task and one task per target. Must be called inside a
/// tokio runtime (it spawns tasks).
///
/// `engine_snapshot` returns the alerts currently firing (normally
/// `engine.lock().firing()`); it is called every `resend_interval_seconds` when Alertmanager
/// targets are configured, from the dispatcher task, so it must be quick and must not block on
/// anything that waits for the notifier.
///
/// # Panics
/// When called outside a tokio runtime (like `tokio::spawn`).
///
/// Returns the handle and the dispatcher's join handle, which completes after
/// [`NotifierHandle::shutdown`] (or once every handle is dropped) when all target tasks have
/// ended.
pub fn spawn_notifier<F>(
    config: NotifyConfig,
    engine_snapshot: F,
) -> (NotifierHandle, JoinHandle<()>)
where
    F: Fn() -> Vec<Alert> + Send + Sync + 'static,
{
    // reqwest is built with rustls but no default crypto provider: install ring once. An error
    // only means a provider is installed already.
    let _ = rustls::crypto::ring::default_provider().install_default();
    let client = reqwest::Client::builder()
        .timeout(config.timeout())
        .user_agent(concat!("gatewatch/", env!("CARGO_PKG_VERSION")))
        .build()
        .map_err(|e| {
            tracing::error!(
                "alert notifier: cannot build the HTTP client: {e}; every delivery will fail"
            );
        })
        .ok();

    let stats = Arc::new(NotifierStats::default());
    let (tx, rx) = mpsc::channel(config.capacity());
    let (done_tx, done_rx) = watch::channel(false);
    let (abort_tx, abort_rx) = watch::channel(false);
    let config = Arc::new(config);

    let mut targets = Vec::new();
    for w in &config.webhooks {
        targets.push(Target {
            url: w.url.clone(),
            kind: TargetKind::Webhook {
                receiver: w.receiver.clone(),
                bearer_token: w.bearer_token.clone(),
            },
        });
    }
    for base in &config.alertmanager_urls {
        targets.push(Target {
            url: format!("{}/api/v2/alerts", base.trim_end_matches('/')),
            kind: TargetKind::Alertmanager,
        });
    }

    let mut queues = Vec::new();
    let mut tasks = Vec::new();
    for target in targets {
        let (qtx, qrx) = mpsc::channel(config.capacity());
        let is_am = matches!(target.kind, TargetKind::Alertmanager);
        queues.push((qtx, is_am, target.url.clone()));
        tasks.push(tokio::spawn(run_target(
            target,
            qrx,
            client.clone(),
            config.clone(),
            stats.clone(),
            abort_rx.clone(),
        )));
    }

    let dispatcher = tokio::spawn(run_dispatcher(
        rx,
        queues,
        tasks,
        config.clone(),
        engine_snapshot,
        stats.clone(),
        abort_rx,
        done_tx,
    ));
    let handle = NotifierHandle {
        inner: Arc::new(HandleInner {
            tx: Mutex::new(Some(tx)),
            stats,
            done: done_rx,
            abort: abort_tx,
        }),
    };
    (handle, dispatcher)
}

#[derive(Debug, Clone)]
enum Job {
    Events(Arc<Vec<AlertEvent>>),
    Resend(Arc<Vec<Alert>>),
}

#[derive(Debug)]
enum TargetKind {
    Webhook {
        receiver: String,
        bearer_token: Option<String>,
    },
    Alertmanager,
}

#[derive(Debug)]
struct Target {
    url: String,
    kind: TargetKind,
}

/// Resolves when an abort is requested; pends forever if the abort sender is gone.
async fn aborted(rx: &mut watch::Receiver<bool>) {
    loop {
        if *rx.borrow_and_update() {
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

#[allow(clippy::too_many_arguments)]
async fn run_dispatcher<F>(
    mut rx: mpsc::Receiver<Vec<AlertEvent>>,
    queues: Vec<(mpsc::Sender<Job>, bool, String)>,
    tasks: Vec<JoinHandle<()>>,
    config: Arc<NotifyConfig>,
    snapshot: F,
    stats: Arc<NotifierStats>,
    mut abort: watch::Receiver<bool>,
    done: watch::Sender<bool>,
) where
    F: Fn() -> Vec<Alert> + Send + Sync + 'static,
{
    let has_am = queues.iter().any(|(_, is_am, _)| *is_am);
    let resend = config.resend_interval().filter(|_| has_am);
    let period = resend.unwrap_or(Duration::from_secs(3600));
    let mut ticker = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);

    let fan_out = |job: Job, am_only: bool| {
        for (q, is_am, url) in &queues {
            if am_only && !is_am {
                continue;
            }
            if q.try_send(job.clone()).is_err() {
                stats.drop_one(&format!("queue of {url} full"));
            }
        }
    };

    loop {
        tokio::select! {
            biased;
            _ = aborted(&mut abort) => {
                // Count what is still queued here as dropped.
                rx.close();
                while rx.try_recv().is_ok() {
                    stats.drop_one("shutdown deadline");
                }
                break;
            }
            msg = rx.recv() => match msg {
                Some(events) => fan_out(Job::Events(Arc::new(events)), false),
                None => break,
            },
            _ = ticker.tick(), if resend.is_some() => {
                let alerts = snapshot();
                if !alerts.is_empty() {
                    fan_out(Job::Resend(Arc::new(alerts)), true);
                }
            }
        }
    }
    drop(queues); // closes the target queues: target tasks drain and end
    for t in tasks {
        if let Err(e) = t.await {
            tracing::error!("alert notifier: a target task ended abnormally: {e}");
        }
    }
    done.send_replace(true);
}

/// Per-target warning rate limiter.
struct WarnLimiter {
    last: Option<Instant>,
    suppressed: u64,
}

impl WarnLimiter {
    fn failure(&mut self, url: &str, msg: &str) {
        let now = Instant::now();
        if self
            .last
            .is_none_or(|t| now.duration_since(t) >= WARN_EVERY)
        {
            tracing::warn!(
                target_url = url,
                suppressed_since_last_warning = self.suppressed,
                "alert delivery failed: {msg}"
            );
            self.last = Some(now);
            self.suppressed = 0;
        } else {
            self.suppressed += 1;
            tracing::debug!(target_url = url, "alert delivery failed: {msg}");
        }
    }
}

async fn run_target(
    target: Target,
    mut rx: mpsc::Receiver<Job>,
    client: Option<reqwest::Client>,
    config: Arc<NotifyConfig>,
    stats: Arc<NotifierStats>,
    mut abort: watch::Receiver<bool>,
) {
    let mut limiter = WarnLimiter {
        last: None,
        suppressed: 0,
    };
    loop {
        let job = tokio::select! {
            biased;
            _ = aborted(&mut abort) => break,
            job = rx.recv() => match job {
                Some(job) => job,
                None => return,
            },
        };
        let body = match (&target.kind, &job) {
            (TargetKind::Webhook { receiver, .. }, Job::Events(events)) => {
                webhook_payload(receiver, &config.external_url, events)
            }
            // Webhooks get transitions only.
            (TargetKind::Webhook { .. }, Job::Resend(_)) => continue,
            (TargetKind::Alertmanager, Job::Events(events)) => {
                let alerts: Vec<Alert> = events.iter().map(|e| e.alert().clone()).collect();
                alertmanager_payload(&alerts, &config.external_url)
            }
            (TargetKind::Alertmanager, Job::Resend(alerts)) => {
                alertmanager_payload(alerts, &config.external_url)
            }
        };
        let result = tokio::select! {
            biased;
            _ = aborted(&mut abort) => {
                stats.drop_one("shutdown deadline");
                break;
            }
            r = deliver(&target, client.as_ref(), &config, &body) => r,
        };
        match result {
            Ok(()) => {
                stats.delivered.fetch_add(1, Ordering::Relaxed);
            }
            Err(msg) => {
                stats.failed.fetch_add(1, Ordering::Relaxed);
                limiter.failure(&target.url, &msg);
            }
        }
    }
    // Aborted: whatever is still queued is abandoned.
    rx.close();
    while rx.try_recv().is_ok() {
        stats.drop_one("shutdown deadline");
    }
}

/// One delivery with retries. `Err` carries a description of the last failure.
async fn deliver(
    target: &Target,
    client: Option<&reqwest::Client>,
    config: &NotifyConfig,
    body: &Value,
) -> Result<(), String> {
    let Some(client) = client else {
        return Err("no HTTP client".to_string());
    };
    let attempts = config.max_attempts.max(1);
    let mut attempt = 1;
    loop {
        let mut req = client.post(&target.url).json(body);
        if let TargetKind::Webhook {
            bearer_token: Some(token),
            ..
        } = &target.kind
        {
            req = req.bearer_auth(token);
        }
        let (retryable, msg) = match req.send().await {
            Ok(resp) if resp.status().is_success() => return Ok(()),
            Ok(resp) => {
                let status = resp.status();
                let retryable = status.is_server_error()
                    || status == reqwest::StatusCode::TOO_MANY_REQUESTS
                    || status == reqwest::StatusCode::REQUEST_TIMEOUT;
                (retryable, format!("HTTP {status}"))
            }
            // A URL that cannot be requested will not get better by retrying.
            Err(e) if e.is_builder() => (false, format!("invalid request: {e}")),
            Err(e) => (true, format!("request error: {e}")),
        };
        if !retryable {
            return Err(format!("{msg} (not retried)"));
        }
        if attempt >= attempts {
            return Err(format!("{msg} after {attempt} attempts"));
        }
        let wait = config.backoff(attempt);
        tracing::debug!(target_url = %target.url, attempt, ?wait, "alert delivery: {msg}, retrying");
        tokio::time::sleep(wait).await;
        attempt += 1;
    }
}

fn label_set_string(labels: &BTreeMap<String, String>) -> String {
    let parts: Vec<String> = labels
        .iter()
        .map(|(k, v)| format!("{k}={}", Value::String(v.clone())))
        .collect();
    format!("{{{}}}", parts.join(", "))
}

/// Key/value pairs present with the same value in every map (empty for no maps).
fn common<'a>(
    mut maps: impl Iterator<Item = &'a BTreeMap<String, String>>,
) -> BTreeMap<String, String> {
    let Some(first) = maps.next() else {
        return BTreeMap::new();
    };
    let mut out = first.clone();
    for m in maps {
        out.retain(|k, v| m.get(k) == Some(v));
    }
    out
}

fn to_object(m: &BTreeMap<String, String>) -> Value {
    Value::Object(
        m.iter()
            .map(|(k, v)| (k.clone(), Value::String(v.clone())))
            .collect::<Map<String, Value>>(),
    )
}

/// The body of a webhook notification, in Alertmanager's webhook format version "4", so that
/// receivers written for Alertmanager work unchanged.
///
/// - `status` is "firing" if any event is a firing one, else "resolved".
/// - `groupLabels` are the common `alertname` and `gate` labels (gatewatch groups by both),
///   `groupKey` is `{}:` followed by them as a label set, as Alertmanager prints it.
/// - `commonLabels` / `commonAnnotations`: pairs shared by all alerts of the batch.
/// - each alert: `status`, `labels`, `annotations`, `startsAt`, `endsAt` (RFC 3339;
///   "0001-01-01T00:00:00Z" while firing, as Alertmanager does), `generatorURL`
///   (= `external_url`), `fingerprint`.
pub fn webhook_payload(receiver: &str, external_url: &str, events: &[AlertEvent]) -> Value {
    let status = if events.iter().any(AlertEvent::is_firing) {
        "firing"
    } else {
        "resolved"
    };
    let common_labels = common(events.iter().map(|e| &e.alert().labels));
    let common_annotations = common(events.iter().map(|e| &e.alert().annotations));
    let group_labels: BTreeMap<String, String> = common_labels
        .iter()
        .filter(|(k, _)| k.as_str() == "alertname" || k.as_str() == "gate")
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let alerts: Vec<Value> = events
        .iter()
        .map(|e| {
            let a = e.alert();
            let ends_at = match (e.is_firing(), a.ends_at) {
                (false, Some(t)) => rfc3339(t),
                _ => ZERO_TIME.to_string(),
            };
            json!({
                "status": e.status(),
                "labels": to_object(&a.labels),
                "annotations": to_object(&a.annotations),
                "startsAt": rfc3339(a.starts_at),
                "endsAt": ends_at,
                "generatorURL": external_url,
                "fingerprint": a.fingerprint,
            })
        })
        .collect();
    json!({
        "version": "4",
        "groupKey": format!("{{}}:{}", label_set_string(&group_labels)),
        "truncatedAlerts": 0,
        "status": status,
        "receiver": receiver,
        "groupLabels": to_object(&group_labels),
        "commonLabels": to_object(&common_labels),
        "commonAnnotations": to_object(&common_annotations),
        "externalURL": external_url,
        "alerts": alerts,
    })
}

/// The body of Alertmanager's `POST /api/v2/alerts`: an array of
/// `{labels, annotations, startsAt, endsAt?, generatorURL}`. `endsAt` is present only for
/// resolved alerts; for firing ones Alertmanager sets it to now + `resolve_timeout`, hence the
/// periodic re-sends.
pub fn alertmanager_payload(alerts: &[Alert], generator_url: &str) -> Value {
    Value::Array(
        alerts
            .iter()
            .map(|a| {
                let mut o = Map::new();
                o.insert("labels".into(), to_object(&a.labels));
                o.insert("annotations".into(), to_object(&a.annotations));
                o.insert("startsAt".into(), Value::String(rfc3339(a.starts_at)));
                if let Some(t) = a.ends_at {
                    o.insert("endsAt".into(), Value::String(rfc3339(t)));
                }
                o.insert(
                    "generatorURL".into(),
                    Value::String(generator_url.to_string()),
                );
                Value::Object(o)
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alert::{AlertEngine, AlertRules, Observation};
    use std::time::{SystemTime, UNIX_EPOCH};

    fn t(secs: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(1_700_000_000 + secs)
    }

    fn obs(z: f64) -> Observation<'static> {
        Observation {
            zeta0: Some(z),
            trusted: true,
            frequency_hz: Some(10.4),
            limit_cycle_amplitude: None,
            time_to_limit: None,
            equation: "ydd + c1*yd + c2*y = 0",
        }
    }

    /// Firing event for g1 (first negative window at t(0), fired at t(5)) and its resolution at
    /// t(20).
    fn events() -> (AlertEvent, AlertEvent) {
        let mut e = AlertEngine::new(AlertRules::default());
        e.observe("g1", &obs(-0.012), t(0));
        let fired = e.observe("g1", &obs(-0.012), t(5)).remove(0);
        e.observe("g1", &obs(0.02), t(10));
        let resolved = e.observe("g1", &obs(0.02), t(20)).remove(0);
        (fired, resolved)
    }

    #[test]
    fn webhook_payload_firing_v4() {
        let (fired, _) = events();
        let fp = fired.alert().fingerprint.clone();
        let v = webhook_payload("team", "http://gw:9184", &[fired]);
        let expected = json!({
            "version": "4",
            "groupKey": "{}:{alertname=\"GateNegativeDamping\", gate=\"g1\"}",
            "truncatedAlerts": 0,
            "status": "firing",
            "receiver": "team",
            "groupLabels": {"alertname": "GateNegativeDamping", "gate": "g1"},
            "commonLabels": {"alertname": "GateNegativeDamping", "gate": "g1", "severity": "critical"},
            "commonAnnotations": v["alerts"][0]["annotations"].clone(),
            "externalURL": "http://gw:9184",
            "alerts": [{
                "status": "firing",
                "labels": {"alertname": "GateNegativeDamping", "gate": "g1", "severity": "critical"},
                "annotations": v["alerts"][0]["annotations"].clone(),
                "startsAt": "2023-11-14T22:13:20.000Z",
                "endsAt": "0001-01-01T00:00:00Z",
                "generatorURL": "http://gw:9184",
                "fingerprint": fp,
            }],
        });
        assert_eq!(v, expected);
        let ann = &v["alerts"][0]["annotations"];
        assert_eq!(
            ann["summary"],
            "gate g1: damping ratio -1.2 % (self-excited vibration at 10.4 Hz)"
        );
        assert_eq!(ann["damping_ratio"], "-0.012");
        assert_eq!(ann["equation"], "ydd + c1*yd + c2*y = 0");
    }

    #[test]
    fn webhook_payload_resolved_has_ends_at() {
        let (_, resolved) = events();
        let v = webhook_payload("r", "", &[resolved]);
        assert_eq!(v["status"], "resolved");
        assert_eq!(v["alerts"][0]["status"], "resolved");
        assert_eq!(v["alerts"][0]["endsAt"], "2023-11-14T22:13:40.000Z");
        assert_eq!(v["alerts"][0]["startsAt"], "2023-11-14T22:13:20.000Z");
    }

    #[test]
    fn webhook_payload_mixed_batch() {
        let mut e = AlertEngine::new(AlertRules::default());
        e.data_seen("g1", t(0));
        e.data_seen("g2", t(0));
        let ev = e.check_stale(t(100));
        let mut batch = ev.clone();
        batch.push(e.data_seen("g1", t(101)).remove(0));
        let v = webhook_payload("r", "", &batch);
        assert_eq!(v["status"], "firing", "any firing -> firing");
        assert_eq!(v["groupLabels"], json!({"alertname": "GateDataStale"}));
        assert_eq!(v["groupKey"], "{}:{alertname=\"GateDataStale\"}");
        assert_eq!(
            v["commonLabels"],
            json!({"alertname": "GateDataStale", "severity": "critical"})
        );
        assert_eq!(v["alerts"].as_array().map(Vec::len), Some(3));
        assert_eq!(v["alerts"][2]["status"], "resolved");
        // All resolved -> resolved; empty batch is resolved with no alerts.
        let all_resolved = webhook_payload("r", "", &[batch[2].clone()]);
        assert_eq!(all_resolved["status"], "resolved");
        let empty = webhook_payload("r", "", &[]);
        assert_eq!(empty["status"], "resolved");
        assert_eq!(empty["groupKey"], "{}:{}");
        assert_eq!(empty["alerts"], json!([]));
    }

    #[test]
    fn alertmanager_payload_format() {
        let (fired, resolved) = events();
        let v = alertmanager_payload(
            &[fired.alert().clone(), resolved.alert().clone()],
            "http://gw:9184",
        );
        let arr = v.as_array().expect("array");
        assert_eq!(arr.len(), 2);
        let keys = |o: &Value| {
            let mut k: Vec<String> = o
                .as_object()
                .map(|m| m.keys().cloned().collect())
                .unwrap_or_default();
            k.sort();
            k
        };
        assert_eq!(
            keys(&arr[0]),
            vec!["annotations", "generatorURL", "labels", "startsAt"]
        );
        assert_eq!(
            keys(&arr[1]),
            vec![
                "annotations",
                "endsAt",
                "generatorURL",
                "labels",
                "startsAt"
            ]
        );
        assert_eq!(arr[0]["labels"]["gate"], "g1");
        assert_eq!(arr[0]["startsAt"], "2023-11-14T22:13:20.000Z");
        assert_eq!(arr[1]["endsAt"], "2023-11-14T22:13:40.000Z");
        assert_eq!(arr[0]["generatorURL"], "http://gw:9184");
        assert_eq!(alertmanager_payload(&[], ""), json!([]));
    }

    #[test]
    fn config_defaults_and_validation() {
        let c: NotifyConfig = serde_json::from_str("{}").expect("defaults");
        assert_eq!(c, NotifyConfig::default());
        assert_eq!(c.resend_interval_seconds, 60.0);
        assert_eq!(c.timeout_seconds, 10.0);
        assert_eq!(c.max_attempts, 6);
        assert_eq!(c.initial_backoff_ms, 500);
        assert_eq!(c.max_backoff_ms, 30_000);
        assert_eq!(c.queue_capacity, DEFAULT_QUEUE_CAPACITY);
        assert!(c.validate().is_ok());
        assert!(serde_json::from_str::<NotifyConfig>(r#"{"webhook": []}"#).is_err());
        assert!(serde_json::from_str::<NotifyConfig>(
            r#"{"webhooks": [{"url": "http://x", "token": "t"}]}"#
        )
        .is_err());
        let c: NotifyConfig = serde_json::from_str(
            r#"{"webhooks": [{"url": "https://hooks.example/a", "bearer_token": "s3cret"}],
                "alertmanager_urls": ["http://am:9093"]}"#,
        )
        .expect("parse");
        assert_eq!(c.webhooks[0].receiver, "gatewatch");
        assert!(c.validate().is_ok());
        assert!(
            !format!("{c:?}").contains("s3cret"),
            "token redacted in Debug"
        );
        let bad = NotifyConfig {
            alertmanager_urls: vec!["ftp://am".into()],
            ..NotifyConfig::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(NotifyConfigError::BadUrl { .. })
        ));
        let bad = NotifyConfig {
            webhooks: vec![WebhookTarget {
                url: "not a url".into(),
                bearer_token: None,
                receiver: "r".into(),
            }],
            ..NotifyConfig::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(NotifyConfigError::BadUrl { .. })
        ));
        let bad = NotifyConfig {
            timeout_seconds: 0.0,
            ..NotifyConfig::default()
        };
        assert_eq!(bad.validate(), Err(NotifyConfigError::BadTimeout(0.0)));
        let bad = NotifyConfig {
            resend_interval_seconds: f64::NAN,
            ..NotifyConfig::default()
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn backoff_doubles_and_caps() {
        let c = NotifyConfig::default();
        let ms: Vec<u128> = (1..=8).map(|r| c.backoff(r).as_millis()).collect();
        assert_eq!(ms, vec![500, 1000, 2000, 4000, 8000, 16000, 30000, 30000]);
        assert_eq!(c.backoff(0).as_millis(), 500);
        assert_eq!(c.backoff(200).as_millis(), 30000, "no overflow");
        let c = NotifyConfig {
            initial_backoff_ms: u64::MAX,
            max_backoff_ms: u64::MAX,
            ..NotifyConfig::default()
        };
        assert_eq!(c.backoff(64).as_millis(), u128::from(u64::MAX));
    }

    #[test]
    fn degenerate_durations() {
        let c = NotifyConfig {
            timeout_seconds: f64::NAN,
            resend_interval_seconds: 0.0,
            queue_capacity: 0,
            ..NotifyConfig::default()
        };
        assert_eq!(c.timeout(), Duration::from_secs(10));
        assert_eq!(c.resend_interval(), None);
        assert_eq!(c.capacity(), 1);
        let c = NotifyConfig {
            resend_interval_seconds: -3.0,
            ..NotifyConfig::default()
        };
        assert_eq!(c.resend_interval(), None);
    }

    /// Two alerts with short annotations: one firing, one resolved.
    fn pin_events() -> Vec<AlertEvent> {
        let alert = |gate: &str, ends: Option<u64>| {
            let labels: BTreeMap<String, String> = [
                ("alertname", "GateDataStale"),
                ("gate", gate),
                ("severity", "critical"),
            ]
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
            let annotations: BTreeMap<String, String> =
                [("summary", "s \"q\""), ("last_seen", "x")]
                    .iter()
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect();
            Alert {
                name: "GateDataStale".into(),
                fingerprint: crate::alert::fingerprint(&labels),
                labels,
                annotations,
                starts_at: t(0),
                ends_at: ends.map(t),
            }
        };
        vec![
            AlertEvent::Firing(alert("g1", None)),
            AlertEvent::Resolved(alert("g2", Some(70))),
        ]
    }

    const PINNED_WEBHOOK: &str = concat!(
        r#"{"alerts":[{"annotations":{"last_seen":"x","summary":"s \"q\""},"#,
        r#""endsAt":"0001-01-01T00:00:00Z","fingerprint":"FP1","generatorURL":"http://gw:9184","#,
        r#""labels":{"alertname":"GateDataStale","gate":"g1","severity":"critical"},"#,
        r#""startsAt":"2023-11-14T22:13:20.000Z","status":"firing"},"#,
        r#"{"annotations":{"last_seen":"x","summary":"s \"q\""},"#,
        r#""endsAt":"2023-11-14T22:14:30.000Z","fingerprint":"FP2","generatorURL":"http://gw:9184","#,
        r#""labels":{"alertname":"GateDataStale","gate":"g2","severity":"critical"},"#,
        r#""startsAt":"2023-11-14T22:13:20.000Z","status":"resolved"}],"#,
        r#""commonAnnotations":{"last_seen":"x","summary":"s \"q\""},"#,
        r#""commonLabels":{"alertname":"GateDataStale","severity":"critical"},"#,
        r#""externalURL":"http://gw:9184","groupKey":"{}:{alertname=\"GateDataStale\"}","#,
        r#""groupLabels":{"alertname":"GateDataStale"},"receiver":"team","status":"firing","#,
        r#""truncatedAlerts":0,"version":"4"}"#,
    );

    const PINNED_ALERTMANAGER: &str = concat!(
        r#"[{"annotations":{"last_seen":"x","summary":"s \"q\""},"generatorURL":"http://gw:9184","#,
        r#""labels":{"alertname":"GateDataStale","gate":"g1","severity":"critical"},"#,
        r#""startsAt":"2023-11-14T22:13:20.000Z"},"#,
        r#"{"annotations":{"last_seen":"x","summary":"s \"q\""},"endsAt":"2023-11-14T22:14:30.000Z","#,
        r#""generatorURL":"http://gw:9184","#,
        r#""labels":{"alertname":"GateDataStale","gate":"g2","severity":"critical"},"#,
        r#""startsAt":"2023-11-14T22:13:20.000Z"}]"#,
    );

    /// The exact bytes POSTed (keys in byte order, compact), so a refactoring of the payload
    /// code cannot change what receivers get.
    #[test]
    fn wire_bytes_are_pinned() {
        let events = pin_events();
        let fp = |i: usize| events[i].alert().fingerprint.clone();
        let expected_webhook = PINNED_WEBHOOK.replace("FP1", &fp(0)).replace("FP2", &fp(1));
        let webhook = serde_json::to_string(&webhook_payload("team", "http://gw:9184", &events))
            .expect("serialise");
        assert_eq!(webhook, expected_webhook);
        let alerts: Vec<Alert> = events.iter().map(|e| e.alert().clone()).collect();
        let am = serde_json::to_string(&alertmanager_payload(&alerts, "http://gw:9184"))
            .expect("serialise");
        assert_eq!(am, PINNED_ALERTMANAGER);
    }
}
