//! A real server on port 0: the raw TCP listener, overload and timeouts, readiness and the
//! graceful shutdown, the simulate client, and the real analyzers.

use crate::service_common;

use std::sync::Arc;
use std::time::Duration;

use gatewatch::service::config::Config;
use gatewatch::service::server::Listeners;
use serde_json::{json, Value};

use service_common::*;

#[tokio::test]
async fn tcp_listener_keeps_the_connection_after_bad_lines() {
    use tokio::io::AsyncWriteExt;
    let r = start_default("").await;
    let mut s = connect_and_write(
        r.tcp,
        b"m,gate=t1 force=1 1000000000000\nthis is not line protocol\nm,gate=t1 force=NaN 1000010000000\n",
    )
    .await;
    // beyond the analysis' bound (+-1e100): refused like NaN, not put in the window
    s.write_all(b"m,gate=t1 force=-1e308 1000015000000\n")
        .await
        .unwrap();
    s.write_all(b"m,gate=t1 force=2 1000020000000\r\n")
        .await
        .unwrap();
    s.write_all(&vec![b'x'; 70_000]).await.unwrap();
    s.write_all(b"\nm,gate=t1 force=3 1000030000000\n")
        .await
        .unwrap();
    s.flush().await.unwrap();
    let addr = r.http;
    wait_for_samples(addr, "t1", 3).await;
    let (_, m) = get(addr, "/metrics").await;
    assert!(
        m.contains("gatewatch_samples_rejected_total{reason=\"bad_line\"} 2"),
        "{m}"
    );
    assert!(m.contains("gatewatch_samples_rejected_total{reason=\"non_finite\"} 1"));
    assert!(
        m.contains("gatewatch_samples_rejected_total{reason=\"out_of_range\"} 1"),
        "{m}"
    );
    drop(s);
    stop(r).await;
}

