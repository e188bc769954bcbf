//! Daemon tests: malformed requests (docs/api.md table), worker pool, cadence, gaps, alerts,
//! metrics, TCP listener, shutdown, simulate client. Every wait is bounded by a timeout.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use axum::Router;
use gatewatch::analysis::{AnalysisError, DampingReport, Verdict, WindowAnalysis, WindowInput};
use gatewatch::service::config::Config;
use gatewatch::service::server::{build_app, run_with_analyzer, Listeners};
use gatewatch::service::state::AppState;
use gatewatch::service::worker::{Job, Submitted, WindowAnalyzer, WorkerPool};
use serde_json::{json, Value};
use tower::ServiceExt;

const TOKEN: &str = "test-token-0123456789";

/// What the fake analyzer saw.
#[derive(Debug, Clone)]
struct Call {
    gate: String,
    t0: f64,
    len: usize,
    warm: Option<Vec<f64>>,
    seed: u64,
}

/// Scripted analyzer: zeta0 from a schedule, optional sleep, optional panic on a call number.
#[derive(Default)]
struct Fake {
    zeta: Vec<f64>,
    sleep: Duration,
    panic_on: Option<usize>,
    calls: Mutex<Vec<Call>>,
    n: AtomicUsize,
}

impl WindowAnalyzer for Fake {
    fn analyze(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        let n = self.n.fetch_add(1, Ordering::SeqCst);
        self.calls.lock().unwrap().push(Call {
            gate: gate.into(),
            t0: input.t0,
            len: input.values.len(),
            warm: warm.map(<[f64]>::to_vec),
            seed,
        });
        std::thread::sleep(self.sleep);
        if self.panic_on == Some(n) {
            panic!("scripted numerical bug");
        }
        let zeta0 = self
            .zeta
            .get(n)
            .or(self.zeta.last())
            .copied()
            .unwrap_or(0.05);
        Ok(WindowAnalysis {
            equation: format!("ydd + {zeta0}*yd + y = 0"),
            coefficients: vec![("c1".into(), zeta0), ("c2".into(), 1.0)],
            damping: DampingReport {
                zeta0: Some(zeta0),
                zeta0_interval: None,
                zeta_eq: Some(zeta0),
                energy_per_cycle: None,
                limit_cycle_amplitude: None,
                time_to_limit: None,
                frequency_hz: Some(1.5),
                growth_rate: None,
                growth_rate_stderr: None,
                zeta0_source: None,
                ambient_zeta: None,
                model_frequency_hz: None,
                amplitude: None,
                agrees: true,
                fit_nmae: 0.01,
                trusted: true,
                verdict: if zeta0 < 0.0 {
                    Verdict::SelfExcited
                } else {
                    Verdict::Damped
                },
            },
            evaluations: 1,
            seconds: 0.0,
            warm_start: vec![n as f64],
        })
    }
}

fn config(extra: &str) -> Config {
    Config::from_toml(&format!(
        "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\n{extra}\n\
         [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n"
    ))
    .unwrap()
}

fn app_with(cfg: Config, fake: Arc<Fake>) -> (Router, Arc<AppState>) {
    build_app(cfg, fake).unwrap()
}

fn make_app(extra: &str) -> (Router, Arc<AppState>) {
    app_with(config(extra), Arc::new(Fake::default()))
}

async fn send(
    app: &Router,
    method: &str,
    uri: &str,
    body: impl Into<Body>,
    token: Option<&str>,
) -> (StatusCode, Value, axum::http::HeaderMap) {
    let mut req = Request::builder().method(method).uri(uri);
    if let Some(t) = token {
        req = req.header("authorization", format!("Bearer {t}"));
    }
    let resp = tokio::time::timeout(
        Duration::from_secs(10),
        app.clone().oneshot(req.body(body.into()).unwrap()),
    )
    .await
    .expect("request timed out")
    .unwrap();
    let status = resp.status();
    let headers = resp.headers().clone();
    let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    let v = serde_json::from_slice(&bytes)
        .unwrap_or(Value::String(String::from_utf8_lossy(&bytes).into()));
    (status, v, headers)
}

async fn post_json(app: &Router, body: Value) -> (StatusCode, Value) {
    let (s, v, _) = send(app, "POST", "/api/v1/samples", body.to_string(), None).await;
    (s, v)
}

fn uniform(gate: &str, start: f64, n: usize) -> Value {
    let values: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).sin()).collect();
    json!({"gate": gate, "start": start, "rate_hz": 100.0, "values": values})
}

