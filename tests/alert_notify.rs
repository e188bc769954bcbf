//! Delivery tests against real HTTP receivers (axum servers on 127.0.0.1:0 inside the test).
//! Every wait is bounded, so a broken notifier fails a test instead of hanging it.

use std::future::IntoFuture;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use axum::body::Bytes;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, Uri};
use axum::Router;
use gatewatch::alert::notify::outbox::OutboxEntry;
use gatewatch::alert::notify::{
    spawn_notifier, spawn_notifier_with_ack, NotifierHandle, NotifyConfig, StatsSnapshot,
    WebhookTarget,
};
use gatewatch::alert::{Alert, AlertEngine, AlertEvent, AlertRules, Observation};
use serde_json::Value;

#[derive(Debug, Clone)]
struct Request {
    path: String,
    authorization: Option<String>,
    body: Value,
    at: Instant,
}

#[derive(Clone, Default)]
struct Receiver {
    requests: Arc<Mutex<Vec<Request>>>,
    /// Answer 500 to this many requests first.
    fail_first: Arc<AtomicUsize>,
    /// Sleep this long before answering (ms).
    delay_ms: Arc<AtomicUsize>,
    /// The status of those failures (0: 500).
    fail_status: Arc<AtomicUsize>,
    /// `Retry-After` sent with those failures.
    retry_after: Arc<Mutex<Option<String>>>,
}

impl Receiver {
    fn requests(&self) -> Vec<Request> {
        self.requests.lock().expect("lock").clone()
    }
    fn count(&self) -> usize {
        self.requests.lock().expect("lock").len()
    }
}

async fn record(
    State(rx): State<Receiver>,
    uri: Uri,
    headers: HeaderMap,
    body: Bytes,
) -> axum::response::Response {
    use axum::response::IntoResponse;
    let delay = rx.delay_ms.load(Ordering::SeqCst);
    if delay > 0 {
        tokio::time::sleep(Duration::from_millis(delay as u64)).await;
    }
    let body = serde_json::from_slice(&body).unwrap_or(Value::Null);
    rx.requests.lock().expect("lock").push(Request {
        path: uri.path().to_string(),
        authorization: headers
            .get("authorization")
            .and_then(|v| v.to_str().ok())
            .map(str::to_string),
        body,
        at: Instant::now(),
    });
    let fail = rx
        .fail_first
        .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
        .is_ok();
    if !fail {
        return StatusCode::OK.into_response();
    }
    let status = match rx.fail_status.load(Ordering::SeqCst) {
        0 => StatusCode::INTERNAL_SERVER_ERROR,
        code => StatusCode::from_u16(code as u16).expect("valid status"),
    };
    let mut resp = status.into_response();
    if let Some(v) = rx.retry_after.lock().expect("lock").clone() {
        let v = axum::http::HeaderValue::from_str(&v).expect("header value");
        resp.headers_mut()
            .insert(axum::http::header::RETRY_AFTER, v);
    }
    resp
}

/// Serves `app` on a port chosen by the system; returns its base URL.
async fn serve(app: Router) -> String {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    tokio::spawn(axum::serve(listener, app).into_future());
    format!("http://{addr}")
}

/// A started recording receiver that fails its first `fail_first` requests; with its base URL.
async fn recording_receiver(fail_first: usize) -> (Receiver, String) {
    let rec = Receiver::default();
    rec.fail_first.store(fail_first, Ordering::SeqCst);
    let base = serve(Router::new().fallback(record).with_state(rec.clone())).await;
    (rec, base)
}

/// A receiver that accepts connections and never answers.
async fn hanging_receiver() -> (String, tokio::task::JoinHandle<()>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr: SocketAddr = listener.local_addr().expect("addr");
    let task = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((sock, _)) = listener.accept().await {
            held.push(sock);
        }
    });
    (format!("http://{addr}"), task)
}

/// An address where nothing listens (bound then released).
async fn dead_url() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    drop(listener);
    format!("http://{addr}/hook")
}

