//! Network hardening on a real server on port 0 (issue 12): refusals before the body is read
//! (`Connection: close`, `Expect: 100-continue`), the HTTP connection cap and header timeout,
//! the request head's size, the TCP idle timeout and client allow-list, unknown-gate expiry (and the hold of a gate whose
//! damping alert fires, and `DELETE /api/v1/gates/{id}`), the paginated gate list.
//! Every wait is bounded by a timeout (a guard against hanging, not a timing assertion).

use crate::service_common;
use crate::store_common;

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use axum::body::Body;
use axum::http::StatusCode;
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use service_common::*;

/// Everything the server sends until it closes the connection (bounded wait).
async fn read_to_close(s: &mut TcpStream) -> String {
    let mut out = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out))
        .await
        .expect("the server closes the connection")
        .unwrap_or(0);
    String::from_utf8_lossy(&out).into_owned()
}

/// Whether the server closed `s`: a read returns end-of-file (or a reset) within 10 s.
async fn closed_by_server(s: &mut TcpStream) -> bool {
    let mut buf = [0u8; 64];
    matches!(
        tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf)).await,
        Ok(Ok(0)) | Ok(Err(_))
    )
}

#[tokio::test]
async fn a_refusal_before_the_body_says_connection_close_to_a_keep_alive_client() {
    // the budget holds one 1 MiB body: a request that declares 1 MiB and sends a few bytes
    // holds all of it
    let r = start_default("body_limit_bytes = 1048576\nmax_body_bytes_in_flight = 1048576").await;
    let holder = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
              content-length: 1048576\r\n\r\n{\"gate\"",
    )
    .await;
    // wait until the holder's reservation is made (its request is in the handler)
    let addr = r.http;
    tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            // the holder is admitted before its body is read: from then on a small POST is
            // refused
            let resp = reqwest::Client::new()
                .post(format!("http://{addr}/api/v1/samples"))
                .body(r#"{"gate":"p","start":1,"rate_hz":100,"values":[1]}"#)
                .send()
                .await
                .unwrap();
            if resp.status() == 503 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("the holder's reservation is made");

    // two pipelined requests on one keep-alive connection: the first is refused before its
    // body is read; the client must get the whole 503 with Retry-After, then a clean close
    let mut c = TcpStream::connect(r.http).await.unwrap();
    let body = r#"{"gate":"k","start":1,"rate_hz":100,"values":[1]}"#;
    let req = format!(
        "POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n{body}",
        body.len()
    );
    c.write_all(format!("{req}{req}").as_bytes()).await.unwrap();
    let answer = read_to_close(&mut c).await.to_ascii_lowercase();
    assert!(answer.starts_with("http/1.1 503"), "{answer}");
    assert!(answer.contains("connection: close"), "{answer}");
    assert!(answer.contains("retry-after: 1"), "{answer}");
    assert!(answer.contains("overloaded"), "{answer}");
    assert_eq!(answer.matches("http/1.1 ").count(), 1, "{answer}");
    drop(holder);
    stop(r).await;
}

#[tokio::test]
async fn expect_continue_over_the_limit_gets_413_without_sending_the_body() {
    let r = start_default("").await;
    let mut c = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
          expect: 100-continue\r\ncontent-length: 1000000000\r\n\r\n",
    )
    .await;
    // no body is ever sent: the answer can only come from the headers
    let answer = read_to_close(&mut c).await.to_ascii_lowercase();
    assert!(answer.starts_with("http/1.1 413"), "{answer}");
    assert!(!answer.contains("100 continue"), "{answer}");
    assert!(answer.contains("connection: close"), "{answer}");
    stop(r).await;
}

#[tokio::test]
async fn a_silent_http_connection_is_closed_after_the_header_timeout() {
    let r = start_default("http_header_read_timeout_seconds = 0.3").await;
    let mut silent = TcpStream::connect(r.http).await.unwrap();
    assert!(closed_by_server(&mut silent).await);
    // a slowloris that never finishes its headers, too
    let mut slow = connect_and_write(r.http, b"GET /healthz HTTP/1.1\r\nhost: x\r\n").await;
    assert!(closed_by_server(&mut slow).await);
    assert_eq!(get(r.http, "/healthz").await.0, 200);
    stop(r).await;
}

/// A request head is buffered up to `MAX_REQUEST_HEAD_BYTES` (64 KiB), then refused with 431:
/// hyper's default let each connection buffer about 400 KiB of head, 204 MiB over the 512
/// connections allowed, outside the documented memory bound.
#[tokio::test]
async fn a_request_head_over_64_kib_is_refused_with_431() {
    use gatewatch::service::listen::MAX_REQUEST_HEAD_BYTES;
    let r = start_default("").await;
    let head = |header_bytes: usize| {
        format!(
            "GET /healthz HTTP/1.1\r\nhost: x\r\nx-filler: {}\r\nconnection: close\r\n\r\n",
            "a".repeat(header_bytes)
        )
    };
    // just under the bound: served
    let mut s = connect_and_write(r.http, head(MAX_REQUEST_HEAD_BYTES - 200).as_bytes()).await;
    let answer = read_to_close(&mut s).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // 100 KiB of one header (hyper's default took it): 431, and the connection ends
    let mut s = TcpStream::connect(r.http).await.unwrap();
    let _ = s.write_all(head(100 * 1024).as_bytes()).await;
    let answer = read_to_close(&mut s).await;
    assert!(answer.starts_with("HTTP/1.1 431"), "{answer}");
    // a client still sending its head when the 431 is written reads it to a clean end, not a
    // reset (which cut it part-way, or lost it): 1 MiB of one header, and 3000 short header
    // lines (under the byte bound, over hyper's count)
    let many: String = (0..3000).map(|i| format!("x-{i}: a\r\n")).collect();
    for big in [
        head(1024 * 1024),
        format!("GET /healthz HTTP/1.1\r\nhost: x\r\n{many}connection: close\r\n\r\n"),
    ] {
        let mut s = TcpStream::connect(r.http).await.unwrap();
        let sent = s.write_all(big.as_bytes()).await;
        let mut out = Vec::new();
        let read = tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out))
            .await
            .expect("the server closes the connection");
        let answer = String::from_utf8_lossy(&out);
        assert!(
            sent.is_ok() && read.is_ok() && answer.starts_with("HTTP/1.1 431"),
            "{} bytes: sent {sent:?}, read {read:?}: {answer:?}",
            big.len()
        );
    }
    stop(r).await;
}

