//! Alerts, metrics and the read API: alert states from identifications and staleness, the
//! Prometheus exposition and rules (checked with promtool when present), configuration files.

use crate::service_common;

use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::http::StatusCode;
use gatewatch::service::config::Config;
use serde_json::json;

use service_common::*;

#[tokio::test]
async fn alerts_follow_identifications_and_staleness() {
    let fake = Arc::new(Fake {
        zeta: vec![0.05, -0.02, -0.03, -0.03],
        ..Default::default()
    });
    let (app, state) = app_with(config(""), fake.clone());
    let mut sent = 0usize;
    for k in 0..4 {
        let n = if k == 0 { 100 } else { 50 };
        post_json(&app, uniform("g1", sent as f64 / 100.0, n)).await;
        sent += n;
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    wait_until(|| state.alert_state("g1") == Some("firing")).await;
    assert_eq!(
        metric(
            &state,
            "gatewatch_alert_state{gate=\"g1\",state=\"firing\"}"
        ),
        1.0
    );
    assert_eq!(
        metric(&state, "gatewatch_alert_state{gate=\"g1\",state=\"ok\"}"),
        0.0
    );
    assert!((metric(&state, "gatewatch_damping_ratio{gate=\"g1\"}") + 0.03).abs() < 1e-12);
    assert!(metric(&state, "gatewatch_notifications_queued_total") >= 1.0);
    // a dead sensor: stale after stale_after_seconds (default 30 s) without data
    state.tick(std::time::SystemTime::now() + Duration::from_secs(120));
    assert_eq!(state.alert_state("g1"), Some("unknown"));
    assert_eq!(
        metric(
            &state,
            "gatewatch_alert_state{gate=\"g1\",state=\"unknown\"}"
        ),
        1.0
    );

    let (s, v, _) = send(&app, "GET", "/api/v1/gates/g1", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v["gate"], "g1");
    assert_eq!(v["window"]["samples"], 100);
    assert_eq!(v["window"]["capacity"], 100);
    assert!(v["identification"]["equation"]
        .as_str()
        .unwrap()
        .contains("ydd"));
    assert_eq!(v["identification"]["coefficients"]["c2"], 1.0);
    assert!(v["identification"]["damping"]["zeta0"].as_f64().unwrap() < 0.0);
    let (s, v, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v["gates"].as_array().unwrap().len(), 1);
}

#[tokio::test]
async fn configured_gate_without_data_goes_stale() {
    let cfg = Config::from_toml("[server]\nworker_threads = 1\n[gates.silent]\n").unwrap();
    let (_app, state) = app_with(cfg, Arc::new(Fake::default()));
    // every new gate shows "unknown" anyway: the alert itself is what staleness adds
    let before = state.gate_view("silent").unwrap();
    assert!(before.alerts.is_empty(), "{:?}", before.alerts);
    state.tick(std::time::SystemTime::now() + Duration::from_secs(3600));
    let v = state.gate_view("silent").unwrap();
    assert!(
        v.alerts.iter().any(|a| a.name == "GateDataStale"),
        "GateDataStale fires for a configured gate that never sent: {:?}",
        v.alerts
    );
    assert_eq!(v.alert_state, "unknown");
}

#[tokio::test]
async fn metrics_exposition_is_valid() {
    let fake = Arc::new(Fake::default());
    let (app, state) = app_with(config(""), fake.clone());
    post_json(&app, uniform("g1", 0.0, 100)).await;
    post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 50, "values": [1]}),
    )
    .await;
    wait_until(|| fake.calls.lock().unwrap().len() == 1 && state.pool().in_flight() == 0).await;
    let (s, v, h) = send(&app, "GET", "/metrics", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK);
    assert!(h["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/plain"));
    let text = v.as_str().unwrap().to_string();
    for name in [
        "gatewatch_damping_ratio",
        "gatewatch_damping_trusted",
        "gatewatch_equivalent_damping_ratio",
        "gatewatch_frequency_hertz",
        "gatewatch_fit_nmae",
        "gatewatch_model_coefficient",
        "gatewatch_alert_state",
        "gatewatch_last_identification_timestamp_seconds",
        "gatewatch_samples_ingested_total",
        "gatewatch_window_fill_ratio",
        "gatewatch_identification_record_seconds",
        "gatewatch_samples_rejected_total",
        "gatewatch_identification_duration_seconds",
        "gatewatch_http_requests_total",
        "gatewatch_http_request_duration_seconds",
    ] {
        assert!(text.contains(&format!("# TYPE {name} ")), "missing {name}");
    }
    assert!(text.contains("route=\"/api/v1/samples\""));
    // the fake's windows are trusted
    assert!(
        text.contains("gatewatch_damping_trusted{gate=\"g1\"} 1\n"),
        "{text}"
    );
    // the first window's record is the window (1 s): the history holds no more yet
    assert!(
        text.contains("gatewatch_identification_record_seconds{gate=\"g1\"} 1\n"),
        "{text}"
    );
    promtool_check_metrics(&text);
}

