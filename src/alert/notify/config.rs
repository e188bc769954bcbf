//! What the notifier is told: targets, timeouts, retry and queue bounds (`[notify]` in the
//! daemon's configuration).

use std::time::Duration;

use backon::ExponentialBuilder;
use serde::Deserialize;

/// Default capacity of the notifier's queues (the handle's and each target's).
pub const DEFAULT_QUEUE_CAPACITY: usize = 1024;

/// Most outbox entries a target keeps in memory while its head is retried (the daemon with a
/// store: [`NotifyConfig::outbox_max_pending`]). Why a count: an entry is retried for
/// `notification_max_age_seconds` (a day), and supersession bounds the entries by the alerts
/// (two per alert for a webhook, one for Alertmanager), not by a number: gates that come, fire
/// `GateDataStale` and expire, each a new alert, made the queue of a dead receiver grow with
/// every gate for a day (`max_gates` new gates every `unknown_gate_expiry_seconds`, up to
/// millions of entries of about 1.5 KB). 10 000 is two entries for each of `max_gates`' largest
/// value, about 15 MB per target; real outages with real gates stay far below it. At the bound
/// the oldest entries are given up, as at their maximum age: counted in `failed`, logged, and
/// deleted from the store (the newest transitions are the ones that say what is true now).
pub const DEFAULT_OUTBOX_MAX_PENDING: usize = 10_000;

/// One webhook receiver (anything that understands Alertmanager's webhook format).
#[derive(Clone, PartialEq, Deserialize)]
#[serde(
    deny_unknown_fields,
    // what a user reads for `webhooks = ["http://..."]`, instead of the type's name
    expecting = "a table such as { url = \"http://host/hook\" } ([[notify.webhooks]] with url, and optionally bearer_token and receiver)"
)]
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
    /// Attempts per delivery, the first included (default 6; at least 1: 1 is no retry;
    /// [`validate`](Self::validate) refuses 0, which the notifier reads as 1).
    pub max_attempts: u32,
    /// Wait before the first retry (default 500 ms), doubling at each retry...
    pub initial_backoff_ms: u64,
    /// ...up to this (default 30000 ms). Each wait is jittered within its upper half (equal
    /// jitter), so it never exceeds this. Also the longest wait a receiver's `Retry-After` (on
    /// 429 or 503) can ask for: a longer one is cut to this, so a receiver cannot park the
    /// queue.
    pub max_backoff_ms: u64,
    /// Capacity of the handle's queue and of each target's queue, in batches (default 1024;
    /// at least 1: [`validate`](Self::validate) refuses 0, which the notifier reads as 1).
    pub queue_capacity: usize,
    /// This daemon's URL: `externalURL` of webhook payloads and `generatorURL` of every alert.
    pub external_url: String,
    /// Set by the daemon from `[storage] notification_max_age_seconds` when it has an outbox:
    /// an outbox entry is then retried for as long as it is younger than this, whatever
    /// `max_attempts` says (not a `[notify]` key).
    #[serde(skip)]
    pub outbox_max_age: Option<Duration>,
    /// Most outbox entries per target in memory ([`DEFAULT_OUTBOX_MAX_PENDING`]; not a
    /// `[notify]` key, a field for the tests; 0 acts as 1).
    #[serde(skip)]
    pub outbox_max_pending: usize,
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
            outbox_max_age: None,
            outbox_max_pending: DEFAULT_OUTBOX_MAX_PENDING,
        }
    }
}

/// A configuration that cannot work (see [`NotifyConfig::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NotifyConfigError {
    /// A target URL does not parse or is not http(s).
    #[error("invalid {what} URL {url:?}: {reason}")]
    BadUrl {
        /// The key under `[notify]`: `webhooks[2].url`, `alertmanager_urls[0]`.
        key: String,
        what: &'static str,
        url: String,
        reason: String,
    },
    /// `timeout_seconds` is not a positive finite number.
    #[error("timeout_seconds must be a positive finite number, got {}", crate::number::Num(*.0))]
    BadTimeout(f64),
    /// `resend_interval_seconds` is negative or NaN.
    #[error("resend_interval_seconds must be >= 0, got {}", crate::number::Num(*.0))]
    BadResendInterval(f64),
    /// `max_attempts` or `queue_capacity` is 0: no delivery could be made, or no batch queued.
    #[error("must be at least 1, got 0")]
    Zero(&'static str),
}