async fn wait_until(mut f: impl FnMut() -> bool) {
    tokio::time::timeout(Duration::from_secs(10), async {
        while !f() {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("condition not reached within 10 s");
}

fn metric(state: &AppState, prefix: &str) -> f64 {
    state
        .metrics
        .render()
        .lines()
        .filter(|l| l.starts_with(prefix))
        .map(|l| l.rsplit(' ').next().unwrap().parse::<f64>().unwrap())
        .sum()
}

// ---------------------------------------------------------------- malformed requests (docs/api.md)

#[tokio::test]
async fn accepted_uniform_and_pairs_and_rfc3339() {
    let (app, state) = make_app("");
    assert_eq!(
        post_json(&app, uniform("g1", 1000.0, 10)).await.0,
        StatusCode::NO_CONTENT
    );
    let pairs = json!({"gate": "g1", "samples": [[1000.10, 1.0], [1000.11, 2.0], [1000.12, 3.0]]});
    assert_eq!(post_json(&app, pairs).await.0, StatusCode::NO_CONTENT);
    let rfc =
        json!({"gate": "g2", "start": "2023-11-14T22:13:20.5Z", "rate_hz": 100, "values": [1, 2]});
    assert_eq!(post_json(&app, rfc).await.0, StatusCode::NO_CONTENT);
    let arr = json!([uniform("g3", 1.0, 3), uniform("g4", 1.0, 3)]);
    assert_eq!(post_json(&app, arr).await.0, StatusCode::NO_CONTENT);
    assert_eq!(state.gate_view("g1").unwrap().window.samples, 13);
    let t = state
        .gate_view("g2")
        .unwrap()
        .window
        .last_sample_time
        .unwrap();
    assert!((t - 1_700_000_000.51).abs() < 1e-6, "{t}");
}

#[tokio::test]
async fn bad_json_names_line_and_column() {
    let (app, _) = make_app("");
    let (s, v, _) = send(
        &app,
        "POST",
        "/api/v1/samples",
        "{\"gate\": \"g1\",\n \"values\": [1,]}",
        None,
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["line"], 2);
    assert!(v["error"].as_str().unwrap().contains("invalid JSON"));
}

#[tokio::test]
async fn json_nan_literal_is_bad_json() {
    let (app, _) = make_app("");
    let (s, v, _) = send(
        &app,
        "POST",
        "/api/v1/samples",
        r#"{"gate":"g1","start":0,"rate_hz":100,"values":[1, NaN]}"#,
        None,
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["line"], 1);
}

#[tokio::test]
async fn wrong_types_name_field_and_index() {
    let (app, _) = make_app("");
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 100, "values": [1, "x", 3]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("values"), Some(1))
    );
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 100, "values": [1, null]}),
    )
    .await;
    assert_eq!((s, v["index"].as_u64()), (StatusCode::BAD_REQUEST, Some(1)));
    let (s, v) = post_json(
        &app,
        json!({"gate": 7, "start": 0, "rate_hz": 100, "values": [1]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("gate"))
    );
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": "yesterday", "rate_hz": 100, "values": [1]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("start"))
    );
    let (s, v) = post_json(&app, json!({"gate": "g1", "samples": [[0, 1], [1]]})).await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("samples"), Some(1))
    );
    let (s, _) = post_json(&app, json!("just a string")).await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    let (s, v) = post_json(&app, json!([uniform("g1", 0.0, 2), 5])).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("[1]"))
    );
}

#[tokio::test]
async fn missing_and_unknown_fields() {
    let (app, _) = make_app("");
    let (s, v) = post_json(&app, json!({"start": 0, "rate_hz": 100, "values": [1]})).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("gate"))
    );
    let (s, v) = post_json(&app, json!({"gate": "g1", "rate_hz": 100, "values": [1]})).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("start"))
    );
    let (s, v) = post_json(&app, json!({"gate": "g1", "start": 0, "values": [1]})).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("rate_hz"))
    );
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 100, "values": [1], "colour": 1}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("colour"))
    );
    let (s, v) = post_json(&app, json!({"gate": "g1"})).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("values"))
    );
    let (s, v) = post_json(
        &app,
        json!({"gate": "bad gate/../x", "start": 0, "rate_hz": 100, "values": [1]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("gate"))
    );
}

#[tokio::test]
async fn empty_values_and_empty_body() {
    let (app, _) = make_app("");
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 100, "values": []}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("values"))
    );
    let (s, _) = post_json(&app, json!([])).await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    let (s, _, _) = send(&app, "POST", "/api/v1/samples", "", None).await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
}

#[tokio::test]
async fn wrong_rate_names_the_field() {
    let (app, state) = make_app("");
    let (s, v) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 102, "values": [1, 2]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("rate_hz"))
    );
    // within 1 %: accepted
    let (s, _) = post_json(
        &app,
        json!({"gate": "g1", "start": 0, "rate_hz": 100.5, "values": [1, 2]}),
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    // implied by pair timestamps (50 Hz)
    let (s, v) = post_json(
        &app,
        json!({"gate": "g2", "samples": [[0.0, 1], [0.02, 2], [0.04, 3]]}),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("samples"))
    );
    let (s, v) = post_json(
        &app,
        json!([uniform("g3", 0.0, 2), {"gate": "g3", "start": 5, "rate_hz": 10, "values": [1]}]),
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("[1].rate_hz"))
    );
    assert!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"rate_mismatch\"}"
        ) >= 3.0
    );
}