async fn wait_until(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// Waits (up to `WAIT`) until the notifier's counters satisfy `cond`.
async fn wait_stats(what: &str, handle: &NotifierHandle, cond: impl Fn(&StatsSnapshot) -> bool) {
    wait_until(what, WAIT, || cond(&handle.stats().snapshot())).await;
}

/// Asserts that the notifier's task ends (within `WAIT`) without a panic.
async fn assert_ends(task: tokio::task::JoinHandle<()>) {
    tokio::time::timeout(WAIT, task)
        .await
        .expect("task ends")
        .expect("no panic");
}

fn t(secs: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_secs(1_700_000_000 + secs)
}

fn obs(z: f64) -> Observation<'static> {
    Observation {
        zeta0: Some(z),
        zeta0_interval: Some((z - 0.002, z + 0.002)),
        trusted: true,
        frequency_hz: Some(10.4),
        limit_cycle_amplitude: Some(0.05),
        time_to_limit: Some(12.0),
        equation: "ydd + c1*yd + c2*y = 0",
        trend: None,
        ambient_ratio: None,
        departure_ratio: None,
        ..Default::default()
    }
}

/// (firing, resolved) events of gate `gate`.
fn events(gate: &str) -> (Vec<AlertEvent>, Vec<AlertEvent>) {
    let mut e = AlertEngine::new(AlertRules::default());
    e.observe(gate, &obs(-0.012), t(0));
    let fired = e.observe(gate, &obs(-0.012), t(5));
    e.observe(gate, &obs(0.02), t(10));
    let resolved = e.observe(gate, &obs(0.02), t(20));
    assert_eq!((fired.len(), resolved.len()), (1, 1));
    (fired, resolved)
}

fn fast_config() -> NotifyConfig {
    NotifyConfig {
        resend_interval_seconds: 0.0,
        timeout_seconds: 5.0,
        max_attempts: 5,
        initial_backoff_ms: 10,
        max_backoff_ms: 200,
        queue_capacity: 16,
        external_url: "http://gatewatch.test:9184".into(),
        ..NotifyConfig::default()
    }
}

fn webhook(url: String, token: Option<&str>) -> WebhookTarget {
    WebhookTarget {
        url,
        bearer_token: token.map(str::to_string),
        receiver: "ops".into(),
    }
}

/// `fast_config()` with one webhook, at `{base}/hook`.
fn hook_config(base: &str) -> NotifyConfig {
    NotifyConfig {
        webhooks: vec![webhook(format!("{base}/hook"), None)],
        ..fast_config()
    }
}

const WAIT: Duration = Duration::from_secs(10);

