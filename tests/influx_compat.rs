//! The InfluxDB HTTP surface over `Router::oneshot`: gzip bodies (and a gzip bomb), unknown
//! encodings, precisions `m` and `h`, `/ping`, `/health`, `/query` and InfluxDB 2.x's error
//! shape. The real clients drive a real daemon in `tests/influx_clients.rs`.

use crate::service_common;

use std::io::Write;
use std::time::Duration;

use axum::body::Body;
use axum::http::{HeaderMap, Request, StatusCode};
use axum::Router;
use flate2::write::GzEncoder;
use flate2::Compression;
use serde_json::Value;
use tower::ServiceExt;

use service_common::*;

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::default());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

/// One request with the given headers; the body parsed as JSON when it is.
async fn request(
    app: &Router,
    method: &str,
    uri: &str,
    headers: &[(&str, &str)],
    body: impl Into<Body>,
) -> (StatusCode, Value, HeaderMap) {
    let mut req = Request::builder().method(method).uri(uri);
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let resp = tokio::time::timeout(
        Duration::from_secs(30),
        app.clone().oneshot(req.body(body.into()).unwrap()),
    )
    .await
    .expect("request timed out")
    .unwrap();
    let (status, headers) = (resp.status(), resp.headers().clone());
    let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    let v = serde_json::from_slice(&bytes)
        .unwrap_or(Value::String(String::from_utf8_lossy(&bytes).into()));
    (status, v, headers)
}

const GZ: (&str, &str) = ("content-encoding", "gzip");