/// `promtool check metrics` on an exposition, when promtool is installed (CI installs it).
fn promtool_check_metrics(text: &str) {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("metrics.txt");
    std::fs::write(&f, text).unwrap();
    promtool_passes(
        &["check", "metrics"],
        std::fs::File::open(&f).unwrap().into(),
    );
}

/// Runs `promtool ARGS` with `stdin` when promtool is installed, asserting that it succeeds.
fn promtool_passes(args: &[&str], stdin: std::process::Stdio) {
    if let Some(p) = promtool() {
        let out = std::process::Command::new(p)
            .args(args)
            .stdin(stdin)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "promtool: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// Gate `g1` after twelve identified windows whose damping falls by 0.1 points a window (a
/// window every 0.5 s of sample time), its fake analyzer holding `dampings` figures in all. The
/// windows stay 1 s long (`window_cycles = 0`: the fake's 1.5 Hz would otherwise lengthen them
/// with the history, up to 6 s), so each figure stands 0.5 s before its window's end and the
/// trend's instants are 0.5 s apart, as the windows' ends are.
async fn declining_gate(
    dampings: usize,
) -> (
    axum::Router,
    Arc<gatewatch::service::state::AppState>,
    Arc<Fake>,
) {
    declining_gate_with(dampings, None).await
}

/// [`declining_gate`] whose call number `hold_call` (from 0) is held until `Fake::release`.
async fn declining_gate_with(
    dampings: usize,
    hold_call: Option<usize>,
) -> (
    axum::Router,
    Arc<gatewatch::service::state::AppState>,
    Arc<Fake>,
) {
    let fake = Arc::new(Fake {
        zeta: (0..dampings).map(|i| 0.02 - 0.001 * i as f64).collect(),
        hold_call,
        ..Fake::default()
    });
    let (app, state) = app_with(
        config_with_defaults("", "window_cycles = 0.0"),
        fake.clone(),
    );
    // one window at a time: a window that comes due while the gate's last one is pending
    // replaces it
    post_json(&app, uniform("g1", 0.0, 100)).await;
    for i in 1..12 {
        wait_until(|| fake.calls.lock().unwrap().len() >= i && state.pool().in_flight() == 0).await;
        post_json(&app, uniform("g1", 0.5 + 0.5 * i as f64, 50)).await;
    }
    wait_until(|| fake.calls.lock().unwrap().len() >= 12 && state.pool().in_flight() == 0).await;
    (app, state, fake)
}

/// The series that only a gate with a trend has (`gatewatch_damping_ratio_trend_per_second`,
/// `gatewatch_damping_zero_crossing_seconds`, issue 8) are in the exposition promtool checks:
/// twelve windows of a damping that falls by 0.1 points a window.
#[tokio::test]
async fn metrics_exposition_with_a_declining_trend_is_valid() {
    let (app, _state, _fake) = declining_gate(12).await;
    let (s, v, _) = send(&app, "GET", "/metrics", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK);
    let text = v.as_str().unwrap().to_string();
    let value = |name: &str| -> f64 {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("{name}{{gate=\"g1\"}} ")))
            .unwrap_or_else(|| panic!("no {name}: {text}"))
            .parse()
            .unwrap()
    };
    // -0.001 a window, a window every 0.5 s
    assert!((value("gatewatch_damping_ratio_trend_per_second") + 0.002).abs() < 2e-4);
    let crossing = value("gatewatch_damping_zero_crossing_seconds");
    assert!(crossing > 0.0 && crossing < 10.0, "{crossing}");
    promtool_check_metrics(&text);
}