#[tokio::test]
async fn batch_is_all_or_nothing() {
    let (app, state) = make_app("");
    let bad = json!([uniform("g1", 0.0, 5), {"gate": "g2", "start": 0, "rate_hz": 100, "values": [1, "x"]}]);
    let (s, v) = post_json(&app, bad).await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("[1].values"), Some(1))
    );
    assert!(
        state.gate_view("g1").is_none(),
        "nothing of a rejected batch is applied"
    );
    let lp = "m,gate=g1 force=1 1000000000\nm,gate=g2 force=NaN 1010000000\n";
    let (s, v, _) = send(&app, "POST", "/api/v2/write", lp, None).await;
    assert_eq!(
        (s, v["line"].as_u64(), v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some(2), Some("force"))
    );
    assert!(state.gate_view("g1").is_none());
    assert!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"non_finite\"}"
        ) >= 2.0
    );
}

#[tokio::test]
async fn huge_body_is_413() {
    let (app, _) = make_app("body_limit_bytes = 2048");
    let big = uniform("g1", 0.0, 2000).to_string();
    assert!(big.len() > 2048);
    let (s, v, _) = send(&app, "POST", "/api/v1/samples", big.clone(), None).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE);
    assert!(v["error"].as_str().unwrap().contains("2048"));
    let (s, _, _) = send(
        &app,
        "POST",
        "/api/v2/write",
        "m,gate=g1 force=1\n".repeat(200),
        None,
    )
    .await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE);
    // still serving
    assert_eq!(
        post_json(&app, uniform("g1", 0.0, 5)).await.0,
        StatusCode::NO_CONTENT
    );
}

#[tokio::test]
async fn unknown_gate_refused_when_configured() {
    let cfg = Config::from_toml(
        "[server]\nworker_threads = 1\naccept_unknown_gates = false\n[defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\n[gates.known]\n",
    )
    .unwrap();
    let (app, _) = app_with(cfg, Arc::new(Fake::default()));
    let (s, v) = post_json(&app, uniform("stranger", 0.0, 3)).await;
    assert_eq!(s, StatusCode::NOT_FOUND);
    assert!(v["error"].as_str().unwrap().contains("stranger"));
    assert_eq!(
        post_json(&app, uniform("known", 0.0, 3)).await.0,
        StatusCode::NO_CONTENT
    );
    let (s, _, _) = send(&app, "GET", "/api/v1/gates/stranger", Body::empty(), None).await;
    assert_eq!(s, StatusCode::NOT_FOUND);
}

#[tokio::test]
async fn max_gates_is_enforced() {
    let (app, _) = make_app("max_gates = 2");
    assert_eq!(
        post_json(&app, uniform("a", 0.0, 3)).await.0,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        post_json(&app, uniform("b", 0.0, 3)).await.0,
        StatusCode::NO_CONTENT
    );
    let (s, v) = post_json(&app, uniform("c", 0.0, 3)).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("gate"))
    );
    assert_eq!(
        post_json(&app, uniform("a", 1.0, 3)).await.0,
        StatusCode::NO_CONTENT
    );
}

#[tokio::test]
async fn bad_line_protocol_names_line_and_column() {
    let (app, _) = make_app("");
    let (s, v, _) = send(
        &app,
        "POST",
        "/api/v2/write",
        "m,gate=g1 force=1 1\nm,gate=g1 force=1x 2\n",
        None,
    )
    .await;
    assert_eq!(
        (s, v["line"].as_u64(), v["column"].as_u64()),
        (StatusCode::BAD_REQUEST, Some(2), Some(17))
    );
    let (s, v, _) = send(&app, "POST", "/write", "m,site=a force=1 1\n", None).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("gate"))
    );
    let (s, v, _) = send(&app, "POST", "/write", "m,gate=a temp=1 1\n", None).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("force"))
    );
    let (s, v, _) = send(&app, "POST", "/write", "m,gate=a force=\"high\" 1\n", None).await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("force"))
    );
    let (s, v, _) = send(
        &app,
        "POST",
        "/api/v2/write?precision=hours",
        "m,gate=a force=1 1\n",
        None,
    )
    .await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("precision"))
    );
    let (s, _, _) = send(
        &app,
        "POST",
        "/api/v2/write",
        vec![0xffu8, 0xfe, b'\n'],
        None,
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    let (s, _, _) = send(&app, "POST", "/api/v2/write", "\n# only a comment\n", None).await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
}

