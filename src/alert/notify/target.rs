//! One target task: takes jobs from its own bounded queue, formats them for its receiver and
//! POSTs them with retries: exponential backoff with jitter, or the receiver's `Retry-After` on
//! 429 and 503, never longer than `max_backoff_ms`. A dead or hanging receiver only delays its
//! own queue.

use std::collections::VecDeque;
use std::fmt;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use backon::Retryable;
use serde::Serialize;
use tokio::sync::{mpsc, watch};

use super::dispatch::{aborted, Job};
use super::outbox::{drain, Ack, Drain};
use super::payload::{PostableAlert, WebhookPayload};
use super::stats::{DropReason, NotifierStats, TargetType};
use super::NotifyConfig;
use crate::alert::engine::{Alert, AlertEvent};

/// How often a failing target may log a warning; failures in between are logged at debug level
/// and counted in the next warning.
const WARN_EVERY: Duration = Duration::from_secs(60);

/// Where one target task posts, and in which format.
#[derive(Debug)]
pub(super) struct Target {
    pub url: String,
    pub kind: TargetKind,
}

#[derive(Debug)]
pub(super) enum TargetKind {
    /// Alertmanager's webhook format; transitions only.
    Webhook {
        receiver: String,
        bearer_token: Option<String>,
    },
    /// `POST /api/v2/alerts`; transitions and re-sends.
    Alertmanager,
}

impl Target {
    /// Whether the target is an Alertmanager (takes states and re-sends).
    pub(super) fn is_alertmanager(&self) -> bool {
        matches!(self.kind, TargetKind::Alertmanager)
    }
}

/// Everything one target task owns.
pub(super) struct TargetTask {
    pub target: Target,
    pub jobs: mpsc::Receiver<Job>,
    /// Shared by all targets; `None` if it could not be built (every delivery fails).
    pub client: Option<reqwest::Client>,
    pub config: Arc<NotifyConfig>,
    pub stats: Arc<NotifierStats>,
    /// Set at the shutdown deadline.
    pub abort: watch::Receiver<bool>,
    /// Told the ids of settled outbox entries.
    pub ack: Ack,
}

impl TargetTask {
    /// Delivers jobs until its queue is closed and empty, or until the shutdown deadline (then
    /// the job in flight and the queued ones are counted as dropped).
    pub async fn run(self) {
        let TargetTask {
            target,
            mut jobs,
            client,
            config,
            stats,
            mut abort,
            ack,
        } = self;
        let kind = match target.kind {
            TargetKind::Webhook { .. } => TargetType::Webhook,
            TargetKind::Alertmanager => TargetType::Alertmanager,
        };
        let mut limiter = WarnLimiter::new();
        // jobs that arrived while the outbox was drained
        let mut deferred = VecDeque::new();
        loop {
            let job = match deferred.pop_front() {
                Some(job) => job,
                None => tokio::select! {
                    biased;
                    _ = aborted(&mut abort) => break,
                    job = jobs.recv() => match job {
                        Some(job) => job,
                        None => return,
                    },
                },
            };
            if let Job::Outbox(entries) = job {
                let d = Drain {
                    target: &target,
                    client: client.as_ref(),
                    config: &config,
                    stats: &stats,
                    kind,
                    ack: &ack,
                    limiter: &mut limiter,
                };
                if !drain(d, entries, &mut jobs, &mut abort, &mut deferred).await {
                    break;
                }
                continue;
            }
            let Some(body) = body(&target.kind, &job, &config.external_url) else {
                continue; // Webhooks get transitions only.
            };
            let result = tokio::select! {
                biased;
                _ = aborted(&mut abort) => {
                    stats.drop_one(Some(kind), DropReason::ShutdownDeadline);
                    break;
                }
                r = deliver(&target, client.as_ref(), &config, body) => r,
            };
            match result {
                Ok(()) => stats.delivered_one(kind),
                Err(e) => {
                    stats.failed_one(kind);
                    limiter.failure(&target.url, &e);
                }
            }
        }
        // Aborted: whatever is still queued is abandoned (outbox entries with a row id stay in
        // the store for the next start).
        jobs.close();
        while let Ok(job) = jobs.try_recv() {
            let lost = match &job {
                Job::Outbox(entries) => entries.iter().filter(|e| e.id.is_none()).count(),
                _ => 1,
            };
            for _ in 0..lost {
                stats.drop_one(Some(kind), DropReason::ShutdownDeadline);
            }
        }
    }
}

