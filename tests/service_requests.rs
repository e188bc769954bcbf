//! Daemon ingestion over `Router::oneshot`: the malformed requests of the docs/api.md table,
//! bounds (body, gates, tokens), duplicates, out-of-order samples and gaps.

use crate::service_common;

use std::sync::{Arc, Barrier};

use axum::body::Body;
use axum::http::StatusCode;
use gatewatch::service::config::Config;
use gatewatch::service::ingest::Batch;
use gatewatch::service::state::IngestError;
use serde_json::json;

use service_common::*;

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
        "[server]\nworker_threads = 1\naccept_unknown_gates = false\n[defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nmax_past_seconds = 0.0\n[gates.known]\n",
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
async fn max_gates_holds_under_concurrent_new_gates() {
    // Many requests at once, each creating a new gate: validation and application share one
    // lock, so exactly `max_gates` are accepted and the others get `TooManyGates`.
    // The race is caught per round only with some probability: with validation and application
    // under two locks, 3 runs of 200 rounds failed at rounds 5, 10, 11 and 16.
    const MAX: usize = 4;
    const SENDERS: usize = 32;
    for round in 0..200 {
        let (_app, state) = make_app(&format!("max_gates = {MAX}"));
        let start = Arc::new(Barrier::new(SENDERS));
        let senders: Vec<_> = (0..SENDERS)
            .map(|i| {
                let (state, start) = (state.clone(), start.clone());
                std::thread::spawn(move || {
                    let batch = Batch {
                        gate: format!("c{i}"),
                        samples: vec![(1000.0, 1.0)],
                        rate: None,
                        values_field: "values".into(),
                        lines: None,
                        precision: None,
                    };
                    start.wait();
                    state.ingest(vec![batch])
                })
            })
            .collect();
        let results: Vec<_> = senders.into_iter().map(|h| h.join().unwrap()).collect();
        let gates = state.gate_ids().len();
        assert!(gates <= MAX, "round {round}: {gates} gates, bound {MAX}");
        assert_eq!(results.iter().filter(|r| r.is_ok()).count(), MAX);
        for r in results.iter().filter_map(|r| r.as_ref().err()) {
            assert!(matches!(r, IngestError::TooManyGates(_)), "{r:?}");
        }
        assert_eq!(
            metric(
                &state,
                "gatewatch_samples_rejected_total{reason=\"too_many_gates\"}"
            ),
            (SENDERS - MAX) as f64
        );
    }
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
async fn authorization_schemes_are_case_insensitive_and_influx_token_is_accepted() {
    use tower::ServiceExt;
    let (app, _) = make_app(&format!("auth_tokens = [\"{TOKEN}\"]"));
    let with = |value: String| {
        axum::http::Request::builder()
            .method("POST")
            .uri("/api/v2/write")
            .header("authorization", value)
            .body(Body::from("m,gate=g1 force=1\n"))
            .unwrap()
    };
    for good in [
        format!("Bearer {TOKEN}"),
        format!("bearer {TOKEN}"),
        format!("BEARER {TOKEN}"),
        format!("Token {TOKEN}"),
        format!("token {TOKEN}"),
    ] {
        let s = app
            .clone()
            .oneshot(with(good.clone()))
            .await
            .unwrap()
            .status();
        assert_eq!(s, StatusCode::NO_CONTENT, "{good}");
    }
    for bad in [
        format!("Basic {TOKEN}"),
        format!("Bearer{TOKEN}"),
        TOKEN.to_string(),
        "Bearer wrong-token-0123456789".to_string(),
    ] {
        let s = app
            .clone()
            .oneshot(with(bad.clone()))
            .await
            .unwrap()
            .status();
        assert_eq!(s, StatusCode::UNAUTHORIZED, "{bad}");
    }
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

/// A gate id in the path is client input like any other: a 60 000-character one was echoed
/// whole in the 404 (`ingest::EXCERPT_CHARS`), and a percent-encoding that is not UTF-8 got
/// axum's text/plain `Invalid URL: Invalid UTF-8 in `id`` instead of the JSON error.
#[tokio::test]
async fn path_parameters_are_quoted_as_an_excerpt_and_refused_in_json() {
    use gatewatch::service::ingest::{EXCERPT_CHARS, MAX_ERROR_CHARS};
    let (app, _) = make_app("");
    let long = "a".repeat(60_000);
    let (s, v, _) = send(
        &app,
        "GET",
        &format!("/api/v1/gates/{long}"),
        Body::empty(),
        None,
    )
    .await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{v}");
    let e = v["error"].as_str().expect("a JSON error");
    assert!(
        e.chars().count() <= MAX_ERROR_CHARS,
        "{} characters",
        e.len()
    );
    let quoted = format!("unknown gate `{}... (60000 bytes)`", &long[..EXCERPT_CHARS]);
    assert_eq!(e, quoted);
    for uri in [
        "/api/v1/gates/%ff%fe",
        "/api/v1/gates/%ff/history",
        "/api/v1/gates/g%c3/history?limit=1",
    ] {
        let (s, v, headers) = send(&app, "GET", uri, Body::empty(), None).await;
        assert_eq!(s, StatusCode::BAD_REQUEST, "{uri}: {v}");
        assert_eq!(
            headers.get("content-type").map(|c| c.as_bytes()),
            Some(&b"application/json"[..]),
            "{uri}"
        );
        assert_eq!(v["field"], "id", "{uri}: {v}");
        assert!(
            v["error"].as_str().is_some_and(|e| e.contains("not UTF-8")),
            "{uri}: {v}"
        );
    }
}

/// Gate ids of dots only (`.`, `..`) were ingested, then listed but not readable: clients
/// normalise `/api/v1/gates/..` to `/api/v1/`. They are refused as every other bad id, over JSON
/// and line protocol, and an id with dots among other characters still passes.
#[tokio::test]
async fn gate_ids_of_dots_only_are_refused() {
    let (app, state) = make_app("");
    for gate in [".", "..", "..."] {
        let (s, v) = post_json(&app, uniform(gate, 1000.0, 3)).await;
        assert_eq!(
            (s, v["field"].as_str()),
            (StatusCode::BAD_REQUEST, Some("gate")),
            "{gate:?}: {v}"
        );
        assert!(
            v["error"]
                .as_str()
                .is_some_and(|e| e.contains("not only dots")),
            "{v}"
        );
        for route in ["/api/v2/write", "/write"] {
            let body = format!("m,gate={gate} force=1 1000000000000\n");
            let (s, v, _) = send(&app, "POST", route, body, None).await;
            assert_eq!(
                (s, v["field"].as_str(), v["line"].as_u64()),
                (StatusCode::BAD_REQUEST, Some("gate"), Some(1)),
                "{route} {gate:?}: {v}"
            );
        }
    }
    assert!(state.gate_ids().is_empty(), "{:?}", state.gate_ids());
    for gate in ["a.b", ".g1", "v1.."] {
        let (s, v) = post_json(&app, uniform(gate, 1000.0, 3)).await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{gate:?}: {v}");
    }
}

#[tokio::test]
async fn duplicates_and_out_of_order_are_counted() {
    let (app, state) = make_app("");
    let pairs = json!({"gate": "g1", "samples": [[10.00, 1], [10.01, 2], [10.01, 2], [10.02, 3], [10.005, 9], [10.03, 4]]});
    // samples dropped: 200 with the counts, never a bare 204 (issue 12)
    assert_eq!(post_json(&app, pairs).await.0, StatusCode::OK);
    assert_eq!(state.gate_view("g1").unwrap().window.samples, 4);
    // a replayed (older) chunk is dropped
    assert_eq!(
        post_json(&app, uniform("g1", 9.0, 5)).await.0,
        StatusCode::OK
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

/// A value the analysis refuses (beyond +-1e100, `data::MAX_ABS_VALUE`) is refused at
/// ingestion naming its sample, as NaN is. Before, 4000 samples with one 1e308 were answered
/// 204 and every window holding it then failed with "window not analysable".
#[tokio::test]
async fn values_beyond_the_analysis_bound_are_refused_naming_the_sample() {
    let (app, state) = make_app("");
    let mut values: Vec<f64> = (0..4000).map(|i| (i as f64 * 0.3).sin()).collect();
    values[1545] = 1e308;
    let batch = |values: &[f64]| json!({"gate": "big1", "start": 1000.0, "rate_hz": 100.0, "values": values});
    let (s, v) = post_json(&app, batch(&values)).await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("values"), Some(1545)),
        "{v}"
    );
    let e = v["error"].as_str().unwrap();
    assert!(e.contains("1e308") && e.contains("1e100"), "{e}");
    assert!(state.gate_view("big1").is_none(), "nothing applied");
    values[1545] = -2e100;
    let (s, v) = post_json(&app, batch(&values)).await;
    assert_eq!(
        (s, v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some(1545))
    );
    // the bound itself is a value the analysis takes
    values[1545] = -1e100;
    assert_eq!(
        post_json(&app, batch(&values)).await.0,
        StatusCode::NO_CONTENT
    );
    // JSON `samples` pairs name the pair
    let pairs = json!({"gate": "g2", "samples": [[1000.0, 1.0], [1000.01, 1e101]]});
    let (s, v) = post_json(&app, pairs).await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("samples"), Some(1))
    );
    // line protocol names the line and the field, on both Influx routes
    let lp = "m,gate=g3 force=1 1000000000000\nm,gate=g3 force=-1e300 1000010000000\n";
    for route in ["/api/v2/write", "/write"] {
        let (s, v, _) = send(&app, "POST", route, lp, None).await;
        assert_eq!(
            (s, v["line"].as_u64(), v["field"].as_str()),
            (StatusCode::BAD_REQUEST, Some(2), Some("force")),
            "{route}: {v}"
        );
        assert!(v["error"].as_str().unwrap().contains("-1e300"), "{v}");
    }
    assert!(state.gate_view("g3").is_none());
    // counted per sample of the refused requests, under their own reason (not `non_finite`)
    assert_eq!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"out_of_range\"}"
        ),
        (4000 + 4000 + 2 + 2 + 2) as f64
    );
    assert_eq!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"non_finite\"}"
        ),
        0.0
    );
}

