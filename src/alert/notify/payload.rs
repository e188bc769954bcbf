//! The bodies POSTed to receivers, as typed serde structs: Alertmanager's webhook payload
//! (version 4) and the array of `postableAlert`s of Alertmanager's `POST /api/v2/alerts`.
//!
//! The fields of every struct are declared in byte order of their JSON names. These bodies
//! used to be built as `serde_json::Value`s, whose objects (serde_json without
//! `preserve_order`) write their keys sorted; declaring the fields in that order keeps the
//! bytes on the wire what they were. Keep new fields in that order (a unit test pins the bytes).
//! The alerts borrow from the [`Alert`]s they describe: building a body copies no labels.

use std::collections::BTreeMap;

use serde::Serialize;
use serde_json::Value;

use crate::alert::engine::{rfc3339, Alert, AlertEvent};

/// `endsAt` of a firing alert in Alertmanager's webhook payload (Go's zero `time.Time`).
pub const ZERO_TIME: &str = "0001-01-01T00:00:00Z";

/// Labels or annotations: name -> value, in byte order of the names (as Alertmanager sorts them).
pub type LabelSet = BTreeMap<String, String>;

/// The body of a webhook notification, in Alertmanager's webhook format version "4", so that
/// receivers written for Alertmanager work unchanged.
///
/// - `status` is "firing" if any event is a firing one, else "resolved".
/// - `groupLabels` are the common `alertname` and `gate` labels (gatewatch groups by both),
///   `groupKey` is `{}:` followed by them as a label set, as Alertmanager prints it.
/// - `commonLabels` / `commonAnnotations`: pairs shared by all alerts of the batch.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct WebhookPayload<'a> {
    pub alerts: Vec<WebhookAlert<'a>>,
    pub common_annotations: LabelSet,
    pub common_labels: LabelSet,
    #[serde(rename = "externalURL")]
    pub external_url: &'a str,
    pub group_key: String,
    pub group_labels: LabelSet,
    pub receiver: &'a str,
    pub status: &'static str,
    /// Always 0: gatewatch sends every alert of a batch.
    pub truncated_alerts: u64,
    /// Always "4".
    pub version: &'static str,
}

/// One alert of a [`WebhookPayload`].
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct WebhookAlert<'a> {
    pub annotations: &'a LabelSet,
    /// RFC 3339; [`ZERO_TIME`] while firing, as Alertmanager does.
    pub ends_at: String,
    pub fingerprint: &'a str,
    /// This daemon's `external_url`.
    #[serde(rename = "generatorURL")]
    pub generator_url: &'a str,
    pub labels: &'a LabelSet,
    /// RFC 3339.
    pub starts_at: String,
    /// "firing" or "resolved".
    pub status: &'static str,
}

/// One element of the body of Alertmanager's `POST /api/v2/alerts` (`postableAlert` in its
/// OpenAPI specification). `endsAt` is present only for resolved alerts; for firing ones
/// Alertmanager sets it to now + `resolve_timeout`, hence the periodic re-sends.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct PostableAlert<'a> {
    pub annotations: &'a LabelSet,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ends_at: Option<String>,
    #[serde(rename = "generatorURL")]
    pub generator_url: &'a str,
    pub labels: &'a LabelSet,
    pub starts_at: String,
}

impl<'a> WebhookPayload<'a> {
    /// The payload of one batch of events for the receiver named `receiver`.
    pub fn new(receiver: &'a str, external_url: &'a str, events: &'a [AlertEvent]) -> Self {
        let status = if events.iter().any(AlertEvent::is_firing) {
            "firing"
        } else {
            "resolved"
        };
        let common_labels = common(events.iter().map(|e| &e.alert().labels));
        let common_annotations = common(events.iter().map(|e| &e.alert().annotations));
        let group_labels: LabelSet = common_labels
            .iter()
            .filter(|(k, _)| k.as_str() == "alertname" || k.as_str() == "gate")
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        let alerts = events
            .iter()
            .map(|e| WebhookAlert::new(e, external_url))
            .collect();
        WebhookPayload {
            alerts,
            common_annotations,
            common_labels,
            external_url,
            group_key: format!("{{}}:{}", label_set_string(&group_labels)),
            group_labels,
            receiver,
            status,
            truncated_alerts: 0,
            version: "4",
        }
    }
}