/// The serialised body of `job` for a target of `kind`, or `None` if such a target does not
/// take this job. Serialised once per job, not per attempt.
pub(super) fn body(
    kind: &TargetKind,
    job: &Job,
    external_url: &str,
) -> Option<Result<Vec<u8>, String>> {
    match (kind, job) {
        (TargetKind::Webhook { receiver, .. }, Job::Events(events)) => Some(to_json(
            &WebhookPayload::new(receiver, external_url, events),
        )),
        (TargetKind::Webhook { .. }, Job::Resend(_)) => None,
        (TargetKind::Alertmanager, Job::Events(events)) => Some(postable_alerts(
            events.iter().map(AlertEvent::alert),
            external_url,
        )),
        (TargetKind::Alertmanager, Job::Resend(alerts)) => {
            Some(postable_alerts(alerts.iter(), external_url))
        }
        // delivered by `outbox::drain`, never formatted as a whole
        (_, Job::Outbox(_)) => None,
    }
}

/// The body of Alertmanager's `POST /api/v2/alerts`.
fn postable_alerts<'a>(
    alerts: impl Iterator<Item = &'a Alert>,
    generator_url: &str,
) -> Result<Vec<u8>, String> {
    let body: Vec<PostableAlert> = alerts
        .map(|a| PostableAlert::new(a, generator_url))
        .collect();
    to_json(&body)
}

fn to_json(body: &impl Serialize) -> Result<Vec<u8>, String> {
    serde_json::to_vec(body).map_err(|e| format!("cannot serialise the payload: {e}"))
}

/// Why one attempt failed.
#[derive(Debug)]
pub(super) enum AttemptError {
    /// The HTTP client could not be built at start (not retried).
    NoClient,
    /// The receiver answered with a status other than 2xx; with the wait its `Retry-After`
    /// asked for, when it answered 429 or 503 with a valid one (not yet capped).
    Status(reqwest::StatusCode, Option<Duration>),
    /// The request could not be built (e.g. an invalid URL).
    InvalidRequest(reqwest::Error),
    /// Connecting, sending or waiting for the answer failed (timeouts included).
    Transport(reqwest::Error),
}

impl AttemptError {
    /// Server errors, 408, 429 and transport errors may pass; the rest will not get better.
    pub(super) fn retryable(&self) -> bool {
        match self {
            AttemptError::Status(s, _) => {
                s.is_server_error()
                    || *s == reqwest::StatusCode::TOO_MANY_REQUESTS
                    || *s == reqwest::StatusCode::REQUEST_TIMEOUT
            }
            AttemptError::InvalidRequest(_) | AttemptError::NoClient => false,
            AttemptError::Transport(_) => true,
        }
    }
}

impl AttemptError {
    /// The wait the receiver asked for with `Retry-After`, if any.
    fn retry_after(&self) -> Option<Duration> {
        match self {
            AttemptError::Status(_, wait) => *wait,
            _ => None,
        }
    }
}