#[tokio::test]
async fn webhook_gets_v4_payload_with_bearer_token_and_resolved_ends_at() {
    let (rec, base) = recording_receiver(0).await;
    let config = NotifyConfig {
        webhooks: vec![
            webhook(format!("{base}/with-token"), Some("s3cret")),
            webhook(format!("{base}/without"), None),
        ],
        ..fast_config()
    };
    let (handle, task) = spawn_notifier(config, Vec::new);
    let (fired, resolved) = events("g1");
    assert!(handle.notify(fired));
    wait_until("firing delivered", WAIT, || rec.count() == 2).await;
    assert!(handle.notify(resolved));
    wait_until("resolved delivered", WAIT, || rec.count() == 4).await;

    let reqs = rec.requests();
    let with: Vec<_> = reqs.iter().filter(|r| r.path == "/with-token").collect();
    let without: Vec<_> = reqs.iter().filter(|r| r.path == "/without").collect();
    assert_eq!((with.len(), without.len()), (2, 2));
    assert!(with
        .iter()
        .all(|r| r.authorization.as_deref() == Some("Bearer s3cret")));
    assert!(without.iter().all(|r| r.authorization.is_none()));

    let b = &with[0].body;
    assert_eq!(b["version"], "4");
    assert_eq!(b["status"], "firing");
    assert_eq!(b["receiver"], "ops");
    assert_eq!(b["truncatedAlerts"], 0);
    assert_eq!(b["externalURL"], "http://gatewatch.test:9184");
    assert_eq!(
        b["groupKey"],
        "{}:{alertname=\"GateNegativeDamping\", gate=\"g1\"}"
    );
    assert_eq!(b["groupLabels"]["gate"], "g1");
    assert_eq!(b["commonLabels"]["severity"], "critical");
    assert!(b["commonAnnotations"]["summary"].is_string());
    let a = &b["alerts"][0];
    assert_eq!(a["status"], "firing");
    assert_eq!(a["labels"]["alertname"], "GateNegativeDamping");
    assert_eq!(a["startsAt"], "2023-11-14T22:13:20.000Z");
    assert_eq!(a["endsAt"], "0001-01-01T00:00:00Z");
    assert_eq!(a["generatorURL"], "http://gatewatch.test:9184");
    assert_eq!(a["fingerprint"].as_str().map(str::len), Some(16));
    assert_eq!(
        a["annotations"]["summary"],
        "gate g1: damping ratio -1.2 % (self-excited vibration at 10.4 Hz)"
    );

    let b = &with[1].body;
    assert_eq!(b["status"], "resolved");
    assert_eq!(b["alerts"][0]["status"], "resolved");
    assert_eq!(b["alerts"][0]["endsAt"], "2023-11-14T22:13:40.000Z");
    assert_eq!(
        b["alerts"][0]["fingerprint"],
        with[0].body["alerts"][0]["fingerprint"]
    );

    // the receiver records a request before it answers; the notifier counts the delivery when
    // the answer reaches it, on its own task
    wait_stats("4 delivered", &handle, |s| s.delivered == 4).await;
    let s = handle.stats().snapshot();
    assert_eq!((s.delivered, s.failed, s.dropped), (4, 0, 0));
    assert!(handle.shutdown(WAIT).await);
    assert_ends(task).await;
}