impl<'a> WebhookAlert<'a> {
    fn new(event: &'a AlertEvent, generator_url: &'a str) -> Self {
        let a = event.alert();
        let ends_at = match (event.is_firing(), a.ends_at) {
            (false, Some(t)) => rfc3339(t),
            _ => ZERO_TIME.to_string(),
        };
        WebhookAlert {
            annotations: &a.annotations,
            ends_at,
            fingerprint: &a.fingerprint,
            generator_url,
            labels: &a.labels,
            starts_at: rfc3339(a.starts_at),
            status: event.status(),
        }
    }
}

impl<'a> PostableAlert<'a> {
    /// `alert` as Alertmanager's API takes it.
    pub fn new(alert: &'a Alert, generator_url: &'a str) -> Self {
        PostableAlert {
            annotations: &alert.annotations,
            ends_at: alert.ends_at.map(rfc3339),
            generator_url,
            labels: &alert.labels,
            starts_at: rfc3339(alert.starts_at),
        }
    }
}

/// [`WebhookPayload`] as a JSON value (for inspection; the notifier serialises the struct).
pub fn webhook_payload(receiver: &str, external_url: &str, events: &[AlertEvent]) -> Value {
    to_value(&WebhookPayload::new(receiver, external_url, events))
}

/// The body of Alertmanager's `POST /api/v2/alerts` for `alerts` (an array of
/// [`PostableAlert`]s) as a JSON value (for inspection; the notifier serialises the structs).
pub fn alertmanager_payload(alerts: &[Alert], generator_url: &str) -> Value {
    let body: Vec<PostableAlert> = alerts
        .iter()
        .map(|a| PostableAlert::new(a, generator_url))
        .collect();
    to_value(&body)
}

fn to_value(body: &impl Serialize) -> Value {
    // Cannot fail: these bodies hold only strings, string-keyed maps and an integer, which
    // serde_json always represents.
    serde_json::to_value(body).expect("payload of strings and integers serialises")
}

/// `{name="value", ...}` as Alertmanager prints a label set (values quoted and escaped as JSON
/// strings).
fn label_set_string(labels: &LabelSet) -> String {
    let parts: Vec<String> = labels
        .iter()
        .map(|(k, v)| format!("{k}={}", Value::String(v.clone())))
        .collect();
    format!("{{{}}}", parts.join(", "))
}

/// Key/value pairs present with the same value in every map (empty for no maps).
fn common<'a>(mut maps: impl Iterator<Item = &'a LabelSet>) -> LabelSet {
    let Some(first) = maps.next() else {
        return BTreeMap::new();
    };
    let mut out = first.clone();
    for m in maps {
        out.retain(|k, v| m.get(k) == Some(v));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alert::{AlertEngine, AlertRules, Observation};
    use serde_json::json;
    use std::time::{Duration, SystemTime, UNIX_EPOCH};

    fn t(secs: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(1_700_000_000 + secs)
    }

    fn obs(z: f64) -> Observation<'static> {
        Observation {
            zeta0: Some(z),
            zeta0_interval: Some((z - 0.002, z + 0.002)),
            trusted: true,
            frequency_hz: Some(10.4),
            limit_cycle_amplitude: None,
            time_to_limit: None,
            equation: "ydd + c1*yd + c2*y = 0",
            trend: None,
            ambient_ratio: None,
            departure_ratio: None,
            ..Default::default()
        }
    }

    /// Firing event for g1 (first negative window at t(0), fired at t(5)) and its resolution at
    /// t(20).
    fn events() -> (AlertEvent, AlertEvent) {
        let mut e = AlertEngine::new(AlertRules::counting());
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
        let mut e = AlertEngine::new(AlertRules::counting());
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
}