/// Timestamps in the wrong unit get a hint naming the likely unit and the fix, when a factor
/// 1e3, 1e6 or 1e9 makes them plausible; other times out of the bounds get none.
#[tokio::test]
async fn timestamps_in_another_unit_get_a_hint_naming_it() {
    // the default bounds: 600 s ahead, 3600 s behind
    let cfg = Config::from_toml(
        "[server]\nworker_threads = 1\n[defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\n",
    )
    .unwrap();
    let (app, state) = app_with(cfg, Arc::new(Fake::default()));
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let lp = |ts: u64| format!("m,gate=g1 force=1 {ts}\n");
    let error = |v: &serde_json::Value| v["error"].as_str().unwrap_or_default().to_string();
    // milliseconds read as the default nanoseconds: 1e6 times too small
    let ms = (now * 1e3) as u64;
    let (s, v, _) = send(&app, "POST", "/api/v2/write", lp(ms), None).await;
    assert_eq!(
        (s, v["field"].as_str(), v["line"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("timestamp"), Some(1)),
        "{v}"
    );
    let e = error(&v);
    assert!(e.contains("behind the daemon's clock"), "{e}");
    assert!(e.contains("in ms?") && e.contains("`?precision=ms`"), "{e}");
    assert!(e.contains("tcp_precision = \"ms\""), "{e}");
    // the fix the hint names works
    let (s, v, _) = send(&app, "POST", "/api/v2/write?precision=ms", lp(ms), None).await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    // seconds at precision=ms: 1e3 times too small; nanoseconds at precision=s: too large
    let (_, v, _) = send(
        &app,
        "POST",
        "/write?precision=ms",
        lp(now as u64 + 1),
        None,
    )
    .await;
    assert!(error(&v).contains("`?precision=s`"), "{v}");
    let ns = (now * 1e9) as u64 + 2_000_000_000;
    let (_, v, _) = send(&app, "POST", "/write?precision=s", lp(ns), None).await;
    assert!(error(&v).contains("ahead of the daemon's clock"), "{v}");
    assert!(error(&v).contains("`?precision=ns`"), "{v}");
    // JSON `start` in milliseconds: seconds is the unit, not a query parameter
    let (s, v) = post_json(&app, uniform("g2", (now + 5.0) * 1e3, 10)).await;
    assert_eq!(
        (s, v["field"].as_str(), v["index"].as_u64()),
        (StatusCode::BAD_REQUEST, Some("start"), Some(0))
    );
    let e = error(&v);
    assert!(e.contains("in ms?") && e.contains("Unix seconds"), "{e}");
    assert!(!e.contains("precision"), "{e}");
    // year 1971 and 2 h behind are no other unit: no hint
    for start in [40_000_000.0, now - 7200.0] {
        let (s, v) = post_json(&app, uniform("g2", start, 10)).await;
        assert_eq!(s, StatusCode::BAD_REQUEST);
        assert!(!error(&v).contains("plausible"), "{v}");
    }
    assert!(state.gate_view("g2").is_none());
}

/// The gate list takes `limit` and `after` (or `cursor`) and refuses anything else, as the
/// history route does (one parser): `?limt=2` listed every gate with a 200, and
/// `?limit=1&limit=2` took the last.
#[tokio::test]
async fn the_gate_list_refuses_unknown_and_repeated_parameters() {
    let (app, _) = make_app("");
    for g in ["a", "b", "c"] {
        assert_eq!(
            post_json(&app, uniform(g, 1000.0, 3)).await.0,
            StatusCode::NO_CONTENT
        );
    }
    let get = |uri: &'static str| {
        let app = app.clone();
        async move { send(&app, "GET", uri, Body::empty(), None).await }
    };
    let (s, v, _) = get("/api/v1/gates?limt=2").await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("limt")),
        "{v}"
    );
    assert!(
        v["error"]
            .as_str()
            .unwrap()
            .contains("unknown parameter `limt`"),
        "{v}"
    );
    let (s, v, _) = get("/api/v1/gates?limit=1&limit=2").await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("limit")),
        "{v}"
    );
    assert!(
        v["error"].as_str().unwrap().contains("more than once"),
        "{v}"
    );
    let (s, v, _) = get("/api/v1/gates?after=a&cursor=b").await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("cursor")),
        "{v}"
    );
    // the parameters it takes still work
    let (s, v, _) = get("/api/v1/gates?limit=1&after=a").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v["gates"][0]["gate"], "b");
    assert_eq!(v["next"], "b");
    let (_, v, _) = get("/api/v1/gates?cursor=b").await;
    assert_eq!(v["gates"].as_array().map(Vec::len), Some(1));
    // the gate's view takes none: `?format=csv` would have answered JSON as if read
    let (s, v, _) = get("/api/v1/gates/a?format=csv").await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("format")),
        "{v}"
    );
    assert_eq!(get("/api/v1/gates/a").await.0, StatusCode::OK);
    // /query: `q` twice is refused; the InfluxDB parameters it ignores are still accepted
    let (s, v, _) = get("/query?q=CREATE+DATABASE+a&q=SHOW+DATABASES").await;
    assert_eq!(
        (s, v["field"].as_str()),
        (StatusCode::BAD_REQUEST, Some("q")),
        "{v}"
    );
    let (s, v, _) = get("/query?q=CREATE+DATABASE+a&db=x&epoch=ms&pretty=true").await;
    assert_eq!(s, StatusCode::OK, "{v}");
}