/// The wait a `Retry-After` header asks for: delta-seconds, or an HTTP date (a date in the past
/// means now). Only 429 (Too Many Requests) and 503 (Service Unavailable) define it; on other
/// statuses, and when it does not parse, it is ignored.
fn retry_after(
    status: reqwest::StatusCode,
    headers: &reqwest::header::HeaderMap,
    now: SystemTime,
) -> Option<Duration> {
    if status != reqwest::StatusCode::TOO_MANY_REQUESTS
        && status != reqwest::StatusCode::SERVICE_UNAVAILABLE
    {
        return None;
    }
    let value = headers
        .get(reqwest::header::RETRY_AFTER)?
        .to_str()
        .ok()?
        .trim();
    if let Ok(secs) = value.parse::<u64>() {
        return Some(Duration::from_secs(secs));
    }
    let date = httpdate::parse_http_date(value).ok()?;
    Some(date.duration_since(now).unwrap_or(Duration::ZERO))
}

/// Equal jitter: a wait drawn in `[backoff / 2, backoff]` from `unit` in `[0, 1)`. Receivers
/// that failed together do not retry in lock-step, each wait stays within the schedule's cap,
/// and a failing receiver still gets at least half the backoff between attempts.
fn equal_jitter(backoff: Duration, unit: f64) -> Duration {
    let half = backoff / 2;
    half + (backoff - half).mul_f64(unit.clamp(0.0, 1.0))
}

/// The wait before the next attempt: the receiver's `Retry-After` if it sent one, else the
/// jittered backoff; never longer than `max`.
pub(super) fn next_wait(
    error: &AttemptError,
    backoff: Duration,
    max: Duration,
    unit: f64,
) -> Duration {
    error
        .retry_after()
        .unwrap_or_else(|| equal_jitter(backoff.min(max), unit))
        .min(max)
}

impl fmt::Display for AttemptError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AttemptError::Status(s, _) => write!(f, "HTTP {s}"),
            AttemptError::InvalidRequest(e) => write!(f, "invalid request: {e}"),
            AttemptError::NoClient => write!(f, "no HTTP client"),
            AttemptError::Transport(e) => write!(f, "request error: {e}"),
        }
    }
}

/// Why a delivery (all its attempts) failed.
#[derive(Debug, thiserror::Error)]
enum DeliveryError {
    #[error("no HTTP client")]
    NoClient,
    #[error("{0}")]
    Payload(String),
    #[error("{0} (not retried)")]
    NotRetried(AttemptError),
    #[error("{last} after {attempts} attempts")]
    GaveUp { last: AttemptError, attempts: u32 },
}

/// One delivery with retries.
async fn deliver(
    target: &Target,
    client: Option<&reqwest::Client>,
    config: &NotifyConfig,
    body: Result<Vec<u8>, String>,
) -> Result<(), DeliveryError> {
    let Some(client) = client else {
        return Err(DeliveryError::NoClient);
    };
    let body = body.map_err(DeliveryError::Payload)?;
    // Attempts made so far, for the logs and the "after N attempts" message, shared by the
    // attempt closure and backon's callbacks. Atomic only because the task's future must be
    // Send (a Cell is not Sync); all of them run on this one task, so Relaxed is enough.
    let made = AtomicU32::new(0);
    let attempt = || async {
        made.fetch_add(1, Ordering::Relaxed);
        post(target, Some(client), &body).await
    };
    let max_wait = config.max_backoff();
    // backon runs the loop: the schedule bounds the retries (`max_attempts - 1`); `adjust`
    // replaces each scheduled wait by the receiver's Retry-After or the jittered backoff
    // (backon's own jitter adds up to 100 % on top of the wait, past `max_backoff_ms`). A
    // Retry-After wait uses up a retry like any other. The shutdown deadline is enforced by the
    // caller, which drops this future.
    let result = attempt
        .retry(config.backoff_schedule())
        .sleep(tokio::time::sleep)
        .when(AttemptError::retryable)
        .adjust(|error, backoff| backoff.map(|b| next_wait(error, b, max_wait, fastrand::f64())))
        .notify(|error, wait| {
            tracing::debug!(
                target_url = %target.url,
                attempt = made.load(Ordering::Relaxed),
                ?wait,
                retry_after = ?error.retry_after(),
                "alert delivery: {error}, retrying"
            );
        })
        .await;
    match result {
        Ok(()) => Ok(()),
        Err(error) if !error.retryable() => Err(DeliveryError::NotRetried(error)),
        Err(last) => Err(DeliveryError::GaveUp {
            last,
            attempts: made.load(Ordering::Relaxed),
        }),
    }
}