/// A window in flight when its gate goes stale does not bring the predicted crossing back when
/// it completes: the gate is still silent (the crossing would count down a time that passes
/// without data, frozen until the gate sends again).
#[tokio::test]
async fn a_window_finishing_after_the_gate_went_stale_predicts_nothing() {
    // the 13th identification is held until released: the gate goes stale while it runs
    let (app, state, fake) = declining_gate_with(13, Some(12)).await;
    let crossing = "gatewatch_damping_zero_crossing_seconds{gate=\"g1\"} ";
    let exposition = || async {
        let (_, v, _) = send(&app, "GET", "/metrics", Body::empty(), None).await;
        v.as_str().unwrap().to_string()
    };
    assert!(exposition().await.contains(crossing));
    post_json(&app, uniform("g1", 6.5, 50)).await;
    wait_until(|| fake.calls.lock().unwrap().len() >= 13).await;
    assert_eq!(state.pool().in_flight(), 1, "the 13th window runs");
    state.tick(std::time::SystemTime::now() + Duration::from_secs(120));
    let stale = exposition().await;
    assert!(
        stale.contains("gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"g1\"} 1"),
        "{stale}"
    );
    assert!(!stale.contains(crossing), "{stale}");
    fake.release();
    wait_until(|| state.pool().in_flight() == 0).await;
    // the window was identified (its damping is on the gauge) and predicts nothing
    let after = exposition().await;
    assert!(
        after.contains("gatewatch_damping_ratio{gate=\"g1\"} 0.008"),
        "{after}"
    );
    assert!(!after.contains(crossing), "{after}");
    let (_, v, _) = send(&app, "GET", "/api/v1/gates/g1", Body::empty(), None).await;
    assert!(v["trend"]["crossing_seconds"].is_null(), "{v}");
}

/// A gate that stops sending predicts nothing: once `GateDataStale` fires, the zero crossing
/// leaves the exposition (it stayed frozen at "2m 14s" for as long as the gate was silent);
/// the slope, a figure of the windows already identified, stays; the next identification sets
/// the crossing again.
#[tokio::test]
async fn a_stale_gate_loses_its_predicted_crossing_until_its_next_window() {
    // a 13th damping for the window after the silence
    let (app, state, fake) = declining_gate(13).await;
    let exposition = || async {
        let (s, v, _) = send(&app, "GET", "/metrics", Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK);
        v.as_str().unwrap().to_string()
    };
    let has = |text: &str, name: &str| text.contains(&format!("{name}{{gate=\"g1\"}} "));
    let crossing = "gatewatch_damping_zero_crossing_seconds";
    let slope = "gatewatch_damping_ratio_trend_per_second";
    let before = exposition().await;
    assert!(has(&before, crossing) && has(&before, slope), "{before}");
    let view = || async {
        let (_, v, _) = send(&app, "GET", "/api/v1/gates/g1", Body::empty(), None).await;
        v["trend"].clone()
    };
    assert!(
        view().await["crossing_seconds"].is_number(),
        "{}",
        view().await
    );
    // silent past stale_after_seconds (default 30 s)
    state.tick(std::time::SystemTime::now() + Duration::from_secs(120));
    let stale = exposition().await;
    assert!(
        stale.contains("gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"g1\"} 1"),
        "{stale}"
    );
    assert!(!has(&stale, crossing), "{stale}");
    assert!(has(&stale, slope), "{stale}");
    // the gate's view says the same: the slope stays, the crossing is gone
    let trend = view().await;
    assert!(trend["crossing_seconds"].is_null(), "{trend}");
    assert!(trend["crossing_seconds_confident"].is_null(), "{trend}");
    assert!(trend["slope_per_second"].is_number(), "{trend}");
    promtool_check_metrics(&stale);
    // another tick while still stale fires nothing new and brings nothing back (before the
    // unknown gate's expiry, 600 s)
    state.tick(std::time::SystemTime::now() + Duration::from_secs(300));
    assert!(!has(&exposition().await, crossing));
    // the gate sends again: its next window predicts again
    post_json(&app, uniform("g1", 6.5, 50)).await;
    wait_until(|| fake.calls.lock().unwrap().len() >= 13 && state.pool().in_flight() == 0).await;
    let after = exposition().await;
    assert!(has(&after, crossing), "{after}");
    assert!(view().await["crossing_seconds"].is_number());
    assert!(
        after.contains("gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"g1\"} 0"),
        "{after}"
    );
    promtool_check_metrics(&after);
}

