//! `gatewatch serve` with `[storage] backend = "nats"` against a REAL `nats-server` (skipped
//! when it is not installed, failed under CI): a simulated gate streamed in is identified and
//! its history lands in the server's stream; a configured gate that never sends fires
//! `GateDataStale`, whose alert state and notification land there too; after the daemon is
//! killed and started again, it serves the first run's history from the server and resumes the
//! stored alert state instead of firing afresh. Every wait is bounded.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use gatewatch::store::{HistoryQuery, NatsOptions, NatsStore, Store};
use serde_json::Value;

mod nats_common;
use nats_common::{free_port, nats_installed, NatsServer};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const WAIT: Duration = Duration::from_secs(60);

/// The daemon's configuration: the NATS backend, a gate `g1` that is streamed, a gate `g2` that
/// never sends (stale after 1 s), a webhook nobody listens to (its row stays in the outbox).
fn write_config(dir: &Path, nats_url: &str, http_port: u16) -> PathBuf {
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{http_port}\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
             [storage]\nbackend = \"nats\"\nnats_url = \"{nats_url}\"\nnats_prefix = \"E2E\"\n\
             [notify]\ninitial_backoff_ms = 100\nmax_backoff_ms = 300\nresend_interval_seconds = 0\n\
             [[notify.webhooks]]\nurl = \"http://127.0.0.1:{}/hook\"\n\
             [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
             [defaults.alert]\nstale_after_seconds = 1.0\n\
             [gates.g1]\n[gates.g2]\n",
            free_port()
        ),
    )
    .expect("write config");
    cfg
}

fn serve(cfg: &Path, log: &Path) -> Child {
    Command::new(BIN)
        .args(["serve", "--config"])
        .arg(cfg)
        .env("GATEWATCH_LOG_LEVEL", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).expect("log"))
        .spawn()
        .expect("spawn gatewatch serve")
}

/// Waits for `/readyz`; fails with the daemon's log when it exits or is not ready in time.
async fn wait_ready(client: &reqwest::Client, url: &str, child: &mut Child, log: &Path) {
    let deadline = Instant::now() + WAIT;
    loop {
        if let Ok(r) = client.get(format!("{url}/readyz")).send().await {
            if r.status().is_success() {
                return;
            }
        }
        let exited = child.try_wait().ok().flatten();
        assert!(
            exited.is_none() && Instant::now() < deadline,
            "daemon not ready ({exited:?}): {}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// One second of a simulated stable gate at 100 Hz, starting at `start` (Unix seconds).
fn second(sim: &mut gatewatch::simulate::GateSimulator, start: f64) -> Value {
    let mut values = vec![0.0; 100];
    sim.fill(&mut values);
    serde_json::json!({"gate": "g1", "start": start, "rate_hz": 100.0, "values": values})
}

fn query(gate: &str) -> HistoryQuery {
    HistoryQuery {
        gate: gate.into(),
        from: None,
        to: None,
        limit: 1000,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_on_nats_keeps_history_and_alert_state_across_a_restart() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let http_port = free_port();
    let cfg = write_config(dir.path(), &server.url(), http_port);
    let url = format!("http://127.0.0.1:{http_port}");
    let log = dir.path().join("gatewatch.log");
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();

    let mut first = serve(&cfg, &log);
    wait_ready(&client, &url, &mut first, &log).await;
    // the test reads the same streams as the daemon (on a blocking thread: the store blocks)
    let nats_url = server.url();
    let store = tokio::task::spawn_blocking(move || {
        NatsStore::open(&NatsOptions {
            prefix: "E2E".into(),
            ..NatsOptions::new(&nats_url, Duration::from_secs(86_400), 1_000_000)
        })
    })
    .await
    .expect("join")
    .expect("open the daemon's streams");
    let store = std::sync::Arc::new(store);

    let params = gatewatch::simulate::GateParams {
        rate_hz: 100.0,
        ..Default::default()
    };
    let mut sim = gatewatch::simulate::GateSimulator::scenario(
        params,
        gatewatch::simulate::Scenario::Stable,
        7,
    );
    let mut next = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64()
        - 30.0;
    let deadline = Instant::now() + WAIT;
    let (rows, g2_state) = loop {
        let body = second(&mut sim, next);
        let r = client
            .post(format!("{url}/api/v1/samples"))
            .json(&body)
            .send()
            .await
            .expect("samples");
        assert!(r.status().is_success(), "HTTP {}", r.status());
        next += 1.0;
        let s = store.clone();
        let (rows, states, outbox) = tokio::task::spawn_blocking(move || {
            (
                s.history(&query("g1")).expect("history"),
                s.alert_states().expect("states"),
                s.outbox().expect("outbox"),
            )
        })
        .await
        .expect("join");
        let g2 = states.into_iter().find(|(g, _)| g == "g2").map(|(_, s)| s);
        if rows.len() >= 3 && g2.is_some() && !outbox.is_empty() {
            break (rows, g2.unwrap_or_default());
        }
        assert!(
            Instant::now() < deadline,
            "{} rows, g2 state {g2:?}, {} outbox rows: {}",
            rows.len(),
            outbox.len(),
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    };
    // the stale alert, firing since a start the restart must keep
    let stored: Value = serde_json::from_str(&g2_state).expect("state JSON");
    assert_eq!(stored["stale"]["name"], "GateDataStale", "{g2_state}");
    assert!(stored["stale"]["starts_at"].is_object(), "{g2_state}");
    first.kill().expect("kill -9");
    let _ = first.wait();

    let mut second_run = serve(&cfg, &log);
    wait_ready(&client, &url, &mut second_run, &log).await;
    // the first run's history, served by the second daemon from the server
    let served: Value = client
        .get(format!("{url}/api/v1/gates/g1/history?limit=1000"))
        .send()
        .await
        .expect("history route")
        .json()
        .await
        .expect("JSON");
    let text = served.to_string();
    for r in &rows {
        assert!(
            text.contains(&format!("{}", r.window_end)),
            "window ending {} missing from {text}",
            r.window_end
        );
    }
    // the stored alert state was resumed, not fired afresh (which would rewrite it with a new
    // start): after a few stale periods it is what the first run wrote
    tokio::time::sleep(Duration::from_secs(3)).await;
    let s = store.clone();
    let states = tokio::task::spawn_blocking(move || s.alert_states().expect("states"))
        .await
        .expect("join");
    let now = states.into_iter().find(|(g, _)| g == "g2").map(|(_, s)| s);
    assert_eq!(now.as_deref(), Some(g2_state.as_str()), "alert state of g2");
    let _ = second_run.kill();
    let _ = second_run.wait();
}