/// One attempt: a POST of `body`, 2xx is success.
pub(super) async fn post(
    target: &Target,
    client: Option<&reqwest::Client>,
    body: &[u8],
) -> Result<(), AttemptError> {
    let Some(client) = client else {
        return Err(AttemptError::NoClient);
    };
    let mut req = client
        .post(&target.url)
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(body.to_vec());
    if let TargetKind::Webhook {
        bearer_token: Some(token),
        ..
    } = &target.kind
    {
        req = req.bearer_auth(token);
    }
    match req.send().await {
        Ok(resp) if resp.status().is_success() => Ok(()),
        Ok(resp) => {
            let wait = retry_after(resp.status(), resp.headers(), SystemTime::now());
            Err(AttemptError::Status(resp.status(), wait))
        }
        Err(e) if e.is_builder() => Err(AttemptError::InvalidRequest(e)),
        Err(e) => Err(AttemptError::Transport(e)),
    }
}

/// Per-target warning rate limiter.
pub(super) struct WarnLimiter {
    last: Option<Instant>,
    suppressed: u64,
}

impl WarnLimiter {
    pub(super) fn new() -> Self {
        WarnLimiter {
            last: None,
            suppressed: 0,
        }
    }

    fn failure(&mut self, url: &str, error: &DeliveryError) {
        self.failure_message(url, &error.to_string());
    }