#[tokio::test]
async fn line_protocol_precisions() {
    let (app, state) = make_app("");
    for (p, ts) in [
        ("s", "1000"),
        ("ms", "1000010"),
        ("us", "1000020000"),
        ("ns", "1000030000000"),
    ] {
        let (s, _, _) = send(
            &app,
            "POST",
            &format!("/api/v2/write?precision={p}&org=x&bucket=y"),
            format!("m,gate=g1 value=1i {ts}\n"),
            None,
        )
        .await;
        assert_eq!(s, StatusCode::NO_CONTENT, "precision {p}");
    }
    let v = state.gate_view("g1").unwrap();
    assert_eq!(v.window.samples, 4);
    assert!((v.window.last_sample_time.unwrap() - 1000.03).abs() < 1e-6);
    // default precision ns on /write
    let (s, _, _) = send(
        &app,
        "POST",
        "/write",
        "m,gate=g2 force=2 1000000000000\n",
        None,
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    assert!(
        (state
            .gate_view("g2")
            .unwrap()
            .window
            .last_sample_time
            .unwrap()
            - 1000.0)
            .abs()
            < 1e-6
    );
}

#[tokio::test]
async fn bearer_tokens() {
    let (app, _) = make_app(&format!("auth_tokens = [\"{TOKEN}\"]"));
    let body = uniform("g1", 0.0, 3).to_string();
    let (s, _, h) = send(&app, "POST", "/api/v1/samples", body.clone(), None).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    assert_eq!(h["www-authenticate"], "Bearer");
    let (s, _, _) = send(
        &app,
        "POST",
        "/api/v1/samples",
        body.clone(),
        Some("wrong-token-0123456789"),
    )
    .await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let (s, _, _) = send(
        &app,
        "POST",
        "/api/v2/write",
        "m,gate=g1 force=1\n",
        Some("x"),
    )
    .await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let (s, _, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let (s, _, _) = send(&app, "POST", "/api/v1/samples", body, Some(TOKEN)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    for open in ["/healthz", "/metrics"] {
        let (s, _, _) = send(&app, "GET", open, Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK, "{open}");
    }
    // /readyz is open too (503 here: no listener in a oneshot test)
    let (s, _, _) = send(&app, "GET", "/readyz", Body::empty(), None).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE);
    let (app2, _) = make_app(&format!("auth_tokens = [\"{TOKEN}\"]\nmetrics_auth = true"));
    let app = app2;
    let (s, _, _) = send(&app, "GET", "/metrics", Body::empty(), None).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
}

#[tokio::test]
async fn unknown_route_and_method() {
    let (app, state) = make_app("");
    let (s, _, _) = send(&app, "GET", "/nope/../etc/passwd", Body::empty(), None).await;
    assert_eq!(s, StatusCode::NOT_FOUND);
    let (s, _, _) = send(&app, "GET", "/api/v1/samples", Body::empty(), None).await;
    assert_eq!(s, StatusCode::METHOD_NOT_ALLOWED);
    let text = state.metrics.render();
    assert!(text.contains("route=\"unmatched\""), "{text}");
    assert!(!text.contains("passwd"));
}

#[tokio::test]
async fn duplicates_and_out_of_order_are_counted() {
    let (app, state) = make_app("");
    let pairs = json!({"gate": "g1", "samples": [[10.00, 1], [10.01, 2], [10.01, 2], [10.02, 3], [10.005, 9], [10.03, 4]]});
    assert_eq!(post_json(&app, pairs).await.0, StatusCode::NO_CONTENT);
    assert_eq!(state.gate_view("g1").unwrap().window.samples, 4);
    // a replayed (older) chunk is dropped
    assert_eq!(
        post_json(&app, uniform("g1", 9.0, 5)).await.0,
        StatusCode::NO_CONTENT
    );
    assert_eq!(state.gate_view("g1").unwrap().window.samples, 4);
    assert_eq!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"duplicate\"}"
        ),
        1.0
    );
    assert_eq!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"out_of_order\"}"
        ),
        6.0
    );
}

#[tokio::test]
async fn gaps_split_windows_over_the_api() {
    let fake = Arc::new(Fake::default());
    let (app, state) = app_with(config(""), fake.clone());
    // 0.8 s, a 0.05 s gap, then 1.2 s: only the stretch after the gap (first full at 1 s) counts
    assert_eq!(
        post_json(&app, uniform("g1", 100.0, 80)).await.0,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        post_json(&app, uniform("g1", 100.85, 120)).await.0,
        StatusCode::NO_CONTENT
    );
    wait_until(|| {
        state.pool().pending() == 0
            && state.pool().in_flight() == 0
            && !fake.calls.lock().unwrap().is_empty()
    })
    .await;
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(calls.len(), 1);
    assert!(
        calls[0].t0 >= 100.85 - 1e-9,
        "window starts after the gap: {}",
        calls[0].t0
    );
    assert_eq!(calls[0].len, 100);
    assert_eq!(
        metric(&state, "gatewatch_window_gaps_total{gate=\"g1\"}"),
        1.0
    );
}

// ---------------------------------------------------------------- worker pool