impl NotifyConfigError {
    /// The key at fault under `[notify]`, for an error that names its place
    /// (`notify.webhooks[1].url`).
    pub fn key(&self) -> String {
        match self {
            NotifyConfigError::BadUrl { key, .. } => key.clone(),
            NotifyConfigError::BadTimeout(_) => "timeout_seconds".into(),
            NotifyConfigError::BadResendInterval(_) => "resend_interval_seconds".into(),
            NotifyConfigError::Zero(key) => (*key).into(),
        }
    }
}

impl NotifyConfig {
    /// Check URLs and durations. [`spawn_notifier`](super::spawn_notifier) never panics on a
    /// bad config (a bad URL makes every delivery to it fail), but a daemon should reject one
    /// at load time.
    pub fn validate(&self) -> Result<(), NotifyConfigError> {
        let check = |key: String, what: &'static str, url: &str| -> Result<(), NotifyConfigError> {
            let bad = |reason: String| NotifyConfigError::BadUrl {
                key: key.clone(),
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
        for (i, w) in self.webhooks.iter().enumerate() {
            check(format!("webhooks[{i}].url"), "webhook", &w.url)?;
        }
        for (i, u) in self.alertmanager_urls.iter().enumerate() {
            check(format!("alertmanager_urls[{i}]"), "alertmanager", u)?;
            // gatewatch appends the API path; given twice, every notification went to
            // `/api/v2/alerts/api/v2/alerts`, a 404, and was lost (a path prefix such as a
            // reverse proxy's `/alertmanager` stays allowed)
            let path = reqwest::Url::parse(u).map_or(String::new(), |p| p.path().to_string());
            let path = path.trim_end_matches('/');
            if ["/api/v2/alerts", "/api/v1/alerts", "/api/v2", "/api/v1"]
                .iter()
                .any(|api| path.ends_with(api))
            {
                return Err(NotifyConfigError::BadUrl {
                    key: format!("alertmanager_urls[{i}]"),
                    what: "alertmanager",
                    url: u.clone(),
                    reason: format!(
                        "give Alertmanager's base URL (such as http://alertmanager:9093), without the API path {path:?}: gatewatch appends /api/v2/alerts"
                    ),
                });
            }
        }
        // every alert carries it as `generatorURL`, which Alertmanager's API requires to be a
        // URI: `external_url = "gatewatch.example.org"` made it answer 422 to every
        // notification (measured against prometheus-alertmanager 0.25), and each was lost
        if !self.external_url.is_empty() {
            check("external_url".into(), "external", &self.external_url)?;
        }
        if !(self.timeout_seconds.is_finite() && self.timeout_seconds > 0.0) {
            return Err(NotifyConfigError::BadTimeout(self.timeout_seconds));
        }
        if self.resend_interval_seconds.is_nan() || self.resend_interval_seconds < 0.0 {
            return Err(NotifyConfigError::BadResendInterval(
                self.resend_interval_seconds,
            ));
        }
        // refused, not read as 1 (which the notifier still does for a caller that skips this
        // check): a 0 in a file is a mistake, and "no retry" is 1
        if self.max_attempts == 0 {
            return Err(NotifyConfigError::Zero("max_attempts"));
        }
        if self.queue_capacity == 0 {
            return Err(NotifyConfigError::Zero("queue_capacity"));
        }
        Ok(())
    }

    /// Timeout of one request; an unusable value (not validated) falls back to the default.
    pub(super) fn timeout(&self) -> Duration {
        Duration::try_from_secs_f64(self.timeout_seconds)
            .ok()
            .filter(|d| !d.is_zero())
            .unwrap_or(Duration::from_secs(10))
    }

    /// `None`: no periodic re-sends.
    pub(super) fn resend_interval(&self) -> Option<Duration> {
        Duration::try_from_secs_f64(self.resend_interval_seconds)
            .ok()
            .filter(|d| !d.is_zero())
    }

    /// Capacity of every queue; tokio's bounded channel needs at least 1.
    pub(super) fn capacity(&self) -> usize {
        self.queue_capacity.max(1)
    }

    /// The retry schedule before jitter: `initial_backoff_ms * 2^(retry-1)` (to `f32`
    /// precision, backon computes in `f32` seconds) capped at `max_backoff_ms`, for
    /// `max_attempts - 1` retries. The first wait is not capped by backon: callers cap every
    /// wait with [`max_backoff`](Self::max_backoff).
    pub(super) fn backoff_schedule(&self) -> ExponentialBuilder {
        let retries = usize::try_from(self.max_attempts.max(1) - 1).unwrap_or(usize::MAX);
        ExponentialBuilder::new()
            .with_min_delay(Duration::from_millis(self.initial_backoff_ms))
            .with_max_delay(self.max_backoff())
            .with_factor(2.0)
            .with_max_times(retries)
    }

    /// The longest wait between two attempts, whether from the backoff or from `Retry-After`.
    pub(super) fn max_backoff(&self) -> Duration {
        Duration::from_millis(self.max_backoff_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        // the API path given with the base: refused, naming the fix; a proxy's prefix passes
        for url in [
            "http://am:9093/api/v2/alerts",
            "http://am:9093/api/v2/alerts/",
            "http://am:9093/api/v1",
        ] {
            let bad = NotifyConfig {
                alertmanager_urls: vec![url.into()],
                ..NotifyConfig::default()
            };
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("base URL") && e.contains(url), "{e}");
        }
        let proxied = NotifyConfig {
            alertmanager_urls: vec!["https://ops.example/alertmanager/".into()],
            ..NotifyConfig::default()
        };
        assert!(proxied.validate().is_ok());
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
        // 0 attempts or a queue of 0 batches is refused, naming the key
        for (key, bad) in [
            (
                "max_attempts",
                NotifyConfig {
                    max_attempts: 0,
                    ..NotifyConfig::default()
                },
            ),
            (
                "queue_capacity",
                NotifyConfig {
                    queue_capacity: 0,
                    ..NotifyConfig::default()
                },
            ),
        ] {
            let e = bad.validate().unwrap_err();
            assert_eq!(e.key(), key);
            assert_eq!(e.to_string(), "must be at least 1, got 0");
        }
        let one = NotifyConfig {
            max_attempts: 1,
            queue_capacity: 1,
            ..NotifyConfig::default()
        };
        assert!(one.validate().is_ok());
    }

    /// Waits in whole milliseconds (backon computes in `f32` seconds).
    fn schedule_ms(c: &NotifyConfig) -> Vec<u128> {
        use backon::BackoffBuilder;
        c.backoff_schedule()
            .build()
            .map(|d| (d.as_secs_f64() * 1000.0).round() as u128)
            .collect()
    }

    #[test]
    fn backoff_doubles_and_caps() {
        let c = NotifyConfig::default();
        assert_eq!(
            schedule_ms(&c),
            vec![500, 1000, 2000, 4000, 8000],
            "5 retries"
        );
        let c = NotifyConfig {
            max_attempts: 9,
            ..NotifyConfig::default()
        };
        assert_eq!(
            schedule_ms(&c),
            vec![500, 1000, 2000, 4000, 8000, 16000, 30000, 30000]
        );
        let c = NotifyConfig {
            max_attempts: 0,
            ..NotifyConfig::default()
        };
        assert!(schedule_ms(&c).is_empty(), "0 attempts acts as 1: no retry");
        let c = NotifyConfig {
            max_attempts: 200,
            ..NotifyConfig::default()
        };
        assert_eq!(schedule_ms(&c).last(), Some(&30000), "no overflow");
        let c = NotifyConfig {
            initial_backoff_ms: u64::MAX,
            max_backoff_ms: u64::MAX,
            max_attempts: 64,
            ..NotifyConfig::default()
        };
        assert_eq!(schedule_ms(&c).len(), 63, "huge waits saturate, no panic");
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
}