#[tokio::test]
async fn connections_over_the_cap_are_closed_and_a_client_gets_in_after_they_go() {
    let r = start_default("max_http_connections = 4").await;
    let mut held = Vec::new();
    for _ in 0..4 {
        let mut s = TcpStream::connect(r.http).await.unwrap();
        // a started request: the connection is surely accepted and served
        s.write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n")
            .await
            .unwrap();
        held.push(s);
    }
    // the fifth is closed at accept (it may take a moment to be accepted)
    let mut extra = TcpStream::connect(r.http).await.unwrap();
    let _ = extra
        .write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n\r\n")
        .await;
    let answer = read_to_close(&mut extra).await;
    assert!(
        answer.is_empty(),
        "over the cap: closed unanswered, got {answer}"
    );
    drop(held);
    // the slots free as the held connections end: /healthz answers again
    let addr = r.http;
    tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            if let Ok(resp) = reqwest::get(format!("http://{addr}/healthz")).await {
                if resp.status() == 200 {
                    break;
                }
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("a new client is served after the held connections closed");
    let (_, m) = get(addr, "/metrics").await;
    assert!(
        m.lines().any(
            |l| l.starts_with("gatewatch_http_connections_rejected_total ") && !l.ends_with(" 0")
        ),
        "{m}"
    );
    stop(r).await;
}

/// The probes' own port (`server.health_listen`): with every connection of `server.listen`
/// held by silent clients, the kubelet's probes and a scrape are still answered there (on the
/// main port they were refused: a liveness probe failing three times restarts the pod). The
/// port serves nothing else, and has a cap of its own, counted apart.
#[tokio::test]
async fn the_health_listener_answers_while_every_http_connection_is_held() {
    let r = start_default("max_http_connections = 2").await;
    let hold = |addr, n| async move {
        let mut held = Vec::new();
        for _ in 0..n {
            let mut s = TcpStream::connect(addr).await.unwrap();
            // a started request: the connection is surely accepted and kept
            s.write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n")
                .await
                .unwrap();
            held.push(s);
        }
        held
    };
    let refused = |addr| async move {
        let mut extra = TcpStream::connect(addr).await.unwrap();
        let _ = extra
            .write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n\r\n")
            .await;
        read_to_close(&mut extra).await
    };
    let held = hold(r.http, 2).await;
    let answer = refused(r.http).await;
    assert!(answer.is_empty(), "the main port is full, got {answer}");
    assert_eq!(get(r.health, "/healthz").await, (200, "ok\n".to_string()));
    assert_eq!(get(r.health, "/readyz").await, (200, "ready\n".to_string()));
    let (status, m) = get(r.health, "/metrics").await;
    assert_eq!(status, 200);
    assert!(
        m.lines().any(
            |l| l.starts_with("gatewatch_http_connections_rejected_total ") && !l.ends_with(" 0")
        ),
        "the main port's refusal is on the health port's /metrics: {m}"
    );
    for path in ["/api/v1/gates", "/api/v1/samples", "/write"] {
        assert_eq!(
            get(r.health, path).await.0,
            404,
            "{path} on the health port"
        );
    }
    drop(held);
    // its own cap: one connection over it is closed at accept and counted apart
    let held = hold(r.health, gatewatch::service::config::HEALTH_MAX_CONNECTIONS).await;
    let answer = refused(r.health).await;
    assert!(answer.is_empty(), "over the health cap, got {answer}");
    drop(held);
    let addr = r.health;
    let m = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            if let Ok(resp) = reqwest::get(format!("http://{addr}/metrics")).await {
                if resp.status() == 200 {
                    break resp.text().await.unwrap();
                }
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("the health port serves again once its held connections closed");
    assert!(
        m.lines().any(
            |l| l.starts_with("gatewatch_health_connections_rejected_total ") && !l.ends_with(" 0")
        ),
        "{m}"
    );
    // the health port's answers cut in sending are counted apart from the main port's
    for listener in ["http", "health"] {
        let series = format!(
            "gatewatch_http_connections_cut_total{{listener=\"{listener}\",reason=\"send_timeout\"}} 0"
        );
        assert!(m.lines().any(|l| l == series), "{series} in {m}");
    }
    stop(r).await;
}

#[tokio::test]
async fn a_silent_tcp_connection_is_closed_after_the_idle_timeout() {
    let r = start_default("tcp_idle_timeout_seconds = 0.3").await;
    let mut silent = TcpStream::connect(r.tcp).await.unwrap();
    assert!(closed_by_server(&mut silent).await);
    // a client that sends keeps its connection and its line is applied
    let _c = connect_and_write(r.tcp, b"m,gate=idle1 force=1 1000000000000\n").await;
    let addr = r.http;
    wait_for_get(
        addr,
        "/api/v1/gates/idle1",
        10,
        "/api/v1/gates/idle1 answers 200",
        |status, _| status == 200,
    )
    .await;
    stop(r).await;
}

/// The idle timeout runs from the last byte: a half line sent once, then silence, held its
/// connection slot until twice the timeout after the connection opened (the wait restarted
/// whole when the buffer had changed at any time during the last one).
#[tokio::test]
async fn a_half_line_then_silence_is_closed_one_timeout_after_its_last_byte() {
    let r = start_default("tcp_idle_timeout_seconds = 1.0").await;
    let mut c = TcpStream::connect(r.tcp).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    c.write_all(b"m,gate=half force=1").await.unwrap();
    let last_byte = std::time::Instant::now();
    assert!(closed_by_server(&mut c).await);
    let silent = last_byte.elapsed().as_secs_f64();
    // closed at 1.9 s after the last byte before; scheduling may add a little
    assert!(
        (0.95..1.6).contains(&silent),
        "closed {silent} s after the last byte"
    );
    stop(r).await;
}

/// Idle means no byte: a client still sending its line, a byte at a time, was cut after one
/// timeout (the wait timed whole lines) and its line lost; a line begun and never ended when
/// the connection goes idle is refused and counted (`bad_line`), not dropped without a word.
#[tokio::test]
async fn a_tcp_client_sending_slowly_is_not_idle_and_a_cut_line_is_counted() {
    let r = start_default("tcp_idle_timeout_seconds = 1.0").await;
    let mut slow = TcpStream::connect(r.tcp).await.unwrap();
    let line = b"m,gate=trickle force=1 1000000000000\n";
    // about 3.7 s for the line, a byte every 0.1 s: more than three timeouts in all
    for b in line {
        slow.write_all(&[*b])
            .await
            .expect("the slow client is not cut");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    wait_for_get(
        r.http,
        "/api/v1/gates/trickle",
        10,
        "the trickled line applied",
        |s, _| s == 200,
    )
    .await;
    let _cut = connect_and_write(r.tcp, b"m,gate=cut force=1 1000000000000").await;
    wait_for_get(r.http, "/metrics", 10, "the cut line counted", |_, m| {
        m.contains("gatewatch_samples_rejected_total{reason=\"bad_line\"} 1")
    })
    .await;
    assert_eq!(get(r.http, "/api/v1/gates/cut").await.0, 404);
    stop(r).await;
}

#[tokio::test]
async fn tcp_clients_outside_the_allowed_networks_are_closed_at_accept() {
    let r = start_default("tcp_allowed_networks = [\"10.0.0.0/8\", \"192.0.2.7\"]").await;
    let mut c = TcpStream::connect(r.tcp).await.unwrap();
    let _ = c
        .write_all(b"m,gate=outsider force=1 1000000000000\n")
        .await;
    assert!(closed_by_server(&mut c).await);
    let (_, m) = get(r.http, "/metrics").await;
    assert!(
        m.contains("gatewatch_tcp_connections_rejected_total{reason=\"not_allowed\"} 1"),
        "{m}"
    );
    // the other reason is exported, at 0 (rate() sees its first increment)
    assert!(
        m.contains("gatewatch_tcp_connections_rejected_total{reason=\"connection_limit\"} 0"),
        "{m}"
    );
    assert_eq!(get(r.http, "/api/v1/gates/outsider").await.0, 404);
    stop(r).await;
}

#[tokio::test]
async fn a_silent_unknown_gate_expires_and_its_stale_alert_resolves() {
    let cfg = config("unknown_gate_expiry_seconds = 600\n[gates.kept]\n");
    let (app, state) = app_with(cfg, Arc::new(Fake::default()));
    let now = SystemTime::now();
    // a window's worth (100 samples) from the unknown gate, a few from the configured one and
    // from a stray sender (an unknown gate that never fills its window)
    for (g, n) in [("junk", 100), ("kept", 5), ("stray", 5)] {
        let (s, _) = post_json(&app, uniform(g, 1000.0, n)).await;
        assert_eq!(s, StatusCode::NO_CONTENT);
    }
    // silent for a while: the sensors go stale (GateDataStale fires), the stray does not
    state.tick(now + Duration::from_secs(120));
    let stale = |g: &str| {
        state
            .gate_view(g)
            .unwrap()
            .alerts
            .iter()
            .any(|a| a.name == "GateDataStale")
    };
    assert!(stale("junk") && stale("kept"));
    assert!(!stale("stray"), "a stray sender pages nothing");
    // past the expiry: the unknown gates are forgotten with their alerts; the configured one
    // stays
    state.tick(now + Duration::from_secs(601));
    assert!(state.gate_view("junk").is_none() && state.gate_view("stray").is_none());
    assert!(state.alert_state("junk").is_none(), "alert state forgotten");
    assert!(state.gate_view("kept").is_some());
    assert_eq!(metric(&state, "gatewatch_gates_expired_total"), 2.0);
    let m = state.render_metrics();
    // none of its series is left
    let left: Vec<&str> = m.lines().filter(|l| l.contains("gate=\"junk\"")).collect();
    assert!(left.is_empty(), "{left:?}");
    // configured gates never expire
    state.tick(now + Duration::from_secs(86_400));
    assert!(state.gate_view("kept").is_some());
}

/// The log lines of one tick are bounded: 60 gates going silent together logged one line per
/// gate for the stale alerts, then one per gate for the expiry and one per resolved alert (an
/// earlier review saw about 10 000 lines). Now each batch logs its first
/// `GATE_LINES_PER_BATCH` gates and one summary with the rest's count, and every event is still
/// counted (the alerts and the expiry metric see all 60).
#[tokio::test]
async fn a_sweep_where_every_gate_goes_stale_logs_a_bounded_number_of_lines() {
    use gatewatch::service::log_limit::GATE_LINES_PER_BATCH;
    const GATES: usize = 60;
    let (app, state) = app_with(
        config("max_gates = 100\nunknown_gate_expiry_seconds = 600"),
        Arc::new(Fake::default()),
    );
    let now = SystemTime::now();
    for g in 0..GATES {
        // a window's worth: each gate counts as a sensor (a stray's few samples page nothing)
        let (s, _) = post_json(&app, uniform(&format!("g{g}"), 1000.0, 100)).await;
        assert_eq!(s, StatusCode::NO_CONTENT);
    }
    // the ticks' log lines, captured (tick runs on this thread)
    let logs = Arc::new(std::sync::Mutex::new(Vec::<u8>::new()));
    let sink = logs.clone();
    let lines = |f: &dyn Fn()| {
        logs.lock().unwrap().clear();
        let sink = sink.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_ansi(false)
            .with_max_level(tracing::Level::INFO)
            .with_writer(move || Capture(sink.clone()))
            .finish();
        tracing::subscriber::with_default(subscriber, f);
        String::from_utf8(logs.lock().unwrap().clone()).unwrap()
    };
    // every gate silent: GateDataStale fires for all 60 in one sweep
    let stale = lines(&|| state.tick(now + Duration::from_secs(120)));
    let firing = (0..GATES)
        .filter(|g| {
            state
                .gate_view(&format!("g{g}"))
                .unwrap()
                .alerts
                .iter()
                .any(|a| a.name == "GateDataStale")
        })
        .count();
    assert_eq!(firing, GATES, "every gate's alert fired");
    let per_gate = stale.lines().filter(|l| l.contains(" alert gate=")).count();
    assert_eq!(per_gate, GATE_LINES_PER_BATCH, "{stale}");
    let held = GATES - GATE_LINES_PER_BATCH;
    assert!(
        stale.contains(&format!(
            "held_back={held} by_kind=GateDataStale firing: {held}"
        )),
        "{stale}"
    );
    assert_eq!(stale.lines().count(), GATE_LINES_PER_BATCH + 1, "{stale}");
    // past the expiry: 60 expired, 60 alerts resolved, each logged up to the bound
    let expiry = lines(&|| state.tick(now + Duration::from_secs(601)));
    assert_eq!(
        metric(&state, "gatewatch_gates_expired_total"),
        GATES as f64
    );
    let expired = expiry
        .lines()
        .filter(|l| l.contains("unknown gate expired"))
        .count();
    let resolved = expiry
        .lines()
        .filter(|l| l.contains(" alert gate="))
        .count();
    assert_eq!(
        (expired, resolved),
        (GATE_LINES_PER_BATCH, GATE_LINES_PER_BATCH),
        "{expiry}"
    );
    assert!(
        expiry
            .lines()
            .any(|l| l.contains("more unknown gates expired")
                && l.contains(&format!("held_back={held}"))),
        "{expiry}"
    );
    assert!(
        expiry.contains(&format!(
            "held_back={held} by_kind=GateDataStale resolved: {held}"
        )),
        "{expiry}"
    );
    assert_eq!(
        expiry.lines().count(),
        2 * (GATE_LINES_PER_BATCH + 1),
        "{expiry}"
    );
}

/// The log lines `f` writes at level info and above (it runs on this thread).
fn log_of(f: &dyn Fn()) -> String {
    let logs = Arc::new(std::sync::Mutex::new(Vec::<u8>::new()));
    let sink = logs.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_ansi(false)
        .with_max_level(tracing::Level::INFO)
        .with_writer(move || Capture(sink.clone()))
        .finish();
    tracing::subscriber::with_default(subscriber, f);
    let out = logs.lock().unwrap().clone();
    String::from_utf8(out).unwrap()
}

/// Drives the auto-accepted gate `gate` through four windows of the fake's schedule (damped,
/// then three self-excited: `GateNegativeDamping` fires), `token` on each request.
async fn self_excite(
    app: &axum::Router,
    state: &gatewatch::service::state::AppState,
    fake: &Fake,
    gate: &str,
    token: Option<&str>,
) {
    let mut sent = 0usize;
    for k in 0..4 {
        let n = if k == 0 { 100 } else { 50 };
        let body = uniform(gate, sent as f64 / 100.0, n).to_string();
        let (s, v, _) = send(app, "POST", "/api/v1/samples", body, token).await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{v}");
        sent += n;
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    wait_until(|| state.alert_state(gate) == Some("firing")).await;
}

/// The names of `gate`'s firing alerts, from its view.
fn firing_alerts(state: &gatewatch::service::state::AppState, gate: &str) -> Vec<String> {
    state
        .gate_view(gate)
        .map(|v| v.alerts.into_iter().map(|a| a.name).collect())
        .unwrap_or_default()
}

/// An auto-accepted gate whose `GateNegativeDamping` fires when its data stops (a sensor or
/// cable failing on a self-excited gate) is held at the expiry: it keeps its entry, its alerts
/// (`GateDataStale` too) and its series, while a silent gate without that alert expires at the
/// same tick. Before, the expiry resolved the damping alert 600 s into the silence ("resolved"
/// went to Alertmanager and the webhooks), removed its series, and nothing paged any more. The
/// hold is logged once, not at every tick.
#[tokio::test]
async fn a_silent_unknown_gate_with_a_firing_damping_alert_is_held_not_expired() {
    // the self-excited gate takes the first four windows, the calm one the fifth
    let fake = Arc::new(Fake {
        zeta: vec![0.05, -0.02, -0.03, -0.03, 0.05],
        ..Default::default()
    });
    let (app, state) = app_with(config("unknown_gate_expiry_seconds = 600"), fake.clone());
    self_excite(&app, &state, &fake, "excited", None).await;
    let (s, _) = post_json(&app, uniform("calm", 0.0, 100)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    wait_until(|| fake.calls.lock().unwrap().len() == 5 && state.pool().in_flight() == 0).await;
    assert_eq!(state.alert_state("calm"), Some("ok"));
    let now = SystemTime::now();
    // both silent: both go stale
    state.tick(now + Duration::from_secs(120));
    assert_eq!(
        firing_alerts(&state, "excited"),
        ["GateNegativeDamping", "GateDataStale"]
    );
    assert_eq!(firing_alerts(&state, "calm"), ["GateDataStale"]);
    // the expiry: the calm gate goes, the self-excited one is held
    let log = log_of(&|| state.tick(now + Duration::from_secs(601)));
    assert!(state.gate_view("calm").is_none(), "the calm gate expired");
    assert_eq!(
        firing_alerts(&state, "excited"),
        ["GateNegativeDamping", "GateDataStale"],
        "held with its alerts"
    );
    assert_eq!(metric(&state, "gatewatch_gates_expired_total"), 1.0);
    let m = state.render_metrics();
    for series in [
        "gatewatch_alert_firing{alertname=\"GateNegativeDamping\",gate=\"excited\"} 1",
        "gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"excited\"} 1",
        "gatewatch_alert_state{gate=\"excited\",state=\"unknown\"} 1",
    ] {
        assert!(m.lines().any(|l| l == series), "{series}: {m}");
    }
    let held: Vec<&str> = log.lines().filter(|l| l.contains("is held")).collect();
    assert_eq!(held.len(), 1, "{log}");
    assert!(
        held[0].contains("gate=excited")
            && held[0].contains("alert=\"GateNegativeDamping\"")
            && held[0].contains("DELETE /api/v1/gates/{id}"),
        "{log}"
    );
    assert!(
        !log.contains("GateNegativeDamping status=\"resolved\""),
        "{log}"
    );
    // later ticks: still held, and not logged again
    let log = log_of(&|| state.tick(now + Duration::from_secs(3600)));
    assert!(!log.contains("is held"), "{log}");
    assert_eq!(
        firing_alerts(&state, "excited"),
        ["GateNegativeDamping", "GateDataStale"]
    );
    let (_, list, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(list["gates"][0]["gate"], "excited", "{list}");
    assert_eq!(list["gates"][0]["firing"], true, "{list}");
}

/// An auto-accepted gate whose damping falls by 0.1 points a window (sixteen windows, the
/// trend acting from the first: `trend_min_span_seconds = 0`), so that `GateDampingDeclining`
/// fires and `GateNegativeDamping` does not. (A trend predicts no further ahead than its windows
/// reach back: from the eleventh window on here; twelve windows were enough before stop 67.)
/// Silent past the expiry it is held too: the data stopping takes away the evidence, not the
/// decline.
#[tokio::test]
async fn a_silent_unknown_gate_with_a_firing_declining_warning_is_held() {
    const WINDOWS: usize = 16;
    let fake = Arc::new(Fake {
        zeta: (0..WINDOWS).map(|i| 0.02 - 0.001 * i as f64).collect(),
        ..Fake::default()
    });
    let cfg =
        config("unknown_gate_expiry_seconds = 600\n[defaults.alert]\ntrend_min_span_seconds = 0.0");
    let (app, state) = app_with(cfg, fake.clone());
    post_json(&app, uniform("g1", 0.0, 100)).await;
    for i in 1..WINDOWS {
        wait_until(|| fake.calls.lock().unwrap().len() >= i && state.pool().in_flight() == 0).await;
        post_json(&app, uniform("g1", 0.5 + 0.5 * i as f64, 50)).await;
    }
    wait_until(|| fake.calls.lock().unwrap().len() >= WINDOWS && state.pool().in_flight() == 0)
        .await;
    assert_eq!(firing_alerts(&state, "g1"), ["GateDampingDeclining"]);
    let now = SystemTime::now();
    state.tick(now + Duration::from_secs(601));
    assert_eq!(
        firing_alerts(&state, "g1"),
        ["GateDataStale", "GateDampingDeclining"],
        "held"
    );
    assert_eq!(metric(&state, "gatewatch_gates_expired_total"), 0.0);
}

/// A webhook payload's alerts as `(status, alertname, gate)`.
fn hook_alerts(payload: &serde_json::Value) -> Vec<(String, String, String)> {
    let field = |a: &serde_json::Value, f: &[&str]| {
        f.iter()
            .fold(a, |v, k| &v[*k])
            .as_str()
            .unwrap_or("")
            .to_string()
    };
    payload["alerts"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|a| {
                    (
                        field(a, &["status"]),
                        field(a, &["labels", "alertname"]),
                        field(a, &["labels", "gate"]),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Waits (at most 10 s) until the webhook receiver got `(status, alertname, gate)`; returns
/// every alert it got meanwhile.
async fn hook_waits_for(
    hook: &mut tokio::sync::mpsc::Receiver<(std::time::Instant, serde_json::Value)>,
    want: (&str, &str, &str),
) -> Vec<(String, String, String)> {
    let mut seen = Vec::new();
    let found = tokio::time::timeout(Duration::from_secs(10), async {
        while let Some((_, p)) = hook.recv().await {
            for a in hook_alerts(&p) {
                let hit = (a.0.as_str(), a.1.as_str(), a.2.as_str()) == want;
                seen.push(a);
                if hit {
                    return;
                }
            }
        }
    })
    .await;
    assert!(found.is_ok(), "no {want:?} within 10 s; got {seen:?}");
    seen
}

/// `DELETE /api/v1/gates/{id}` (authenticated) forgets a held auto-accepted gate as its expiry
/// would: 200 naming the gate and the alerts resolved, "resolved" delivered to the webhook,
/// no series left, counted apart from the expiry. 404 for a gate the daemon does not know, 409
/// naming `[gates.ID]` for a configured one.
#[tokio::test]
async fn delete_forgets_an_auto_accepted_gate_and_resolves_its_alerts() {
    use store_common::{free_port, receiver};
    let port = free_port();
    let mut hook = receiver(port).await;
    let fake = Arc::new(Fake {
        zeta: vec![0.05, -0.02, -0.03, -0.03],
        ..Default::default()
    });
    let cfg = config(&format!(
        "unknown_gate_expiry_seconds = 600
auth_tokens = [\"{TOKEN}\"]
\
         [notify]\ninitial_backoff_ms = 50\nmax_backoff_ms = 500\n\
         [[notify.webhooks]]\nurl = \"http://127.0.0.1:{port}/hook\"\n\
         [gates.kept]\n"
    ));
    let (app, state) = app_with(cfg, fake.clone());
    self_excite(&app, &state, &fake, "x1", Some(TOKEN)).await;
    hook_waits_for(&mut hook, ("firing", "GateNegativeDamping", "x1")).await;
    // its sensor fails: stale, then held past the expiry
    let now = SystemTime::now();
    state.tick(now + Duration::from_secs(120));
    state.tick(now + Duration::from_secs(601));
    assert_eq!(
        firing_alerts(&state, "x1"),
        ["GateNegativeDamping", "GateDataStale"]
    );
    // the route is behind the tokens
    let (s, _, _) = send(&app, "DELETE", "/api/v1/gates/x1", Body::empty(), None).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    assert!(state.gate_view("x1").is_some());
    let delete = |path: &'static str| send(&app, "DELETE", path, Body::empty(), Some(TOKEN));
    // the operator retires the sensor
    let (s, v, _) = delete("/api/v1/gates/x1").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(
        v,
        json!({"gate": "x1", "resolved": ["GateNegativeDamping", "GateDataStale"]})
    );
    assert!(state.gate_view("x1").is_none() && state.alert_state("x1").is_none());
    // one batch, the damping alert first
    let seen = hook_waits_for(&mut hook, ("resolved", "GateDataStale", "x1")).await;
    let resolved = ("resolved", "GateNegativeDamping", "x1");
    assert!(
        seen.iter()
            .any(|a| (a.0.as_str(), a.1.as_str(), a.2.as_str()) == resolved),
        "{seen:?}"
    );
    assert_eq!(metric(&state, "gatewatch_gates_deleted_total"), 1.0);
    assert_eq!(metric(&state, "gatewatch_gates_expired_total"), 0.0);
    let m = state.render_metrics();
    let left: Vec<&str> = m.lines().filter(|l| l.contains("gate=\"x1\"")).collect();
    assert!(left.is_empty(), "{left:?}");
    assert_eq!(state.pool().remembered_gates(), 0, "no worker memory left");
    // gone: a second DELETE does not know it
    let (s, v, _) = delete("/api/v1/gates/x1").await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{v}");
    assert!(v["error"].as_str().unwrap().contains("`x1`"), "{v}");
    // a configured gate: the configuration would make it again
    let (s, v, _) = delete("/api/v1/gates/kept").await;
    assert_eq!(s, StatusCode::CONFLICT, "{v}");
    let e = v["error"].as_str().unwrap();
    assert!(
        e.contains("[gates.kept]") && e.contains("remove it from the configuration"),
        "{v}"
    );
    assert!(state.gate_view("kept").is_some());
    // it takes no parameter, as the gate view
    let (s, v, _) = delete("/api/v1/gates/kept?force=1").await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    assert_eq!(v["field"], "force", "{v}");
}

/// A `MakeWriter` target: the log lines into a shared buffer.
struct Capture(Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for Capture {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// An expired gate that had been identified leaves no series in a scrape of /metrics: not its
/// model coefficients (whose `coefficient` values depend on the model), intervals, counters,
/// alert series or identification counts.
#[tokio::test]
async fn an_identified_gate_that_expires_leaves_no_series_in_metrics() {
    let fake = Arc::new(Fake::default());
    let (app, state) = app_with(config("unknown_gate_expiry_seconds = 600"), fake.clone());
    let now = SystemTime::now();
    let (s, _) = post_json(&app, uniform("junk", 0.0, 100)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    wait_until(|| fake.calls.lock().unwrap().len() == 1 && state.pool().in_flight() == 0).await;
    let scrape = || async {
        let (s, v, _) = send(&app, "GET", "/metrics", Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK);
        v.as_str().unwrap().to_string()
    };
    let before = scrape().await;
    for series in [
        "gatewatch_model_coefficient{coefficient=\"c1\",gate=\"junk\"}",
        "gatewatch_model_coefficient{coefficient=\"c2\",gate=\"junk\"}",
        "gatewatch_damping_ratio{gate=\"junk\"}",
        "gatewatch_damping_ratio_lower{gate=\"junk\"}",
        "gatewatch_damping_ratio_upper{gate=\"junk\"}",
        "gatewatch_identifications_total{gate=\"junk\",path=\"full\"}",
        "gatewatch_samples_ingested_total{gate=\"junk\"}",
        "gatewatch_alert_state{gate=\"junk\",state=\"ok\"}",
    ] {
        assert!(before.contains(series), "{series} before the expiry");
    }
    assert_eq!(
        state.pool().remembered_gates(),
        1,
        "the pool keeps its tracking memory"
    );
    state.tick(now + Duration::from_secs(601));
    assert!(state.gate_view("junk").is_none());
    assert_eq!(
        state.pool().remembered_gates(),
        0,
        "an expired gate leaves no tracking memory in the pool"
    );
    let after = scrape().await;
    let left: Vec<&str> = after
        .lines()
        .filter(|l| l.contains("gate=\"junk\""))
        .collect();
    assert!(left.is_empty(), "series left behind: {left:?}");
    assert!(after.contains("gatewatch_gates_expired_total 1"), "{after}");
}

/// A gate that expires while its window is being identified, and sends again before that job
/// ends, is a new gate: the old job's result (a window of its earlier life) is not reported on
/// it, nor stored in the pool's memory for it.
#[tokio::test]
async fn a_job_of_an_expired_gate_does_not_report_on_the_gate_that_comes_back() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(600),
        ..Fake::default()
    });
    let (app, state) = app_with(config("unknown_gate_expiry_seconds = 600"), fake.clone());
    let now = SystemTime::now();
    let (s, _) = post_json(&app, uniform("junk", 0.0, 100)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    wait_until(|| state.pool().in_flight() == 1).await;
    state.tick(now + Duration::from_secs(601));
    assert!(state.gate_view("junk").is_none(), "expired");
    // back, with fewer samples than a window: no job of its own yet
    let (s, _) = post_json(&app, uniform("junk", 100.0, 10)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    wait_until(|| fake.calls.lock().unwrap().len() == 1 && state.pool().in_flight() == 0).await;
    let v = state.gate_view("junk").expect("the gate is back");
    assert!(
        v.identification.is_none(),
        "the old life's window reported on the new gate: {:?}",
        v.identification
    );
    assert_eq!(
        state.pool().remembered_gates(),
        0,
        "nor kept as its tracking memory"
    );
    assert_eq!(
        metric(
            &state,
            "gatewatch_identifications_total{gate=\"junk\",path=\"full\"}"
        ),
        0.0
    );
}

#[tokio::test]
async fn the_gate_list_is_paginated_and_visits_every_gate_once() {
    let (app, state) = make_app("max_gates = 2000");
    let batches: Vec<_> = (0..2000)
        .map(|i| json!({"gate": format!("g{i:04}"), "start": 1000.0, "rate_hz": 100.0, "values": [0.5]}))
        .collect();
    let (s, _) = post_json(&app, json!(batches)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    let mut seen = Vec::new();
    let mut uri = "/api/v1/gates?limit=333".to_string();
    loop {
        let (s, v, _) = send(&app, "GET", &uri, Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK, "{v}");
        let page = v["gates"].as_array().unwrap();
        assert!(page.len() <= 333);
        seen.extend(page.iter().map(|g| g["gate"].as_str().unwrap().to_string()));
        // a summary, not the full view: fixed-size fields only
        assert!(page[0].get("alerts").is_none() && page[0].get("samples").is_some());
        match v["next"].as_str() {
            Some(n) => uri = format!("/api/v1/gates?limit=333&after={n}"),
            None => break,
        }
    }
    let expected: Vec<String> = (0..2000).map(|i| format!("g{i:04}")).collect();
    assert_eq!(seen, expected, "every gate exactly once, in id order");
    // default page size, and a bad limit named
    let (_, v, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(v["gates"].as_array().unwrap().len(), 100);
    let (s, v, _) = send(&app, "GET", "/api/v1/gates?limit=5000", Body::empty(), None).await;
    assert_eq!(s, StatusCode::BAD_REQUEST);
    assert_eq!(v["field"], "limit");
    // the page is copied under the state's lock and released before it is serialised: while
    // a page is held (as the handler holds it while serialising), ingestion takes the lock.
    // With the lock still held this same thread would deadlock here.
    let (page, next) = state.gate_page(None, 1000);
    assert_eq!(page.len(), 1000);
    assert_eq!(next.as_deref(), Some("g0999"));
    let (s, _) = post_json(&app, uniform("g0001", 2000.0, 3)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    drop(page);
}

/// An unknown gate's alert restored from the store after a restart, when the gate does not send
/// again, expires `unknown_gate_expiry_seconds` after the start like the gate would have: before,
/// its `GateDataStale` stayed firing for ever, with no gate behind it in the API.
#[tokio::test]
async fn a_restored_alert_of_an_unknown_gate_that_stays_silent_expires_after_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    let cfg = || config("unknown_gate_expiry_seconds = 600\n[gates.kept]\n");
    let with_store = |c: gatewatch::service::config::Config, fake: Arc<Fake>| {
        let p =
            gatewatch::service::storage::Persistence::open(&db, &c.storage, c.sample_lead_bound())
                .expect("store");
        gatewatch::service::state::AppState::with_persistence(c, fake, Some(p)).expect("state")
    };
    // the first run: the junk gate sends a window's worth once, goes stale, and the daemon stops
    {
        let fake = Arc::new(Fake::default());
        let state = with_store(cfg(), fake.clone());
        let app = gatewatch::service::api::router(state.clone());
        let (s, _) = post_json(&app, uniform("junk", 1000.0, 100)).await;
        assert_eq!(s, StatusCode::NO_CONTENT);
        // its window identified and its result stored before the daemon stops: the second
        // run must not open the store while this run's worker may still write to it
        wait_until(|| fake.calls.lock().unwrap().len() == 1 && state.pool().in_flight() == 0).await;
        state.tick(SystemTime::now() + Duration::from_secs(120));
        assert!(state
            .gate_view("junk")
            .unwrap()
            .alerts
            .iter()
            .any(|a| a.name == "GateDataStale"));
        let p = state.persistence.clone().unwrap();
        assert!(p.writer.close(Duration::from_secs(10)), "flushed");
    }
    // the second run: the junk gate never sends again
    let state = with_store(cfg(), Arc::new(Fake::default()));
    let start = SystemTime::now();
    const STALE: &str = "gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"junk\"} 1";
    let firing = || state.render_metrics().lines().any(|l| l == STALE);
    state.tick(start + Duration::from_secs(1));
    assert!(firing(), "restored: {}", state.render_metrics());
    state.tick(start + Duration::from_secs(60));
    assert!(firing(), "not before the expiry");
    state.tick(start + Duration::from_secs(601));
    assert!(!firing());
    assert_eq!(state.alert_state("junk"), None, "expired with its alert");
    assert!(
        state.alert_state("kept").is_some(),
        "a configured gate stays"
    );
    assert_eq!(metric(&state, "gatewatch_gates_expired_total"), 1.0);
    let m = state.render_metrics();
    let left: Vec<&str> = m.lines().filter(|l| l.contains("gate=\"junk\"")).collect();
    assert!(left.is_empty(), "{left:?}");
}

/// `AppState` on the SQLite store at `db`, with `fake` as its analyzer (the configuration has
/// no `[gates.*]` table: every gate is accepted automatically).
fn with_store(
    db: &std::path::Path,
    fake: Arc<Fake>,
) -> (axum::Router, Arc<gatewatch::service::state::AppState>) {
    with_store_max(db, fake, 64)
}

/// [`with_store`] with `server.max_gates = max_gates`.
fn with_store_max(
    db: &std::path::Path,
    fake: Arc<Fake>,
    max_gates: usize,
) -> (axum::Router, Arc<gatewatch::service::state::AppState>) {
    let c = config(&format!(
        "unknown_gate_expiry_seconds = 600\nmax_gates = {max_gates}\n"
    ));
    let p = gatewatch::service::storage::Persistence::open(db, &c.storage, c.sample_lead_bound())
        .expect("store");
    let state =
        gatewatch::service::state::AppState::with_persistence(c, fake, Some(p)).expect("state");
    (gatewatch::service::api::router(state.clone()), state)
}

const G7_FIRING: &str = "gatewatch_alert_firing{alertname=\"GateNegativeDamping\",gate=\"g7\"}";

/// A first run on `db`: the auto-accepted gate g7 goes self-excited (`GateNegativeDamping`
/// fires), then the daemon stops with its writes flushed. The samples sent so far.
async fn g7_fires_then_stops(db: &std::path::Path) -> usize {
    let mut sent = 0usize;
    let fake = Arc::new(Fake {
        zeta: vec![0.05, -0.02, -0.03, -0.03],
        ..Default::default()
    });
    let (app, state) = with_store(db, fake.clone());
    for k in 0..4 {
        let n = if k == 0 { 100 } else { 50 };
        post_json(&app, uniform("g7", sent as f64 / 100.0, n)).await;
        sent += n;
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    wait_until(|| state.alert_state("g7") == Some("firing")).await;
    assert_eq!(metric(&state, G7_FIRING), 1.0);
    let p = state.persistence.clone().unwrap();
    assert!(p.writer.close(Duration::from_secs(10)), "flushed");
    sent
}

/// An auto-accepted gate (no `[gates.*]` table) firing `GateNegativeDamping` when the daemon
/// stops: after the restart its `gatewatch_alert_firing` series stays 1 once its samples
/// arrive again. Before, its first samples reset the gauge to 0 (the shipped rule
/// `gatewatch_alert_firing == 1` resolved on a gate still self-excited) while the API and
/// `gatewatch_alert_state` still said firing.
#[tokio::test]
async fn a_restored_firing_unknown_gate_keeps_its_firing_gauge_when_it_sends_again() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    let sent = g7_fires_then_stops(&db).await;
    let (app, state) = with_store(&db, Arc::new(Fake::default()));
    assert_eq!(metric(&state, G7_FIRING), 1.0, "restored");
    let (s, _) = post_json(&app, uniform("g7", sent as f64 / 100.0, 20)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    assert_eq!(state.alert_state("g7"), Some("firing"));
    assert_eq!(
        metric(
            &state,
            "gatewatch_alert_state{gate=\"g7\",state=\"firing\"}"
        ),
        1.0
    );
    assert_eq!(metric(&state, G7_FIRING), 1.0, "{}", state.render_metrics());
}

/// The same restart: before any new sample, the API lists the auto-accepted gate with its
/// firing alert (it was absent, `/api/v1/gates/g7` said unknown gate, while `/metrics` showed
/// its alert firing).
#[tokio::test]
async fn a_restored_unknown_gate_is_in_the_api_before_its_first_sample() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    g7_fires_then_stops(&db).await;
    let (app, state) = with_store(&db, Arc::new(Fake::default()));
    let (s, list, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK, "{list}");
    let gates = list["gates"].as_array().expect("gates");
    assert_eq!(gates.len(), 1, "{list}");
    assert_eq!(gates[0]["gate"], "g7", "{list}");
    assert_eq!(gates[0]["firing"], true, "{list}");
    let (s, view, _) = send(&app, "GET", "/api/v1/gates/g7", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK, "{view}");
    assert_eq!(view["alert_state"], "firing", "{view}");
    assert!(
        view["alerts"].to_string().contains("GateNegativeDamping"),
        "{view}"
    );
    assert_eq!(metric(&state, G7_FIRING), 1.0);
}

/// More gates restored than `server.max_gates` leaves room for: the firing one gets its entry
/// (though its name sorts last), the other keeps only its alert state, is not in the API, and
/// is forgotten `unknown_gate_expiry_seconds` after the start as before.
#[tokio::test]
async fn restored_gates_beyond_max_gates_leave_the_firing_one_in_the_api() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    g7_fires_then_stops(&db).await;
    // a second run: gate "a1" sends one window (damped), then the daemon stops
    {
        let fake = Arc::new(Fake::default());
        let (app, state) = with_store(&db, fake.clone());
        post_json(&app, uniform("a1", 0.0, 100)).await;
        wait_until(|| fake.calls.lock().unwrap().len() == 1 && state.pool().in_flight() == 0).await;
        wait_until(|| state.alert_state("a1") == Some("ok")).await;
        let p = state.persistence.clone().unwrap();
        assert!(p.writer.close(Duration::from_secs(10)), "flushed");
    }
    let (_, state) = with_store_max(&db, Arc::new(Fake::default()), 1);
    assert_eq!(state.gate_ids(), ["g7"], "the firing gate first");
    assert!(state.gate_view("a1").is_none());
    assert_eq!(state.alert_state("a1"), Some("ok"), "its alert state kept");
    let start = SystemTime::now();
    state.tick(start + Duration::from_secs(601));
    assert_eq!(state.alert_state("a1"), None, "forgotten after the expiry");
}

/// A stored alert state that does not decode (a newer or damaged row) is skipped at start and
/// counted in `gatewatch_store_restore_skipped_total{what="alert_state"}` (before: an error
/// line only), the other gates' states restored.
#[tokio::test]
async fn an_undecodable_alert_state_is_counted_at_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    g7_fires_then_stops(&db).await;
    {
        use gatewatch::store::{SqliteStore, Store, WriteBatch};
        let store = SqliteStore::open(&db, 64).expect("open");
        store
            .write(&WriteBatch {
                alert_states: vec![("g9".into(), "{not json".into())],
                ..Default::default()
            })
            .expect("write");
    }
    let (_, state) = with_store(&db, Arc::new(Fake::default()));
    assert_eq!(
        metric(
            &state,
            "gatewatch_store_restore_skipped_total{what=\"alert_state\"}"
        ),
        1.0
    );
    assert_eq!(state.alert_state("g9"), None);
    assert_eq!(state.alert_state("g7"), Some("firing"));
}

/// A stored gate whose id is not valid (`..`: a store of an older version, or a SQLite file
/// edited by hand) is not restored at start: its alert state and its history are skipped with a
/// warning naming the id, quoted, and the file (the alert state also counted), never a panic;
/// the other gates are restored as before. It was restored unchecked, and the API listed a
/// firing gate `..` that no URL can read.
#[tokio::test]
async fn a_stored_gate_with_an_invalid_id_is_skipped_at_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    g7_fires_then_stops(&db).await;
    {
        // g7's rows copied under the id `..`, as a hand-edited file holds them; their windows
        // end now (g7's end in 1970, sample time, and the store's writer prunes them by age at
        // start, in a race with the resume's read)
        let c = rusqlite::Connection::open(&db).expect("open the store");
        c.execute_batch(
            "INSERT INTO alert_state (gate, state) SELECT '..', state FROM alert_state WHERE gate = 'g7';
             CREATE TEMP TABLE dots AS SELECT * FROM history WHERE gate = 'g7';
             UPDATE dots SET gate = '..', window_end = unixepoch('now') - 60 + rowid;
             INSERT INTO history SELECT * FROM dots;",
        )
        .expect("rows of gate ..");
        let n: i64 = c
            .query_row("SELECT count(*) FROM history WHERE gate = '..'", [], |r| {
                r.get(0)
            })
            .expect("count");
        assert!(n > 0, "g7 has history to copy");
    }
    let logs = Arc::new(std::sync::Mutex::new(Vec::<u8>::new()));
    let sink = logs.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_ansi(false)
        .with_max_level(tracing::Level::WARN)
        .with_writer(move || Capture(sink.clone()))
        .finish();
    let (app, state) = tracing::subscriber::with_default(subscriber, || {
        with_store(&db, Arc::new(Fake::default()))
    });
    let logs = String::from_utf8(logs.lock().unwrap().clone()).unwrap();
    assert_eq!(state.alert_state(".."), None, "{logs}");
    assert_eq!(state.gate_ids(), ["g7"], "{logs}");
    assert_eq!(state.alert_state("g7"), Some("firing"));
    assert_eq!(metric(&state, G7_FIRING), 1.0);
    let (s, list, _) = send(&app, "GET", "/api/v1/gates", Body::empty(), None).await;
    assert_eq!(s, StatusCode::OK, "{list}");
    assert!(!list.to_string().contains("\"..\""), "{list}");
    assert_eq!(
        metric(
            &state,
            "gatewatch_store_restore_skipped_total{what=\"alert_state\"}"
        ),
        1.0
    );
    for what in ["alert state", "history"] {
        let line = logs
            .lines()
            .find(|l| l.contains(&format!("stored {what} of gate \"..\"")))
            .unwrap_or_else(|| panic!("no warning for the {what} of gate ..: {logs}"));
        assert!(line.contains(" WARN "), "{line}");
        assert!(line.contains("not a valid gate id"), "{line}");
        assert!(line.contains(&db.display().to_string()), "{line}");
    }
}

/// `AppState` on the SQLite store at `db` with the test configuration and `extra` in
/// `[server]`.
fn with_store_config(
    db: &std::path::Path,
    extra: &str,
) -> (axum::Router, Arc<gatewatch::service::state::AppState>) {
    let c = config(extra);
    let p = gatewatch::service::storage::Persistence::open(db, &c.storage, c.sample_lead_bound())
        .expect("store");
    let state = gatewatch::service::state::AppState::with_persistence(
        c,
        Arc::new(Fake::default()),
        Some(p),
    )
    .expect("state");
    (gatewatch::service::api::router(state.clone()), state)
}

/// An alert state restored from the store with no gate behind it (here the configuration no
/// longer accepts unknown gates) whose `GateNegativeDamping` fires is held by the sweep
/// `unknown_gate_expiry_seconds` after the start, as a silent gate is; `DELETE` forgets it, and
/// the store with it: the next start does not bring it back.
#[tokio::test]
async fn a_held_restored_alert_state_is_forgotten_by_delete_and_in_the_store() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    g7_fires_then_stops(&db).await;
    {
        let (app, state) = with_store_config(
            &db,
            "unknown_gate_expiry_seconds = 600\naccept_unknown_gates = false",
        );
        assert!(state.gate_view("g7").is_none(), "no entry: not accepted");
        let start = SystemTime::now();
        state.tick(start + Duration::from_secs(601));
        assert_eq!(state.alert_state("g7"), Some("unknown"), "held");
        assert_eq!(metric(&state, G7_FIRING), 1.0);
        let (s, v, _) = send(&app, "DELETE", "/api/v1/gates/g7", Body::empty(), None).await;
        assert_eq!(s, StatusCode::OK, "{v}");
        assert_eq!(v["gate"], "g7", "{v}");
        assert_eq!(v["resolved"][0], "GateNegativeDamping", "{v}");
        assert_eq!(state.alert_state("g7"), None);
        let p = state.persistence.clone().unwrap();
        assert!(p.writer.close(Duration::from_secs(10)), "flushed");
    }
    let (_, state) = with_store_config(&db, "unknown_gate_expiry_seconds = 600");
    assert_eq!(state.alert_state("g7"), None, "not restored");
    assert!(state.gate_ids().is_empty());
    assert_eq!(metric(&state, G7_FIRING), 0.0);
}

/// An unknown gate that expired is not restored at the next start: the expiry deletes its
/// stored alert state. Before, the store kept its last state, and the restart sent its
/// `GateDataStale` to the receivers as firing again, for a gate forgotten before the restart,
/// until it expired a second time.
#[tokio::test]
async fn an_expired_gate_is_not_restored_at_the_next_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("gw.db");
    let extra = "unknown_gate_expiry_seconds = 600";
    {
        let (app, state) = with_store_config(&db, extra);
        let (s, _) = post_json(&app, uniform("junk", 1000.0, 100)).await;
        assert_eq!(s, StatusCode::NO_CONTENT);
        // the window's identification applied and its write queued before the gate expires:
        // a result computed before the forget and queued after it restored an `ok` state in
        // one CI rehearsal (the daemon's race is noted on issue 8, not fixed)
        wait_until(|| {
            state
                .gate_view("junk")
                .is_some_and(|v| v.identification.is_some())
        })
        .await;
        tokio::time::sleep(Duration::from_millis(100)).await;
        let now = SystemTime::now();
        state.tick(now + Duration::from_secs(120));
        assert_eq!(firing_alerts(&state, "junk"), ["GateDataStale"]);
        state.tick(now + Duration::from_secs(601));
        assert!(state.gate_view("junk").is_none(), "expired");
        let p = state.persistence.clone().unwrap();
        assert!(p.writer.close(Duration::from_secs(10)), "flushed");
    }
    let (_, state) = with_store_config(&db, extra);
    assert_eq!(state.alert_state("junk"), None, "not restored");
    let m = state.render_metrics();
    assert!(!m.contains("gate=\"junk\""), "{m}");
}