#[tokio::test]
async fn slow_workers_replace_pending_jobs_instead_of_queueing() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(200),
        ..Default::default()
    });
    let done = Arc::new(AtomicUsize::new(0));
    let d = done.clone();
    let pool = WorkerPool::start(
        1,
        8,
        fake.clone(),
        Arc::new(move |_: &Job, _, _| {
            d.fetch_add(1, Ordering::SeqCst);
        }),
    )
    .unwrap();
    let job = |i: u64| Job {
        gate: "g1".into(),
        t0: i as f64,
        rate_hz: 100.0,
        values: vec![0.0; 10],
        end_index: i,
    };
    let mut replaced = 0;
    let mut queued = 0;
    for i in 0..20 {
        match pool.submit(job(i)) {
            Submitted::Replaced => replaced += 1,
            Submitted::Queued => queued += 1,
            other => panic!("{other:?}"),
        }
        assert!(
            pool.pending() <= 1,
            "never more than one pending job per gate"
        );
    }
    assert!(
        replaced > 0,
        "a slow worker makes newer windows replace pending ones"
    );
    assert_eq!(replaced + queued, 20);
    wait_until(|| done.load(Ordering::SeqCst) == queued).await;
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(calls.len(), queued);
    // the newest window is the one analysed last
    assert_eq!(calls.last().unwrap().t0, 19.0);
    let (abandoned, clean) = pool.shutdown(Duration::from_secs(5)).await;
    assert_eq!((abandoned, clean), (0, true));
    assert_eq!(pool.submit(job(99)), Submitted::Closed);
}

#[tokio::test]
async fn queue_bound_and_one_in_flight_per_gate() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(100),
        ..Default::default()
    });
    let pool = WorkerPool::start(2, 2, fake.clone(), Arc::new(|_: &Job, _, _| {})).unwrap();
    let job = |g: &str| Job {
        gate: g.into(),
        t0: 0.0,
        rate_hz: 100.0,
        values: vec![0.0; 4],
        end_index: 1,
    };
    let mut full = 0;
    for g in ["a", "b", "c", "d", "e", "f"] {
        if pool.submit(job(g)) == Submitted::QueueFull {
            full += 1;
        }
        assert!(pool.pending() <= 2);
    }
    assert!(full >= 1);
    pool.shutdown(Duration::from_secs(5)).await;
}

#[tokio::test]
async fn warm_start_seed_and_panics() {
    let fake = Arc::new(Fake {
        panic_on: Some(1),
        ..Default::default()
    });
    let (app, state) = app_with(config(""), fake.clone());
    for k in 0..4 {
        // each post makes one window due (1 s window, 0.5 s cadence)
        let n = if k == 0 { 100 } else { 50 };
        let start = if k == 0 {
            0.0
        } else {
            1.0 + 0.5 * (k - 1) as f64
        };
        assert_eq!(
            post_json(&app, uniform("g1", start, n)).await.0,
            StatusCode::NO_CONTENT
        );
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    let calls = fake.calls.lock().unwrap().clone();
    assert_eq!(calls[0].warm, None);
    assert_eq!(calls[1].warm, Some(vec![0.0]));
    // call 1 panicked: call 2 still warm-starts from the last success
    assert_eq!(calls[2].warm, Some(vec![0.0]));
    assert_eq!(calls[3].warm, Some(vec![2.0]));
    assert_eq!(
        calls[0].seed,
        gatewatch::service::worker::window_seed("g1", 100)
    );
    assert_ne!(calls[0].seed, calls[1].seed);
    assert!(calls.iter().all(|c| c.gate == "g1"));
    assert_eq!(
        metric(
            &state,
            "gatewatch_identification_failures_total{reason=\"panic\"}"
        ),
        1.0
    );
    // still serving
    assert_eq!(
        send(&app, "GET", "/healthz", Body::empty(), None).await.0,
        StatusCode::OK
    );
}

#[tokio::test]
async fn cadence_is_in_sample_time_whatever_the_replay_speed() {
    // the same stream posted in 0.1 s chunks and in 0.05 s chunks, waiting for each job:
    // identical windows and seeds
    async fn windows(chunk: usize) -> Vec<(u64, usize, i64)> {
        let fake = Arc::new(Fake::default());
        let (app, state) = app_with(config(""), fake.clone());
        let mut sent = 0;
        while sent < 400 {
            let (s, _) = post_json(&app, uniform("g1", 50.0 + sent as f64 / 100.0, chunk)).await;
            assert_eq!(s, StatusCode::NO_CONTENT);
            sent += chunk;
            wait_until(|| state.pool().pending() == 0 && state.pool().in_flight() == 0).await;
        }
        let calls = fake.calls.lock().unwrap().clone();
        calls
            .iter()
            .map(|c| (c.seed, c.len, (c.t0 * 1000.0).round() as i64))
            .collect()
    }
    let a = windows(10).await;
    let b = windows(5).await;
    assert_eq!(a.len(), 7, "full at 1 s, then every 0.5 s until 4 s");
    assert_eq!(a, b);
}

// ---------------------------------------------------------------- alerts, metrics, API

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
    assert!(metric(&state, "gatewatch_notifications_total") >= 1.0);
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
    state.tick(std::time::SystemTime::now() + Duration::from_secs(3600));
    assert_eq!(state.alert_state("silent"), Some("unknown"));
}