/// The gate list says whether each `zeta0` is trusted, as the gate's view does
/// (`identification.damping.trusted`): an untrusted window's `zeta0` was listed alone, read as
/// the gate's damping.
#[tokio::test]
async fn the_gate_list_says_whether_zeta0_is_trusted() {
    for untrusted in [false, true] {
        let fake = Arc::new(Fake {
            zeta: vec![-0.0849],
            untrusted,
            ..Fake::default()
        });
        let (app, state) = app_with(config(""), fake.clone());
        // half a window: no identification yet, so null, as zeta0
        post_json(&app, uniform("tiny", 0.0, 50)).await;
        let (_, v, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
        let g = &v["gates"][0];
        assert!(g["trusted"].is_null() && g["zeta0"].is_null(), "{v}");
        post_json(&app, uniform("tiny", 0.5, 50)).await;
        wait_until(|| {
            state
                .gate_view("tiny")
                .is_some_and(|v| v.identification.is_some())
        })
        .await;
        let (s, v, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK);
        let g = &v["gates"][0];
        assert_eq!(g["gate"], "tiny");
        assert_eq!(g["zeta0"], -0.0849);
        assert_eq!(g["trusted"], json!(!untrusted), "{v}");
        let (_, view, _) = send(&app, "GET", "/api/v1/gates/tiny", Body::empty(), None).await;
        assert_eq!(g["trusted"], view["identification"]["damping"]["trusted"]);
    }
}

#[test]
fn prometheus_rules_are_valid() {
    let rules = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/prometheus/gatewatch-rules.yml"
    );
    assert!(std::path::Path::new(rules).is_file());
    promtool_passes(&["check", "rules", rules], std::process::Stdio::null());
}

/// The rules' unit tests (deploy/prometheus/gatewatch-rules.test.yml): each rule fires after its
/// `for`, keeps firing for its `keep_firing_for`, and its annotations read as expected with and
/// without the series their templates query.
#[test]
fn prometheus_rules_pass_their_unit_tests() {
    // its `rule_files: [gatewatch-rules.yml]` is resolved next to it by promtool
    let tests = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/prometheus/gatewatch-rules.test.yml"
    );
    assert!(std::path::Path::new(tests).is_file());
    promtool_passes(&["test", "rules", tests], std::process::Stdio::null());
}

#[test]
fn check_config_files() {
    use gatewatch::service::cli::{check_config, CheckConfigArgs};
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/config/gatewatch.toml");
    assert_eq!(
        check_config(CheckConfigArgs {
            file: example.into()
        }),
        std::process::ExitCode::SUCCESS
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[gates.g1]\nrate_hz = -5.0\n").unwrap();
    assert_eq!(
        check_config(CheckConfigArgs { file: bad.clone() }),
        std::process::ExitCode::from(2)
    );
    assert_eq!(
        Config::from_file(&bad).unwrap_err().message,
        "gates.g1.rate_hz: must be > 0, line 2"
    );
    assert_eq!(
        check_config(CheckConfigArgs {
            file: dir.path().join("missing.toml")
        }),
        std::process::ExitCode::from(2)
    );
}