#[tokio::test]
async fn gzip_bodies_are_accepted_on_every_ingest_route() {
    let (app, state) = make_app("");
    let lp = gzip(b"m,gate=v2 force=1 1000000\nm,gate=v2 force=2 1000010\n");
    let (s, v, _) = request(&app, "POST", "/api/v2/write?precision=ms", &[GZ], lp).await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    let lp = gzip(b"m,gate=v1 force=1 1000\n");
    // x-gzip and any case, as RFC 9110 allows
    let (s, v, _) = request(
        &app,
        "POST",
        "/write?precision=s&db=x",
        &[("content-encoding", "X-GZIP")],
        lp,
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    let js = gzip(uniform("js", 1000.0, 5).to_string().as_bytes());
    let (s, v, _) = request(
        &app,
        "POST",
        "/api/v1/samples",
        &[GZ, ("content-type", "application/json")],
        js,
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    assert_eq!(state.gate_view("v2").unwrap().window.samples, 2);
    assert_eq!(state.gate_view("v1").unwrap().window.samples, 1);
    assert_eq!(state.gate_view("js").unwrap().window.samples, 5);
    // identity is the absence of a coding
    let (s, _, _) = request(
        &app,
        "POST",
        "/api/v2/write?precision=ms",
        &[("content-encoding", "identity")],
        "m,gate=v2 force=3 1000020\n",
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    assert_eq!(state.gate_view("v2").unwrap().window.samples, 3);
}

/// A gzip body of several members (`cat a.gz b.gz`, RFC 1952 section 2.2) is read whole: the
/// lines after the first member were dropped with a 204 and no count. Bytes after the last
/// member that are not gzip are a broken body (400), not ignored.
#[tokio::test]
async fn every_member_of_a_gzip_body_is_read() {
    let (app, state) = make_app("");
    let lines = |gate: &str, from: usize, to: usize| {
        (from..to)
            .map(|i| format!("m,gate={gate} force={i} {}\n", 1_000_000 + 10 * i))
            .collect::<String>()
    };
    for uri in ["/api/v2/write?precision=ms", "/write?precision=ms"] {
        let gate = if uri.starts_with("/api") {
            "mm2"
        } else {
            "mm1"
        };
        let mut body = gzip(lines(gate, 0, 100).as_bytes());
        body.extend(gzip(lines(gate, 100, 200).as_bytes()));
        body.extend(gzip(lines(gate, 200, 203).as_bytes()));
        let (s, v, h) = request(&app, "POST", uri, &[GZ], body).await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{uri}: {v}");
        assert!(h.get("x-gatewatch-dropped").is_none(), "{uri}: {h:?}");
        // all 203 taken (the window itself holds 100: 1 s at 100 Hz)
        assert_eq!(
            state.gate_view(gate).unwrap().window.samples_total,
            203,
            "{uri}"
        );
    }
    let js = |gate: &str| uniform(gate, 1000.0, 5).to_string();
    let mut body = gzip(js("js1").as_bytes());
    body.extend(gzip(b"\n"));
    let (s, v, _) = request(&app, "POST", "/api/v1/samples", &[GZ], body).await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    assert_eq!(state.gate_view("js1").unwrap().window.samples, 5);
    // garbage after the last member
    let mut body = gzip(lines("mm3", 0, 10).as_bytes());
    body.extend(b"garbage after the gzip stream");
    let (s, v, _) = request(&app, "POST", "/api/v2/write?precision=ms", &[GZ], body).await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    assert!(state.gate_view("mm3").is_none());
}

/// Line protocol over HTTP has its rate checked for the whole request, as JSON `samples`
/// pairs do: 250 Hz lines on a 100 Hz gate were answered 204, taken, and never identified
/// (counted `rate_mismatch` one by one). Lines whose unit cannot resolve the gate's step
/// (`precision=s` at 100 Hz) imply no rate and go on as before.
#[tokio::test]
async fn line_protocol_at_another_rate_is_refused_naming_the_gate_and_line() {
    let (app, state) = make_app("");
    let lines = |gate: &str, step_ms: usize, n: usize| {
        (0..n)
            .map(|i| format!("m,gate={gate} force={i} {}\n", 1_000_000 + step_ms * i))
            .collect::<String>()
    };
    let body = format!("# a comment\n{}", lines("fast", 4, 50));
    let (s, v, _) = request(&app, "POST", "/api/v2/write?precision=ms", &[], body).await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    let message = v["message"].as_str().unwrap();
    assert!(
        message.contains("sample rate 250 Hz disagrees with the configured 100 Hz of gate `fast`"),
        "{v}"
    );
    assert!(message.contains("line 2"), "{v}");
    assert!(state.gate_view("fast").is_none());
    assert_eq!(
        metric(
            &state,
            "gatewatch_samples_rejected_total{reason=\"rate_mismatch\"}"
        ),
        50.0
    );
    // at the gate's rate, and two lines (no rate to read), taken
    let (s, v, _) = request(
        &app,
        "POST",
        "/write?precision=ms",
        &[],
        lines("right", 10, 50),
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    assert_eq!(state.gate_view("right").unwrap().window.samples_total, 50);
    let (s, v, _) = request(&app, "POST", "/write?precision=ms", &[], lines("two", 4, 2)).await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    // whole seconds cannot tell 100 Hz samples apart: no rate, as before
    let body: String = (0..5)
        .map(|i| format!("m,gate=coarse force={i} {}\n", 1000 + i))
        .collect();
    let (s, v, _) = request(&app, "POST", "/write?precision=s", &[], body).await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
}

#[tokio::test]
async fn gzip_bomb_is_413_and_counted() {
    // 64 KiB limit; 16 MiB of line protocol compresses to a few KiB, far under the limit
    let (app, state) = make_app("body_limit_bytes = 65536");
    let line = b"m,gate=bomb force=1 1000\n";
    let plain: Vec<u8> = line
        .iter()
        .copied()
        .cycle()
        .take(16 * 1024 * 1024)
        .collect();
    let bomb = gzip(&plain);
    assert!(bomb.len() < 65536, "compressed {} bytes", bomb.len());
    for uri in ["/api/v2/write", "/write"] {
        let (s, v, _) = request(&app, "POST", uri, &[GZ], bomb.clone()).await;
        assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE, "{uri}: {v}");
        assert_eq!(v["code"], "request too large", "{uri}");
    }
    let (s, v, _) = request(&app, "POST", "/api/v1/samples", &[GZ], bomb).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE, "{v}");
    assert!(state.gate_view("bomb").is_none());
    assert_eq!(
        metric(
            &state,
            "gatewatch_ingest_requests_rejected_total{reason=\"body_too_large\"}"
        ),
        3.0
    );
}

#[tokio::test]
async fn unknown_encodings_are_415_naming_them_and_bad_gzip_is_400() {
    let (app, state) = make_app("");
    for enc in ["br", "deflate", "gzip, gzip"] {
        let (s, v, h) = request(
            &app,
            "POST",
            "/api/v2/write",
            &[("content-encoding", enc)],
            "m,gate=g force=1\n",
        )
        .await;
        assert_eq!(s, StatusCode::UNSUPPORTED_MEDIA_TYPE, "{enc}");
        assert!(
            v["message"].as_str().unwrap().contains(&format!("`{enc}`")),
            "{v}"
        );
        assert_eq!(v["code"], "unsupported media type");
        assert_eq!(h["accept-encoding"], "gzip");
    }
    // the same coding on two header lines is the list `gzip, gzip` (RFC 9110, section 5.3):
    // it was decoded once and the still compressed body read as bad JSON
    let twice = gzip(&gzip(uniform("twice", 1000.0, 5).to_string().as_bytes()));
    for second in ["gzip", "br"] {
        let req = Request::builder()
            .method("POST")
            .uri("/api/v1/samples")
            .header("content-encoding", "gzip")
            .header("content-encoding", second)
            .body(Body::from(twice.clone()))
            .unwrap();
        let resp = app.clone().oneshot(req).await.unwrap();
        assert_eq!(
            resp.status(),
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "gzip + {second}"
        );
        let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX)
            .await
            .unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains(&format!("`gzip, {second}`")), "{text}");
    }
    // gatewatch's own route keeps its own shape
    let (s, v, _) = request(
        &app,
        "POST",
        "/api/v1/samples",
        &[("content-encoding", "zstd")],
        "{}",
    )
    .await;
    assert_eq!(s, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    assert!(v["error"].as_str().unwrap().contains("`zstd`"), "{v}");
    assert!(v.get("code").is_none());
    // not gzip at all
    let (s, v, _) = request(&app, "POST", "/api/v2/write", &[GZ], "m,gate=g force=1\n").await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    assert!(state.gate_view("g").is_none());
}

#[tokio::test]
async fn precisions_m_and_h_of_influxdb_1x() {
    let (app, state) = make_app("");
    let (s, v, _) = request(
        &app,
        "POST",
        "/write?precision=m",
        &[],
        "m,gate=min force=1 28333334\n",
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    let t = state
        .gate_view("min")
        .unwrap()
        .window
        .last_sample_time
        .unwrap();
    assert!((t - 28_333_334.0 * 60.0).abs() < 1e-3, "{t}");
    let (s, v, _) = request(
        &app,
        "POST",
        "/write?precision=h",
        &[],
        "m,gate=hour force=1 472222\n",
    )
    .await;
    assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
    let t = state
        .gate_view("hour")
        .unwrap()
        .window
        .last_sample_time
        .unwrap();
    assert!((t - 472_222.0 * 3600.0).abs() < 1e-3, "{t}");
    let (s, v, _) = request(
        &app,
        "POST",
        "/write?precision=d",
        &[],
        "m,gate=x force=1 1\n",
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["field"], "precision");
    assert!(v["message"].as_str().unwrap().contains("m, h"), "{v}");
}

#[tokio::test]
async fn ping_health_and_query() {
    let (app, _) = make_app(&format!("auth_tokens = [\"{TOKEN}\"]"));
    for method in ["GET", "HEAD"] {
        let (s, _, h) = request(&app, method, "/ping", &[], Body::empty()).await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{method}");
        assert!(h["x-influxdb-version"]
            .to_str()
            .unwrap()
            .starts_with("gatewatch-"));
    }
    // no listener in a oneshot test: not ready, in InfluxDB's shape
    let (s, v, _) = request(&app, "GET", "/health", &[], Body::empty()).await;
    assert_eq!(s, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(
        (v["name"].as_str(), v["status"].as_str()),
        (Some("gatewatch"), Some("fail"))
    );
    // why, as /readyz says it (not the v2 error shape's generic "service unavailable")
    assert_eq!(
        v["message"], "not ready: listeners not up (starting or shutting down)",
        "{v}"
    );
    let auth = format!("Bearer {TOKEN}");
    let bearer = ("authorization", auth.as_str());
    let (s, v, _) = request(
        &app,
        "POST",
        "/query?q=CREATE+DATABASE+%22telegraf%22",
        &[bearer],
        Body::empty(),
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v, serde_json::json!({"results": [{"statement_id": 0}]}));
    // the 1.x clients may send q as a form body
    let (s, v, _) = request(
        &app,
        "POST",
        "/query",
        &[
            bearer,
            ("content-type", "application/x-www-form-urlencoded"),
        ],
        "q=CREATE+DATABASE+db1",
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{v}");
    // q twice in the body, or once in the URL and once in the body: which one wins is a guess
    // (a form read into a map took the last), so each is a 400 naming q
    let form = ("content-type", "application/x-www-form-urlencoded");
    for (uri, body, says) in [
        (
            "/query",
            "q=CREATE+DATABASE+db1&q=SHOW+DATABASES",
            "given more than once",
        ),
        (
            "/query?q=CREATE+DATABASE+db1",
            "q=SHOW+DATABASES",
            "both the URL",
        ),
    ] {
        let (s, v, _) = request(&app, "POST", uri, &[bearer, form], body).await;
        assert_eq!(s, StatusCode::BAD_REQUEST, "{uri} {body}: {v}");
        let message = v["message"].as_str().unwrap_or_default();
        assert!(
            message.contains(says) && message.contains("SHOW DATABASES"),
            "{uri} {body}: {v}"
        );
    }
    // a form body without q, q in the URL: the URL's
    let (s, v, _) = request(
        &app,
        "POST",
        "/query?q=CREATE+DATABASE+db2",
        &[bearer, form],
        "db=x&epoch=ms",
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{v}");
    // a body that is not read as a form is said as such (it was "missing required parameter
    // `q`"), and one over the body limit is a 413, as on the write routes
    let (s, v, _) = request(
        &app,
        "POST",
        "/query",
        &[bearer, ("content-type", "text/plain")],
        "q=CREATE+DATABASE+db3",
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    let message = v["message"].as_str().unwrap_or_default();
    assert!(message.contains("this body was not read as one"), "{v}");
    let big = format!("q=CREATE+DATABASE+{}", "a".repeat(5 << 20));
    let (s, v, _) = request(&app, "POST", "/query", &[bearer, form], big).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE, "{v}");
    let (s, v, h) = request(
        &app,
        "GET",
        "/query?q=SHOW+DATABASES",
        &[bearer],
        Body::empty(),
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["code"], "invalid");
    assert_eq!(h["x-platform-error-code"], "invalid");
    assert!(
        v["message"].as_str().unwrap().contains("no databases"),
        "{v}"
    );
    // writes and queries need the token like every ingestion route
    let (s, v, h) = request(&app, "POST", "/write", &[], "m,gate=g force=1\n").await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    assert_eq!(v["code"], "unauthorized");
    assert_eq!(h["www-authenticate"], "Bearer");
}

#[tokio::test]
async fn influx_errors_in_v2_shape_and_gatewatch_errors_unchanged() {
    let (app, _) = make_app("");
    let (s, v, _) = request(
        &app,
        "POST",
        "/api/v2/write",
        &[],
        "m,gate=g1 force=1 1\nm,gate=g1 force=1x 2\n",
    )
    .await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["code"], "invalid");
    let msg = v["message"].as_str().unwrap();
    assert!(msg.starts_with("line 2 column 17: "), "{msg}");
    // the 1.x member and the location stay
    assert!(v["error"].is_string());
    assert_eq!(
        (v["line"].as_u64(), v["column"].as_u64()),
        (Some(2), Some(17))
    );
    let (s, v, _) = request(&app, "POST", "/api/v1/samples", &[], "{").await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert!(v["error"].is_string() && v.get("code").is_none(), "{v}");
}