fn promtool() -> Option<std::path::PathBuf> {
    let found = std::env::var_os("PATH").and_then(|p| {
        std::env::split_paths(&p)
            .map(|d| d.join("promtool"))
            .find(|f| f.is_file())
    });
    if found.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "promtool is required in CI (Debian package `prometheus`)"
        );
        eprintln!("SKIP: promtool not on PATH");
    }
    found
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
        "gatewatch_equivalent_damping_ratio",
        "gatewatch_frequency_hertz",
        "gatewatch_fit_nmae",
        "gatewatch_model_coefficient",
        "gatewatch_alert_state",
        "gatewatch_last_identification_timestamp_seconds",
        "gatewatch_samples_ingested_total",
        "gatewatch_window_fill_ratio",
        "gatewatch_samples_rejected_total",
        "gatewatch_identification_duration_seconds",
        "gatewatch_http_requests_total",
        "gatewatch_http_request_duration_seconds",
    ] {
        assert!(text.contains(&format!("# TYPE {name} ")), "missing {name}");
    }
    assert!(text.contains("route=\"/api/v1/samples\""));
    if let Some(p) = promtool() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("metrics.txt");
        std::fs::write(&f, &text).unwrap();
        let out = std::process::Command::new(p)
            .arg("check")
            .arg("metrics")
            .stdin(std::fs::File::open(&f).unwrap())
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

#[test]
fn prometheus_rules_are_valid() {
    let rules = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/prometheus/gatewatch-rules.yml"
    );
    assert!(std::path::Path::new(rules).is_file());
    if let Some(p) = promtool() {
        let out = std::process::Command::new(p)
            .args(["check", "rules", rules])
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
        "gates.g1.rate_hz: must be > 0"
    );
    assert_eq!(
        check_config(CheckConfigArgs {
            file: dir.path().join("missing.toml")
        }),
        std::process::ExitCode::from(2)
    );
}

// ---------------------------------------------------------------- real server: TCP, overload, shutdown, simulate

struct Running {
    http: std::net::SocketAddr,
    tcp: std::net::SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
}

async fn start(extra: &str, fake: Arc<Fake>) -> Running {
    gatewatch::service::cli::ensure_crypto_provider();
    let cfg = config(&format!(
        "tcp_listen = \"127.0.0.1:0\"\nshutdown_grace_seconds = 2.0\n{extra}"
    ));
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let tcp = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let (ha, ta) = (http.local_addr().unwrap(), tcp.local_addr().unwrap());
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(run_with_analyzer(
        cfg,
        Listeners {
            http,
            tcp: Some(tcp),
        },
        fake,
        async move {
            let _ = rx.await;
        },
    ));
    Running {
        http: ha,
        tcp: ta,
        stop,
        task,
    }
}

async fn get(addr: std::net::SocketAddr, path: &str) -> (u16, String) {
    let r = reqwest::get(format!("http://{addr}{path}")).await.unwrap();
    (r.status().as_u16(), r.text().await.unwrap())
}

async fn stop(r: Running) {
    let _ = r.stop.send(());
    tokio::time::timeout(Duration::from_secs(15), r.task)
        .await
        .expect("shutdown within the deadline")
        .unwrap()
        .unwrap();
}