#[tokio::test]
async fn retries_with_exponential_backoff_until_success() {
    let (rec, base) = recording_receiver(3).await;
    let config = NotifyConfig {
        initial_backoff_ms: 40,
        max_backoff_ms: 1000,
        ..hook_config(&base)
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    wait_stats("success after 3 failures", &handle, |s| s.delivered == 1).await;
    let reqs = rec.requests();
    assert_eq!(reqs.len(), 4, "3 failures + 1 success");
    assert!(
        reqs.iter().all(|r| r.body == reqs[0].body),
        "same body each attempt"
    );
    let gaps: Vec<Duration> = reqs.windows(2).map(|w| w[1].at - w[0].at).collect();
    // Backoff 40, 80, 160 ms (doubling), each jittered within its upper half: at least 20, 40,
    // 80 ms (1 ms off for backon's f32 arithmetic); scheduling slack only adds.
    for (gap, min) in gaps.iter().zip([19u64, 39, 79]) {
        assert!(*gap >= Duration::from_millis(min), "gaps {gaps:?}");
    }
    assert_eq!(handle.stats().snapshot().failed, 0);
    assert!(handle.shutdown(WAIT).await);
}

/// A 503 with `Retry-After: 1` is waited out (not the 10 ms backoff), and the attempt counts.
#[tokio::test]
async fn retry_after_seconds_is_honoured() {
    let (rec, base) = recording_receiver(1).await;
    rec.fail_status.store(503, Ordering::SeqCst);
    *rec.retry_after.lock().expect("lock") = Some("1".into());
    let config = NotifyConfig {
        max_attempts: 2,
        initial_backoff_ms: 10,
        max_backoff_ms: 5000,
        ..hook_config(&base)
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    wait_stats("delivered after the 503", &handle, |s| s.delivered == 1).await;
    let reqs = rec.requests();
    assert_eq!(
        reqs.len(),
        2,
        "503 + 200: the Retry-After wait used up one retry"
    );
    let gap = reqs[1].at - reqs[0].at;
    assert!(gap >= Duration::from_millis(950), "waited {gap:?}");
    let s = handle.stats().snapshot();
    assert_eq!((s.delivered, s.failed, s.dropped), (1, 0, 0));
    assert!(handle.shutdown(WAIT).await);
}

/// A `Retry-After` longer than `max_backoff_ms` (an hour here, as an HTTP date) is cut to it,
/// every such wait counts as an attempt, and the delivery gives up after `max_attempts`.
#[tokio::test]
async fn retry_after_beyond_the_cap_is_capped_and_counted() {
    let (rec, base) = recording_receiver(usize::MAX).await;
    rec.fail_status.store(429, Ordering::SeqCst);
    let in_an_hour = SystemTime::now() + Duration::from_secs(3600);
    *rec.retry_after.lock().expect("lock") = Some(httpdate::fmt_http_date(in_an_hour));
    let config = NotifyConfig {
        max_attempts: 3,
        initial_backoff_ms: 10,
        max_backoff_ms: 200,
        ..hook_config(&base)
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    // Within WAIT, not an hour.
    wait_stats("failure counted", &handle, |s| s.failed == 1).await;
    let reqs = rec.requests();
    assert_eq!(reqs.len(), 3, "max_attempts, Retry-After waits included");
    for w in reqs.windows(2) {
        let gap = w[1].at - w[0].at;
        // The capped Retry-After (200 ms), not the 10-20 ms backoff.
        assert!(gap >= Duration::from_millis(190), "gap {gap:?}");
    }
    assert_eq!(handle.stats().snapshot().delivered, 0);
    assert!(handle.shutdown(WAIT).await);
}

#[tokio::test]
async fn gives_up_after_max_attempts_and_counts_failed() {
    let (rec, base) = recording_receiver(usize::MAX).await;
    let config = NotifyConfig {
        max_attempts: 3,
        ..hook_config(&base)
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    wait_stats("failure counted", &handle, |s| s.failed == 1).await;
    assert_eq!(rec.count(), 3);
    assert_eq!(handle.stats().snapshot().delivered, 0);
    assert!(handle.shutdown(WAIT).await);
}

#[tokio::test]
async fn client_errors_are_not_retried() {
    // A 404 (wrong path) will not get better by retrying: one attempt of the five allowed, then
    // the failure. (Until stop 67 this test bounded the time instead, which five quick attempts
    // also met.)
    let (rec, base) = recording_receiver(usize::MAX).await;
    rec.fail_status.store(404, Ordering::SeqCst);
    let config = hook_config(&base);
    assert_eq!(config.max_attempts, 5);
    let (handle, _task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    wait_stats("failure counted", &handle, |s| s.failed == 1).await;
    assert_eq!(rec.count(), 1, "a 404 was retried");
    assert!(handle.shutdown(WAIT).await);
}

#[tokio::test]
async fn invalid_url_fails_without_panic_or_retries() {
    let config = NotifyConfig {
        webhooks: vec![webhook("not a url".into(), Some("t"))],
        alertmanager_urls: vec!["ftp://am".into()],
        // A retry would wait a minute, far beyond `WAIT`: both failures counted within `WAIT`
        // means neither was retried. (The bound used to be 900 ms against a 1 s backoff that
        // `max_backoff_ms = 200` capped, so four quick retries also met it.)
        initial_backoff_ms: 60_000,
        max_backoff_ms: 60_000,
        ..fast_config()
    };
    assert!(config.validate().is_err());
    let (handle, task) = spawn_notifier(config, Vec::new);
    handle.notify(events("g1").0);
    wait_stats("both failures counted, without a retry", &handle, |s| {
        s.failed == 2
    })
    .await;
    assert!(handle.shutdown(WAIT).await);
    assert_ends(task).await;
}

#[tokio::test]
async fn dead_or_hanging_receiver_does_not_block_others() {
    let (rec, base) = recording_receiver(0).await;
    let (hang, _hang_task) = hanging_receiver().await;
    let config = NotifyConfig {
        webhooks: vec![
            webhook(format!("{hang}/hook"), None),
            webhook(dead_url().await, None),
            webhook(format!("{base}/live"), None),
        ],
        timeout_seconds: 30.0,
        max_attempts: 50,
        initial_backoff_ms: 100,
        max_backoff_ms: 100,
        ..fast_config()
    };
    let (handle, task) = spawn_notifier(config, Vec::new);
    let (fired, resolved) = events("g1");
    let start = Instant::now();
    handle.notify(fired);
    handle.notify(resolved);
    wait_until("live receiver got both batches", 2 * WAIT, || {
        rec.count() == 2
    })
    .await;
    // a blocked queue would wait for the hanging target's 30 s timeout; 10 s leaves a loaded
    // machine room without hiding that
    assert!(
        start.elapsed() < Duration::from_secs(10),
        "live receiver delayed: {:?}",
        start.elapsed()
    );
    wait_stats("2 delivered", &handle, |s| s.delivered == 2).await;
    // Shutdown cannot flush the stuck targets: it returns at the deadline, abandoning them.
    let start = Instant::now();
    assert!(!handle.shutdown(Duration::from_millis(300)).await);
    let took = start.elapsed();
    // at its deadline, not after the stuck targets' 30 s timeout
    assert!(
        took >= Duration::from_millis(300) && took < Duration::from_secs(10),
        "{took:?}"
    );
    assert_ends(task).await;
    let s = handle.stats().snapshot();
    // 2 batches for each of the 2 stuck targets were abandoned.
    assert_eq!(s.dropped, 4, "{s:?}");
    assert_eq!(s.delivered, 2);
}

#[tokio::test]
async fn alertmanager_receives_array_at_api_v2_alerts() {
    let (rec, base) = recording_receiver(0).await;
    let config = NotifyConfig {
        // Trailing slash tolerated.
        alertmanager_urls: vec![format!("{base}/")],
        ..fast_config()
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    let (fired, resolved) = events("g1");
    handle.notify(fired);
    wait_until("firing posted", WAIT, || rec.count() == 1).await;
    handle.notify(resolved);
    wait_until("resolved posted", WAIT, || rec.count() == 2).await;
    let reqs = rec.requests();
    assert!(reqs.iter().all(|r| r.path == "/api/v2/alerts"));
    let a = &reqs[0].body;
    assert_eq!(a.as_array().map(Vec::len), Some(1));
    assert_eq!(a[0]["labels"]["alertname"], "GateNegativeDamping");
    assert_eq!(a[0]["labels"]["gate"], "g1");
    assert_eq!(a[0]["startsAt"], "2023-11-14T22:13:20.000Z");
    assert!(a[0].get("endsAt").is_none(), "firing: no endsAt");
    assert_eq!(a[0]["generatorURL"], "http://gatewatch.test:9184");
    assert_eq!(a[0]["annotations"]["damping_ratio"], "-0.012");
    let r = &reqs[1].body;
    assert_eq!(r[0]["endsAt"], "2023-11-14T22:13:40.000Z");
    assert!(handle.shutdown(WAIT).await);
}

#[tokio::test]
async fn firing_alerts_are_resent_to_alertmanager_only() {
    let (am, am_base) = recording_receiver(0).await;
    let (hook, hook_base) = recording_receiver(0).await;
    let snapshot: Arc<Mutex<Vec<Alert>>> = Arc::new(Mutex::new(Vec::new()));
    let snap = snapshot.clone();
    let config = NotifyConfig {
        alertmanager_urls: vec![am_base],
        webhooks: vec![webhook(format!("{hook_base}/hook"), None)],
        resend_interval_seconds: 0.05,
        ..fast_config()
    };
    let (handle, _task) = spawn_notifier(config, move || {
        snap.lock().map(|v| v.clone()).unwrap_or_default()
    });
    // Nothing firing: no re-sends.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(am.count(), 0);
    let (fired, _) = events("g1");
    *snapshot.lock().expect("lock") = vec![fired[0].alert().clone()];
    wait_until("3 re-sends", WAIT, || am.count() >= 3).await;
    for r in am.requests() {
        assert_eq!(r.body[0]["labels"]["gate"], "g1");
        assert!(r.body[0].get("endsAt").is_none());
    }
    assert_eq!(hook.count(), 0, "webhooks get transitions only");
    snapshot.lock().expect("lock").clear();
    assert!(handle.shutdown(WAIT).await);
}

#[tokio::test]
async fn shutdown_flushes_queued_batches() {
    let (rec, base) = recording_receiver(1).await;
    rec.delay_ms.store(30, Ordering::SeqCst);
    let config = hook_config(&base);
    let (handle, task) = spawn_notifier(config, Vec::new);
    for g in ["g1", "g2", "g3", "g4", "g5"] {
        assert!(handle.notify(events(g).0));
    }
    assert!(handle.shutdown(WAIT).await, "flushed before the deadline");
    // Everything queued was delivered (the first one after a retry).
    let gates: Vec<String> = rec
        .requests()
        .iter()
        .map(|r| {
            r.body["alerts"][0]["labels"]["gate"]
                .as_str()
                .unwrap_or("")
                .to_string()
        })
        .collect();
    assert_eq!(gates, vec!["g1", "g1", "g2", "g3", "g4", "g5"]);
    let s = handle.stats().snapshot();
    assert_eq!((s.delivered, s.failed, s.dropped), (5, 0, 0));
    assert_ends(task).await;
    // After shutdown: refused, counted, no blocking.
    assert!(!handle.notify(events("g6").0));
    assert_eq!(handle.stats().snapshot().dropped, 1);
    assert!(
        handle.shutdown(Duration::from_millis(10)).await,
        "idempotent"
    );
}

#[tokio::test]
async fn full_queue_drops_without_blocking() {
    let (hang, _hang_task) = hanging_receiver().await;
    let config = NotifyConfig {
        queue_capacity: 2,
        timeout_seconds: 30.0,
        ..hook_config(&hang)
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    let (fired, _) = events("g1");
    let start = Instant::now();
    let mut accepted = 0;
    for _ in 0..100 {
        if handle.notify(fired.clone()) {
            accepted += 1;
        }
        tokio::task::yield_now().await;
    }
    assert!(
        start.elapsed() < Duration::from_secs(2),
        "notify never blocks"
    );
    let s = handle.stats().snapshot();
    // Accepted by the handle queue, then dropped at the target queue or still queued:
    // in any case far fewer than 100 kept, and every loss counted.
    assert!(s.dropped >= 90, "{s:?} accepted {accepted}");
    assert!(!handle.shutdown(Duration::from_millis(100)).await);
    assert!(handle.notify(Vec::new()), "empty batch is a no-op");
}

/// A restart must not resolve anything: shutting down sends no "resolved", and re-sends the
/// firing alerts to Alertmanager once more, so they stay active for a whole resolve_timeout
/// from the shutdown while the restarted daemon re-asserts them.
#[tokio::test]
async fn shutdown_resends_firing_alerts_to_alertmanager_and_resolves_nothing() {
    let (am, am_base) = recording_receiver(0).await;
    let (hook, hook_base) = recording_receiver(0).await;
    let (fired, _) = events("g1");
    let firing = vec![fired[0].alert().clone()];
    let config = NotifyConfig {
        alertmanager_urls: vec![am_base],
        webhooks: vec![webhook(format!("{hook_base}/hook"), None)],
        // far longer than the test: only the shutdown can cause a re-send
        resend_interval_seconds: 3600.0,
        ..fast_config()
    };
    let (handle, _task) = spawn_notifier(config, move || firing.clone());
    assert!(handle.shutdown(WAIT).await);
    let reqs = am.requests();
    assert_eq!(reqs.len(), 1, "one re-send at shutdown");
    assert_eq!(reqs[0].body[0]["labels"]["gate"], "g1");
    assert!(reqs[0].body[0].get("endsAt").is_none(), "still firing");
    assert_eq!(hook.count(), 0, "webhooks get no re-send and no resolved");
    let s = handle.stats().snapshot();
    assert_eq!((s.alertmanager.delivered, s.webhook.delivered), (1, 0));
}

/// The counters are kept per kind of target, and a batch dropped before it reached the
/// targets' queues counts once for every target.
#[tokio::test]
async fn stats_split_by_target_kind() {
    let (_, am_base) = recording_receiver(0).await;
    let config = NotifyConfig {
        alertmanager_urls: vec![am_base],
        webhooks: vec![
            webhook(dead_url().await, None),
            webhook(dead_url().await, None),
        ],
        max_attempts: 1,
        ..fast_config()
    };
    let (handle, _task) = spawn_notifier(config, Vec::new);
    let (fired, _) = events("g1");
    assert!(handle.notify(fired.clone()));
    wait_stats("delivered and failed", &handle, |s| {
        s.alertmanager.delivered == 1 && s.webhook.failed == 2
    })
    .await;
    assert!(handle.shutdown(WAIT).await);
    // refused after shutdown: dropped for each of the three targets
    assert!(!handle.notify(fired));
    let s = handle.stats().snapshot();
    assert_eq!((s.webhook.dropped, s.alertmanager.dropped), (2, 1));
    assert_eq!((s.delivered, s.failed, s.dropped), (1, 2, 3));
}

/// Outbox entry `n` (row id `n`, batch `n`) of a firing alert with fingerprint `fp<n>`.
fn outbox_entry(n: i64) -> OutboxEntry {
    let (fired, _) = events("g1");
    let mut alert = fired[0].alert().clone();
    alert.fingerprint = format!("fp{n}");
    OutboxEntry {
        id: Some(n),
        batch: n as u64,
        event: AlertEvent::Firing(alert),
        created: SystemTime::now(),
    }
}

/// A receiver that fails for as long as an outage lasts, while new alerts keep coming: the
/// entries a target keeps in memory stop at `outbox_max_pending`. The oldest are given up
/// (counted in `failed`, their rows acknowledged for the store to delete); the newest are
/// delivered in order once the receiver is back. Before stop 60 the queue grew with every new
/// alert for `notification_max_age_seconds` (a day).
#[tokio::test]
async fn an_outbox_queue_kept_during_an_outage_stops_at_its_bound_and_gives_up_the_oldest() {
    let (rec, base) = recording_receiver(usize::MAX).await;
    let config = NotifyConfig {
        outbox_max_age: Some(Duration::from_secs(3600)),
        outbox_max_pending: 5,
        ..hook_config(&base)
    };
    let acked = Arc::new(Mutex::new(Vec::<i64>::new()));
    let sink = acked.clone();
    let ack: gatewatch::alert::notify::outbox::Ack =
        Arc::new(move |ids: Vec<i64>| sink.lock().expect("lock").extend(ids));
    let (handle, _task) = spawn_notifier_with_ack(config, Vec::new, ack);
    // the head is retried...
    assert!(handle.notify_entries(vec![(0, outbox_entry(1))]));
    wait_until("the head's first attempts", WAIT, || rec.count() >= 2).await;
    // ...while eleven more alerts come
    assert!(handle.notify_entries((2..=12).map(|n| (0, outbox_entry(n))).collect()));
    wait_until("the oldest given up", WAIT, || {
        acked.lock().expect("lock").len() == 7
    })
    .await;
    assert_eq!(*acked.lock().expect("lock"), (1..=7).collect::<Vec<_>>());
    let s = handle.stats().snapshot();
    assert_eq!((s.webhook.failed, s.webhook.delivered), (7, 0));
    // the receiver is back: the five kept are delivered, in order
    rec.fail_first.store(0, Ordering::SeqCst);
    wait_stats("the rest delivered", &handle, |s| s.webhook.delivered == 5).await;
    assert_eq!(*acked.lock().expect("lock"), (1..=12).collect::<Vec<_>>());
    let mut sent: Vec<String> = Vec::new();
    for r in rec.requests() {
        let fp = r.body["alerts"][0]["fingerprint"]
            .as_str()
            .expect("fingerprint")
            .to_string();
        if sent.last() != Some(&fp) {
            sent.push(fp);
        }
    }
    assert_eq!(sent, ["fp1", "fp8", "fp9", "fp10", "fp11", "fp12"]);
    assert_eq!(handle.stats().snapshot().webhook.failed, 7);
    assert!(handle.shutdown(WAIT).await);
}