#[tokio::test]
async fn tcp_an_over_long_line_is_skipped_and_the_next_line_arrives() {
    use tokio::io::AsyncWriteExt;
    let r = start_default("[ingest]\ntcp_max_line_bytes = 64").await;
    let mut s = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    // exactly 64 bytes before its newline: kept
    let head = "m,gate=long force=1.";
    let tail = " 1000000000000";
    let exact = format!("{head}{}{tail}\n", "0".repeat(64 - head.len() - tail.len()));
    assert_eq!(exact.len(), 65);
    s.write_all(exact.as_bytes()).await.unwrap();
    // 65 bytes, then a good line in the same write
    s.write_all(format!("{}\nm,gate=long force=2 1000010000000\n", "x".repeat(65)).as_bytes())
        .await
        .unwrap();
    s.flush().await.unwrap();
    wait_for_samples(r.http, "long", 2).await;
    // an over-long line arriving in pieces is discarded across the reads
    for _ in 0..4 {
        s.write_all(&[b'y'; 50]).await.unwrap();
        s.flush().await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    s.write_all(b"\nm,gate=long force=3 1000020000000\n")
        .await
        .unwrap();
    s.flush().await.unwrap();
    wait_for_samples(r.http, "long", 3).await;
    let (_, m) = get(r.http, "/metrics").await;
    assert!(
        m.contains("gatewatch_samples_rejected_total{reason=\"bad_line\"} 2"),
        "{m}"
    );
    drop(s);
    stop(r).await;
}

#[tokio::test]
async fn tcp_invalid_utf8_mid_stream_is_counted_and_skipped() {
    use tokio::io::AsyncWriteExt;
    let r = start_default("").await;
    let mut s = connect_and_write(
        r.tcp,
        b"m,gate=u8 force=1 1000000000000\n\
          m,gate=u8 force=\xff\xfe 1000010000000\n\
          m,gate=u8 force=2 1000020000000\n",
    )
    .await;
    s.flush().await.unwrap();
    wait_for_samples(r.http, "u8", 2).await;
    // the connection is kept
    s.write_all(b"m,gate=u8 force=3 1000030000000\n")
        .await
        .unwrap();
    s.flush().await.unwrap();
    wait_for_samples(r.http, "u8", 3).await;
    let (_, m) = get(r.http, "/metrics").await;
    assert!(
        m.contains("gatewatch_samples_rejected_total{reason=\"bad_line\"} 1"),
        "{m}"
    );
    drop(s);
    stop(r).await;
}

#[tokio::test]
async fn a_tcp_burst_is_applied_whole_and_in_order() {
    // 10 000 lines (about 400 KB, over MAX_BATCH_BYTES) in one write: they reach the blocking pool in
    // one or more batches, each line applied on its own and in order (none out of order).
    use tokio::io::AsyncWriteExt;
    let r = start_default("").await;
    let mut s = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    let mut burst = String::new();
    for i in 0..10_000u64 {
        burst.push_str(&format!(
            "m,gate=burst force={i} {}\n",
            1_000_000_000_000u64 + i * 10_000_000
        ));
    }
    s.write_all(burst.as_bytes()).await.unwrap();
    s.flush().await.unwrap();
    let addr = r.http;
    wait_for_get(
        addr,
        "/api/v1/gates/burst",
        20,
        "every line ingested",
        |_, body| body.contains("\"samples_total\":10000"),
    )
    .await;
    let (_, m) = get(addr, "/metrics").await;
    // exported from the start, all still 0
    assert!(m.contains("gatewatch_samples_rejected_total{"), "{m}");
    assert!(
        m.lines()
            .filter(|l| l.starts_with("gatewatch_samples_rejected_total{"))
            .all(|l| l.ends_with(" 0")),
        "{m}"
    );
    drop(s);
    stop(r).await;
}

#[tokio::test]
async fn tcp_connection_limit() {
    use tokio::io::AsyncReadExt;
    let r = start_default("max_tcp_connections = 1").await;
    let first = connect_and_write(r.tcp, b"m,gate=t2 force=1 1000000000000\n").await;
    let addr = r.http;
    wait_for_samples(addr, "t2", 1).await;
    let mut second = tokio::net::TcpStream::connect(r.tcp).await.unwrap();
    let mut buf = [0u8; 1];
    let n = tokio::time::timeout(Duration::from_secs(10), second.read(&mut buf))
        .await
        .unwrap()
        .unwrap_or(0);
    assert_eq!(n, 0, "the second connection is closed");
    let (_, m) = get(addr, "/metrics").await;
    assert!(
        m.contains("gatewatch_tcp_connections_rejected_total{reason=\"connection_limit\"} 1"),
        "{m}"
    );
    assert!(
        m.contains("gatewatch_tcp_connections_rejected_total{reason=\"not_allowed\"} 0"),
        "{m}"
    );
    drop(first);
    stop(r).await;
}

#[tokio::test]
async fn overload_is_503_with_retry_after() {
    let r = start_default("max_concurrent_requests = 1").await;
    // hold the only slot: a request whose body never completes
    let hold = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\ncontent-length: 1000\r\n\r\n{\"gate\"",
    )
    .await;
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
    wait_for_get(addr, "/healthz", 10, "serving again", |status, _| {
        status == 200
    })
    .await;
    // a request that never completes does not hold the shutdown beyond the grace period
    let hold = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\n{",
    )
    .await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    stop(r).await;
    drop(hold);
}

#[tokio::test]
async fn full_ingest_slots_are_503_while_the_api_still_answers() {
    let r = start_default("max_concurrent_ingest = 1").await;
    let hold = connect_and_write(
        r.http,
        b"POST /api/v2/write HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\nm,gate=",
    )
    .await;
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
    use tokio::io::AsyncReadExt;
    let r = start_default("request_timeout_seconds = 0.2").await;
    let mut s = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\n{",
    )
    .await;
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

/// A request whose body has wholly arrived when the request timeout runs out is finished and
/// answered for what it did. The handler was dropped at the deadline while its parsing and
/// applying went on in the blocking pool: 408 ("nothing changed, retry") for samples that
/// were applied, and the request's admission freed while it still held its body. Here the
/// timeout (10 ms) runs out while a 4 MB body, read at once, is parsed: each answer must say
/// what happened (2xx: its samples are in; 408: none are). A body still arriving at the
/// deadline gets its 408, and nothing of it is applied.
#[tokio::test]
async fn a_body_read_before_the_deadline_is_answered_for_what_it_did() {
    use axum::body::Body;
    use axum::http::StatusCode;
    use futures_util::StreamExt;
    let (app, _) = make_app("request_timeout_seconds = 0.01");
    let samples = |gate: &str| {
        json!({"gate": gate, "start": 1000.0, "rate_hz": 100.0, "values": vec![0.5; 990_000]})
            .to_string()
    };
    let request = |body: Body| {
        axum::http::Request::builder()
            .method("POST")
            .uri("/api/v1/samples")
            .header("content-type", "application/json")
            .body(body)
            .unwrap()
    };
    let stored = |v: &Value| v["window"]["samples_total"].as_u64();
    for i in 0..3 {
        let gate = format!("in_time{i}");
        let body = samples(&gate);
        assert!(body.len() < 4 * 1024 * 1024);
        let r = tower::ServiceExt::oneshot(app.clone(), request(Body::from(body)))
            .await
            .unwrap();
        // time for work the answer did not wait for to land (it did before: the 408 came while
        // the blocking pool still parsed)
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (status, v, _) = send(&app, "GET", &format!("/api/v1/gates/{gate}"), "", None).await;
        match r.status() {
            StatusCode::NO_CONTENT => assert_eq!(stored(&v), Some(990_000), "{v}"),
            StatusCode::REQUEST_TIMEOUT => {
                assert_eq!(
                    status,
                    StatusCode::NOT_FOUND,
                    "a 408 whose samples went in: {v}"
                )
            }
            other => panic!("{other}"),
        }
    }
    // half a body, and the client goes quiet: 408, nothing applied
    let half = samples("too_late");
    let half = half[..half.len() / 2].to_string();
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<String, std::io::Error>>(1);
    tx.send(Ok(half)).await.unwrap();
    let stream = futures_util::stream::unfold(rx, |mut rx| async move {
        rx.recv().await.map(|chunk| (chunk, rx))
    })
    .boxed();
    let r = tower::ServiceExt::oneshot(app.clone(), request(Body::from_stream(stream)))
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::REQUEST_TIMEOUT);
    drop(tx);
    let (status, _, _) = send(&app, "GET", "/api/v1/gates/too_late", "", None).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
}

/// A request dropped while its body is parsed (its client gone) keeps its place in
/// `max_concurrent_ingest` until the blocking work it started has finished: the place was given
/// back with the handler's future while the blocking pool still held and parsed the body, so
/// clients that disconnect at once could pile up parses past every bound. Whenever the place
/// comes back, the request's effect is final.
#[tokio::test]
async fn a_request_dropped_mid_parse_keeps_its_admission_until_its_work_ends() {
    use axum::body::Body;
    let (app, state) = make_app("");
    let places = state.config.server.max_concurrent_ingest;
    for i in 0..3 {
        let gate = format!("gone{i}");
        let body = json!({"gate": gate, "start": 1000.0, "rate_hz": 100.0,
            "values": vec![0.5; 990_000]})
        .to_string();
        let req = axum::http::Request::builder()
            .method("POST")
            .uri("/api/v1/samples")
            .header("content-type", "application/json")
            .body(Body::from(body))
            .unwrap();
        // the client goes away 2 ms in: the request's future is dropped
        let _ = tokio::time::timeout(
            Duration::from_millis(2),
            tower::ServiceExt::oneshot(app.clone(), req),
        )
        .await;
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        while state.ingest_permits.available_permits() < places {
            assert!(
                std::time::Instant::now() < deadline,
                "the place never came back"
            );
            tokio::time::sleep(Duration::from_micros(200)).await;
        }
        let uri = format!("/api/v1/gates/{gate}");
        let (at_release, v, _) = send(&app, "GET", &uri, "", None).await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (later, w, _) = send(&app, "GET", &uri, "", None).await;
        assert_eq!(
            (at_release, v["window"]["samples_total"].clone()),
            (later, w["window"]["samples_total"].clone()),
            "the work went on after the request's place was given back"
        );
    }
}

#[tokio::test]
async fn readiness_and_graceful_shutdown_with_a_job_in_flight() {
    let fake = Arc::new(Fake {
        sleep: Duration::from_millis(500),
        ..Default::default()
    });
    let r = start("", fake.clone()).await;
    let addr = r.http;
    wait_for_get(addr, "/readyz", 10, "ready", |status, _| status == 200).await;
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
async fn shutdown_with_everything_stuck_takes_one_grace_period() {
    // A worker stuck in the numerics and an HTTP request that never completes: every drain
    // shares one deadline, so the shutdown takes one grace period (2 s), not one per drain
    // (which took 4 s and more). The bound is what tells the two apart: under two grace
    // periods, which leaves a loaded machine 1.8 s of slack; and the stuck worker is given
    // its grace period, not abandoned early.
    let fake = Arc::new(Fake {
        sleep: Duration::from_secs(30),
        ..Default::default()
    });
    let r = start("", fake.clone()).await;
    let c = reqwest::Client::new();
    let resp = c
        .post(format!("http://{}/api/v1/samples", r.http))
        .body(uniform("g1", 0.0, 100).to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(resp.status(), 204);
    wait_until(|| !fake.calls.lock().unwrap().is_empty()).await;
    let hold = connect_and_write(
        r.http,
        b"POST /api/v1/samples HTTP/1.1\r\nhost: x\r\ncontent-length: 1000\r\n\r\n{",
    )
    .await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    let began = std::time::Instant::now();
    stop(r).await;
    let took = began.elapsed();
    assert!(
        took >= Duration::from_millis(1_950) && took < Duration::from_millis(3_800),
        "shutdown took {took:?}: one grace period (2 s) with everything stuck, not two"
    );
    drop(hold);
}

#[tokio::test]
async fn simulate_client_streams_through_every_protocol() {
    use gatewatch::service::client::{
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
            duration: Some(2.0),
            seed: 7,
            protocol,
            rate: 100.0,
            token: Some(TOKEN.into()),
            chunk_seconds: 0.1,
            start: Some(1000.0),
            onset_hold: Some(1.0),
            onset_ramp: Some(1.0),
            sensor: Default::default(),
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
    // without --start, a stream faster than real time is sent from the past: 700 s of samples
    // as fast as possible stay within the daemon's max_future_seconds (600 s by default), which
    // refused them from the 600th second when the stream started now
    let args = SimulateArgs {
        url: format!("http://{}", r.http),
        tcp_addr: r.tcp.to_string(),
        gate: "sf".into(),
        scenario: Scenario::Stable,
        speed: 0.0,
        duration: Some(700.0),
        seed: 3,
        protocol: Protocol::Json,
        rate: 100.0,
        token: Some(TOKEN.into()),
        chunk_seconds: 10.0,
        start: None,
        onset_hold: None,
        onset_ramp: None,
        sensor: Default::default(),
    };
    let mut sim = simulator(&args).unwrap();
    let n = simulate_with_source(&args, |b: &mut [f64]| sim.fill(b))
        .await
        .expect("every chunk accepted");
    assert_eq!(n, 70_000);
    // a wrong token is an error, not a hang
    let args = SimulateArgs {
        url: format!("http://{}", r.http),
        tcp_addr: r.tcp.to_string(),
        gate: "x".into(),
        scenario: Scenario::Stable,
        speed: 0.0,
        duration: Some(0.5),
        seed: 1,
        protocol: Protocol::Json,
        rate: 100.0,
        token: Some("wrong-token-0123456789".into()),
        chunk_seconds: 0.1,
        start: None,
        onset_hold: None,
        onset_ramp: None,
        sensor: Default::default(),
    };
    let e = simulate_with_source(&args, |b: &mut [f64]| b.fill(0.0))
        .await
        .unwrap_err();
    assert!(e.to_string().contains("401"), "{e}");
    stop(r).await;
}

#[test]
fn simulate_scenarios_map_to_the_simulator_and_are_reproducible() {
    use gatewatch::service::client::{simulator, Protocol, Scenario, SimulateArgs};
    let args = |scenario| SimulateArgs {
        url: String::new(),
        tcp_addr: String::new(),
        gate: "g1".into(),
        scenario,
        speed: 0.0,
        duration: Some(10.0),
        seed: 3,
        protocol: Protocol::Json,
        rate: 200.0,
        token: None,
        chunk_seconds: 0.1,
        start: None,
        onset_hold: Some(5.0),
        onset_ramp: Some(10.0),
        sensor: Default::default(),
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
    bad.onset_ramp = Some(-1.0);
    assert!(simulator(&bad).is_err());
    // without `--onset-*` and `--duration`, `simulate --scenario onset` is `bench warning`'s onset
    // (+2 % for 120 s, a 60 s ramp, 300 s in all) and the slow drift runs past its zero crossing
    // (720 s): before, the onset held 60 s and ramped over 300 s, and every scenario stopped at
    // 600 s
    let plain = |scenario| SimulateArgs {
        duration: None,
        onset_hold: None,
        onset_ramp: None,
        ..args(scenario)
    };
    let onset = plain(Scenario::Onset);
    assert_eq!(
        onset.named_scenario(),
        Some(gatewatch::simulate::ScenarioName::Onset)
    );
    assert_eq!(onset.effective_duration(), 300.0);
    let sim = simulator(&onset).unwrap();
    assert_eq!(sim.true_zeta(100.0), 0.02);
    assert!((sim.true_zeta(150.0)).abs() < 1e-12);
    assert_eq!(sim.true_zeta(200.0), -0.02);
    assert!(plain(Scenario::SlowDrift).effective_duration() > 720.0);
    // one `--onset-*` flag shapes the onset; the other keeps the bench's value
    let shaped = SimulateArgs {
        onset_ramp: Some(300.0),
        ..plain(Scenario::Onset)
    };
    assert_eq!(shaped.named_scenario(), None);
    assert_eq!(shaped.onset_shape(), (120.0, 300.0));
    assert_eq!(shaped.effective_duration(), 600.0);
}

#[tokio::test]
async fn real_analyzers_never_take_the_daemon_down() {
    // `server::run` with the real per-gate analyzers: whatever the numerics do (succeed, refuse,
    // or panic while unfinished), the daemon keeps serving and reports the outcome.
    gatewatch::service::client::ensure_crypto_provider();
    // `server::run` opens the store: a file of this test's own, not one in the checkout
    let dir = tempfile::tempdir().unwrap();
    let cfg = Config::from_toml(&format!(
        "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\nshutdown_grace_seconds = 1.0\n\
         [storage]\npath = \"{}\"\n\
         [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 1.0\npopulation = 8\ngenerations = 5\nmax_past_seconds = 0.0\n",
        dir.path().join("gw.db").display()
    ))
    .unwrap();
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = http.local_addr().unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(gatewatch::service::server::run(
        cfg,
        Listeners::http_only(http),
        async move {
            let _ = rx.await;
        },
    ));
    let c = reqwest::Client::new();
    // 5 s of samples: the first window is due within two cadences (1 s each, staggered)
    let values: Vec<f64> = (0..500)
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
    // Until g1's window was analysed: its view holds an identification or the reason there is
    // none. (Every `identification_failures_total` series exists at 0 from the start, so the
    // metrics alone said nothing: this waited for no analysis until stop 67.)
    let view = tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            let (status, body) = get(addr, "/api/v1/gates/g1").await;
            if status == 200 {
                let v: serde_json::Value = serde_json::from_str(&body).unwrap();
                if !v["identification"].is_null() || !v["last_error"].is_null() {
                    break v;
                }
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("the identification finished or failed");
    assert!(view["analysed_until"].as_f64().is_some(), "{view}");
    assert_eq!(get(addr, "/healthz").await.0, 200);
    assert_eq!(get(addr, "/api/v1/gates/g1").await.0, 200);
    let _ = tx.send(());
    tokio::time::timeout(Duration::from_secs(15), task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
}