#[tokio::test]
async fn tcp_listener_keeps_the_connection_after_bad_lines() {
    use tokio::io::AsyncWriteExt;
    let r = start("", Arc::new(Fake::default())).await;
    let mut s = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    s.write_all(b"m,gate=t1 force=1 1000000000000\nthis is not line protocol\nm,gate=t1 force=NaN 1000010000000\n").await.unwrap();
    s.write_all(b"m,gate=t1 force=2 1000020000000\r\n")
        .await
        .unwrap();
    s.write_all(&vec![b'x'; 70_000]).await.unwrap();
    s.write_all(b"\nm,gate=t1 force=3 1000030000000\n")
        .await
        .unwrap();
    s.flush().await.unwrap();
    let addr = r.http;
    tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            let (_, text) = get(addr, "/api/v1/gates/t1").await;
            if text.contains("\"samples_total\":3") {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("three good lines ingested");
    let (_, m) = get(addr, "/metrics").await;
    assert!(
        m.contains("gatewatch_samples_rejected_total{reason=\"bad_line\"} 2"),
        "{m}"
    );
    assert!(m.contains("gatewatch_samples_rejected_total{reason=\"non_finite\"} 1"));
    drop(s);
    stop(r).await;
}

#[tokio::test]
async fn tcp_connection_limit() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let r = start("max_tcp_connections = 1", Arc::new(Fake::default())).await;
    let mut first = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    first
        .write_all(b"m,gate=t2 force=1 1000000000000\n")
        .await
        .unwrap();
    let addr = r.http;
    tokio::time::timeout(Duration::from_secs(10), async {
        while !get(addr, "/api/v1/gates/t2")
            .await
            .1
            .contains("samples_total\":1")
        {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .unwrap();
    let mut second = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    let mut buf = [0u8; 1];
    let n = tokio::time::timeout(Duration::from_secs(10), second.read(&mut buf))
        .await
        .unwrap()
        .unwrap_or(0);
    assert_eq!(n, 0, "the second connection is closed");
    let (_, m) = get(addr, "/metrics").await;
    assert!(m.contains("gatewatch_tcp_connections_rejected_total 1"));
    drop(first);
    stop(r).await;
}

#[tokio::test]
async fn overload_is_503_with_retry_after() {
    use tokio::io::AsyncWriteExt;
    let r = start("max_concurrent_requests = 1", Arc::new(Fake::default())).await;
    // hold the only slot: a request whose body never completes
    let mut hold = tokio::net::TcpStream::connect(r.http).await.unwrap();
    hold.write_all(b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\ncontent-length: 1000\r\n\r\n{\"gate\"").await.unwrap();
    let addr = r.http;
    let resp = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            let resp = reqwest::get(format!("http://{addr}/healthz"))
                .await
                .unwrap();
            if resp.status() == 503 {
                break resp;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("503 while the slot is held");
    assert_eq!(resp.headers()["retry-after"], "1");
    drop(hold);
    tokio::time::timeout(Duration::from_secs(10), async {
        while get(addr, "/healthz").await.0 != 200 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("serving again");
    // a request that never completes does not hold the shutdown beyond the grace period
    let mut hold = tokio::net::TcpStream::connect(r.http).await.unwrap();
    hold.write_all(b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\n{")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    stop(r).await;
    drop(hold);
}

#[tokio::test]
async fn full_ingest_slots_are_503_while_the_api_still_answers() {
    use tokio::io::AsyncWriteExt;
    let r = start("max_concurrent_ingest = 1", Arc::new(Fake::default())).await;
    let mut hold = tokio::net::TcpStream::connect(r.http).await.unwrap();
    hold.write_all(
        b"POST /api/v2/write HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\nm,gate=",
    )
    .await
    .unwrap();
    let addr = r.http;
    let c = reqwest::Client::new();
    let resp = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            let resp = c
                .post(format!("http://{addr}/api/v1/samples"))
                .body(uniform("g1", 0.0, 3).to_string())
                .send()
                .await
                .unwrap();
            if resp.status() == 503 {
                break resp;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("503 while the ingest slot is held");
    assert_eq!(resp.headers()["retry-after"], "1");
    assert_eq!(get(addr, "/api/v1/gates").await.0, 200);
    drop(hold);
    stop(r).await;
}

#[tokio::test]
async fn slow_request_times_out_with_408() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let r = start("request_timeout_seconds = 0.2", Arc::new(Fake::default())).await;
    let mut s = tokio::net::TcpStream::connect(r.http).await.unwrap();
    s.write_all(b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\n{")
        .await
        .unwrap();
    let mut buf = vec![0u8; 256];
    let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf))
        .await
        .expect("answered")
        .unwrap();
    let head = String::from_utf8_lossy(&buf[..n]);
    assert!(head.starts_with("HTTP/1.1 408"), "{head}");
    assert_eq!(get(r.http, "/healthz").await.0, 200);
    stop(r).await;
}

#[tokio::test]
async fn readiness_and_graceful_shutdown_with_a_job_in_flight() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(500),
        ..Default::default()
    });
    let r = start("", fake.clone()).await;
    let addr = r.http;
    tokio::time::timeout(Duration::from_secs(10), async {
        while get(addr, "/readyz").await.0 != 200 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("ready");
    let c = reqwest::Client::new();
    let resp = c
        .post(format!("http://{addr}/api/v1/samples"))
        .body(uniform("g1", 0.0, 100).to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 204);
    wait_until(|| !fake.calls.lock().unwrap().is_empty()).await;
    stop(r).await; // returns within shutdown_grace_seconds even with the job in flight
    assert!(
        tokio::net::TcpStream::connect(addr).await.is_err(),
        "no longer accepting"
    );
}

#[tokio::test]
async fn simulate_client_streams_through_every_protocol() {
    use gatewatch::service::cli::{
        simulate_with_source, simulator, Protocol, Scenario, SimulateArgs,
    };
    let fake = Arc::new(Fake::default());
    let r = start(&format!("auth_tokens = [\"{TOKEN}\"]"), fake.clone()).await;
    for (gate, protocol) in [
        ("sj", Protocol::Json),
        ("sl", Protocol::Line),
        ("st", Protocol::Tcp),
    ] {
        let args = SimulateArgs {
            url: format!("http://{}", r.http),
            tcp_addr: r.tcp.to_string(),
            gate: gate.into(),
            scenario: Scenario::Onset,
            speed: 0.0,
            duration: 2.0,
            seed: 7,
            protocol,
            rate: 100.0,
            token: Some(TOKEN.into()),
            chunk_seconds: 0.1,
            start: Some(1000.0),
            onset_hold: 1.0,
            onset_ramp: 1.0,
        };
        let mut sim = simulator(&args).unwrap();
        let source = |b: &mut [f64]| sim.fill(b);
        let n = tokio::time::timeout(Duration::from_secs(20), simulate_with_source(&args, source))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(n, 200);
        let c = reqwest::Client::new();
        let url = format!("http://{}/api/v1/gates/{gate}", r.http);
        tokio::time::timeout(Duration::from_secs(10), async {
            loop {
                let v: Value = c
                    .get(&url)
                    .bearer_auth(TOKEN)
                    .send()
                    .await
                    .unwrap()
                    .json()
                    .await
                    .unwrap_or(Value::Null);
                if v["window"]["samples_total"] == 200 {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await
        .unwrap_or_else(|_| panic!("{gate}: 200 samples arrive"));
    }
    // a wrong token is an error, not a hang
    let args = SimulateArgs {
        url: format!("http://{}", r.http),
        tcp_addr: r.tcp.to_string(),
        gate: "x".into(),
        scenario: Scenario::Stable,
        speed: 0.0,
        duration: 0.5,
        seed: 1,
        protocol: Protocol::Json,
        rate: 100.0,
        token: Some("wrong-token-0123456789".into()),
        chunk_seconds: 0.1,
        start: None,
        onset_hold: 60.0,
        onset_ramp: 300.0,
    };
    let e = simulate_with_source(&args, |b: &mut [f64]| b.fill(0.0))
        .await
        .unwrap_err();
    assert!(e.to_string().contains("401"), "{e}");
    stop(r).await;
}

#[test]
fn simulate_scenarios_map_to_the_simulator_and_are_reproducible() {
    use gatewatch::service::cli::{simulator, Protocol, Scenario, SimulateArgs};
    let args = |scenario| SimulateArgs {
        url: String::new(),
        tcp_addr: String::new(),
        gate: "g1".into(),
        scenario,
        speed: 0.0,
        duration: 10.0,
        seed: 3,
        protocol: Protocol::Json,
        rate: 200.0,
        token: None,
        chunk_seconds: 0.1,
        start: None,
        onset_hold: 5.0,
        onset_ramp: 10.0,
    };
    for (sc, z0, z_late) in [
        (Scenario::Stable, 0.01, 0.01),
        (Scenario::Onset, 0.02, -0.02),
        (Scenario::LimitCycle, -0.02, -0.02),
    ] {
        let (mut a, mut b) = (simulator(&args(sc)).unwrap(), simulator(&args(sc)).unwrap());
        assert_eq!(a.true_zeta(0.0), z0);
        assert_eq!(a.true_zeta(20.0), z_late);
        let (mut x, mut y) = (vec![0.0; 2000], vec![0.0; 2000]);
        a.fill(&mut x);
        b.fill(&mut y);
        assert_eq!(x, y);
        assert!(x.iter().all(|v| v.is_finite()));
        assert!(x.iter().any(|v| *v != 0.0));
    }
    assert_eq!(
        simulator(&args(Scenario::Onset)).unwrap().true_zeta(10.0),
        0.0
    );
    let mut bad = args(Scenario::Onset);
    bad.onset_ramp = -1.0;
    assert!(simulator(&bad).is_err());
}

#[tokio::test]
async fn real_analyzers_never_take_the_daemon_down() {
    // `server::run` with the real per-gate analyzers: whatever the numerics do (succeed, refuse,
    // or panic while unfinished), the daemon keeps serving and reports the outcome.
    gatewatch::service::cli::ensure_crypto_provider();
    let cfg = Config::from_toml(
        "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\nshutdown_grace_seconds = 1.0\n\
         [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\npopulation = 8\ngenerations = 5\n",
    )
    .unwrap();
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = http.local_addr().unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(gatewatch::service::server::run(
        cfg,
        Listeners { http, tcp: None },
        async move {
            let _ = rx.await;
        },
    ));
    let c = reqwest::Client::new();
    let values: Vec<f64> = (0..150)
        .map(|i| 81_360.0 * 0.001 * (i as f64 * 0.094).sin() * (-0.01 * i as f64).exp())
        .collect();
    let resp = c
        .post(format!("http://{addr}/api/v1/samples"))
        .body(
            json!({"gate": "g1", "start": 1000.0, "rate_hz": 100.0, "values": values}).to_string(),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 204);
    tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            let m = get(addr, "/metrics").await.1;
            if m.contains("gatewatch_identification_failures_total{")
                || m.contains("gatewatch_last_identification_timestamp_seconds{")
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("the identification finished or failed");
    assert_eq!(get(addr, "/healthz").await.0, 200);
    assert_eq!(get(addr, "/api/v1/gates/g1").await.0, 200);
    let _ = tx.send(());
    tokio::time::timeout(Duration::from_secs(15), task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
}