    pub(super) fn failure_message(&mut self, url: &str, error: &str) {
        let now = Instant::now();
        if self
            .last
            .is_none_or(|t| now.duration_since(t) >= WARN_EVERY)
        {
            tracing::warn!(
                target_url = url,
                suppressed_since_last_warning = self.suppressed,
                "alert delivery failed: {error}"
            );
            self.last = Some(now);
            self.suppressed = 0;
        } else {
            self.suppressed += 1;
            tracing::debug!(target_url = url, "alert delivery failed: {error}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use reqwest::StatusCode;
    use std::collections::BTreeMap;
    use std::time::{SystemTime, UNIX_EPOCH};

    fn t(secs: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(1_700_000_000 + secs)
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
        let events = Arc::new(pin_events());
        let fp = |i: usize| events[i].alert().fingerprint.clone();
        let expected_webhook = PINNED_WEBHOOK.replace("FP1", &fp(0)).replace("FP2", &fp(1));
        let webhook = TargetKind::Webhook {
            receiver: "team".into(),
            bearer_token: Some("secret".into()),
        };
        let wire = |kind: &TargetKind, job: &Job| {
            let bytes = body(kind, job, "http://gw:9184")
                .expect("this target takes this job")
                .expect("serialise");
            String::from_utf8(bytes).expect("utf-8")
        };
        let events_job = Job::Events(events.clone());
        assert_eq!(wire(&webhook, &events_job), expected_webhook);
        assert_eq!(
            wire(&TargetKind::Alertmanager, &events_job),
            PINNED_ALERTMANAGER
        );
        // A re-send of the same alerts is the same body; webhooks do not take re-sends.
        let alerts: Vec<Alert> = events.iter().map(|e| e.alert().clone()).collect();
        let resend = Job::Resend(Arc::new(alerts));
        assert_eq!(
            wire(&TargetKind::Alertmanager, &resend),
            PINNED_ALERTMANAGER
        );
        assert!(body(&webhook, &resend, "").is_none());
    }

    #[test]
    fn which_answers_are_retried() {
        let retried = |code: u16| {
            AttemptError::Status(StatusCode::from_u16(code).expect("valid status"), None)
                .retryable()
        };
        for code in [500, 502, 503, 504, 408, 429] {
            assert!(retried(code), "{code} is retried");
        }
        for code in [400, 401, 403, 404, 409, 422] {
            assert!(!retried(code), "{code} is not retried");
        }
    }

    #[test]
    fn failure_messages() {
        let s = |code: u16| AttemptError::Status(StatusCode::from_u16(code).expect("status"), None);
        assert_eq!(
            DeliveryError::NotRetried(s(400)).to_string(),
            "HTTP 400 Bad Request (not retried)"
        );
        assert_eq!(
            DeliveryError::GaveUp {
                last: s(503),
                attempts: 6
            }
            .to_string(),
            "HTTP 503 Service Unavailable after 6 attempts"
        );
        assert_eq!(DeliveryError::NoClient.to_string(), "no HTTP client");
    }

    #[test]
    fn retry_after_delta_seconds_or_http_date_on_429_and_503_only() {
        use reqwest::header::{HeaderMap, HeaderValue, RETRY_AFTER};
        let now = UNIX_EPOCH + Duration::from_secs(1_445_412_480); // Wed, 21 Oct 2015 07:28:00 GMT
        let headers = |v: &str| {
            let mut h = HeaderMap::new();
            h.insert(RETRY_AFTER, HeaderValue::from_str(v).expect("header"));
            h
        };
        let ra = |code: u16, v: &str| {
            retry_after(
                StatusCode::from_u16(code).expect("status"),
                &headers(v),
                now,
            )
        };
        assert_eq!(ra(503, "120"), Some(Duration::from_secs(120)));
        assert_eq!(ra(429, " 0 "), Some(Duration::ZERO));
        assert_eq!(
            ra(503, "Wed, 21 Oct 2015 07:28:30 GMT"),
            Some(Duration::from_secs(30))
        );
        assert_eq!(
            ra(429, "Wed, 21 Oct 2015 07:27:00 GMT"),
            Some(Duration::ZERO),
            "a date in the past: now"
        );
        assert_eq!(ra(503, "soon"), None);
        assert_eq!(ra(503, "-5"), None);
        assert_eq!(ra(500, "120"), None, "only 429 and 503 define it");
        assert_eq!(ra(502, "120"), None);
        assert_eq!(
            retry_after(StatusCode::SERVICE_UNAVAILABLE, &HeaderMap::new(), now),
            None
        );
    }

    #[test]
    fn waits_are_jittered_within_the_cap_and_retry_after_wins_capped() {
        let ms = Duration::from_millis;
        let max = ms(1000);
        let plain = AttemptError::Status(StatusCode::INTERNAL_SERVER_ERROR, None);
        assert_eq!(next_wait(&plain, ms(400), max, 0.0), ms(200));
        assert_eq!(next_wait(&plain, ms(400), max, 1.0), ms(400));
        // A first wait above the cap (initial_backoff_ms > max_backoff_ms) is capped too.
        assert_eq!(next_wait(&plain, ms(5000), max, 1.0), max);
        let mut rng = fastrand::Rng::with_seed(7);
        for backoff in [0, 1, 10, 400, 999, 1000, 5000, u64::MAX] {
            let backoff = ms(backoff);
            for _ in 0..200 {
                let w = next_wait(&plain, backoff, max, rng.f64());
                let b = backoff.min(max);
                assert!(w >= b / 2 && w <= b, "{w:?} for {backoff:?}");
            }
        }
        let asked = |s: u64| AttemptError::Status(StatusCode::SERVICE_UNAVAILABLE, Some(ms(s)));
        assert_eq!(
            next_wait(&asked(300), ms(10), max, 0.5),
            ms(300),
            "not jittered"
        );
        assert_eq!(next_wait(&asked(0), ms(800), max, 0.5), ms(0));
        assert_eq!(
            next_wait(&asked(3_600_000), ms(10), max, 0.5),
            max,
            "capped"
        );
    }
}
