//! `gatewatch serve` with `[storage] backend = "nats"` against a REAL `nats-server` (skipped
//! when it is not installed, failed under CI): a simulated gate streamed in is identified and
//! its history lands in the server's stream; a configured gate that never sends fires
//! `GateDataStale`, whose alert state and notification land there too; after the daemon is
//! killed and started again, it serves the first run's history from the server and resumes the
//! stored alert state instead of firing afresh. One daemon per prefix: a second daemon on the
//! prefix is refused at start naming the first; after the `kill -9` the restart is refused
//! until the killed daemon's lease expires, then starts; a clean stop releases the lease.
//! Every wait is bounded.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use gatewatch::store::{HistoryQuery, NatsStore, Store, NATS_OPERATION_TIMEOUT};
use serde_json::Value;

use crate::nats_common;
use nats_common::{free_port, nats_installed, NatsServer};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const WAIT: Duration = Duration::from_secs(60);
/// The daemons' owner lease: long enough that a restart right after a `kill -9` is refused
/// (renewed every third, so at least 6.7 s of it are left), short enough to wait out.
const LEASE_SECONDS: f64 = 10.0;

/// The daemon's configuration: the NATS backend, a gate `g1` that is streamed, a gate `g2` that
/// never sends (stale after 1 s), a webhook nobody listens to (its row stays in the outbox), an
/// owner lease of [`LEASE_SECONDS`].
fn write_config(dir: &Path, nats_url: &str, http_port: u16) -> PathBuf {
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{http_port}\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
             [storage]\nbackend = \"nats\"\nnats_url = \"{nats_url}\"\nnats_prefix = \"E2E\"\n\
             nats_lease_seconds = {LEASE_SECONDS}\n\
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
    if let Err(log) = ready_or_exit(client, url, child, log).await {
        panic!("daemon exited: {log}");
    }
}

/// Waits for `/readyz` (`Ok`) or the daemon's exit (`Err` with its status and log); fails when
/// neither comes in time.
async fn ready_or_exit(
    client: &reqwest::Client,
    url: &str,
    child: &mut Child,
    log: &Path,
) -> Result<(), String> {
    let deadline = Instant::now() + WAIT;
    loop {
        if let Ok(r) = client.get(format!("{url}/readyz")).send().await {
            if r.status().is_success() {
                return Ok(());
            }
        }
        let text = || std::fs::read_to_string(log).unwrap_or_default();
        if let Some(status) = child.try_wait().ok().flatten() {
            return Err(format!("{status}: {}", text()));
        }
        assert!(Instant::now() < deadline, "daemon not ready: {}", text());
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
    // a second daemon on the prefix (its own HTTP port) is refused, naming the first
    let rival_dir = dir.path().join("rival");
    std::fs::create_dir(&rival_dir).expect("rival dir");
    let rival_port = free_port();
    let rival_cfg = write_config(&rival_dir, &server.url(), rival_port);
    let rival_log = rival_dir.join("gatewatch.log");
    let mut rival = serve(&rival_cfg, &rival_log);
    let refused = ready_or_exit(
        &client,
        &format!("http://127.0.0.1:{rival_port}"),
        &mut rival,
        &rival_log,
    )
    .await
    .expect_err("a second daemon on the prefix started");
    let owner = format!(
        "another gatewatch owns prefix E2E on {}: host ",
        server.url()
    );
    assert!(refused.contains(&owner), "{refused}");
    assert!(
        refused.contains(&format!(" pid {} since ", first.id())),
        "{refused}"
    );
    assert!(!refused.starts_with("exit status: 0"), "{refused}");
    // the test reads the same streams as the daemon (on a blocking thread: the store blocks),
    // read-only: as `gatewatch history --nats` does, without declaring them with its own limits
    let nats_url = server.url();
    let store = tokio::task::spawn_blocking(move || {
        NatsStore::open_read_only(&nats_url, "E2E", NATS_OPERATION_TIMEOUT)
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
    let killed = Instant::now();

    // the killed daemon did not release its lease: the restart is refused until it expires
    // (what a systemd Restart= loop goes through), then starts
    let mut refusals = 0;
    let mut second_run = loop {
        let mut run = serve(&cfg, &log);
        match ready_or_exit(&client, &url, &mut run, &log).await {
            Ok(()) => break run,
            Err(refused) => {
                assert!(refused.contains(&owner), "{refused}");
                assert!(refused.contains("its lease expires in"), "{refused}");
                assert!(
                    killed.elapsed() < Duration::from_secs_f64(LEASE_SECONDS) + WAIT,
                    "still refused long after the lease: {refused}"
                );
                refusals += 1;
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
        }
    };
    assert!(
        refusals >= 1,
        "the restart was not refused within the lease"
    );
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
    // and read by `gatewatch history --nats` beside the running daemon: every window the first
    // run stored, while the daemon keeps its lease (same instance, still live) and stays ready
    let s = store.clone();
    let (_, lease) = tokio::task::spawn_blocking(move || s.owner_lease().expect("lease"))
        .await
        .expect("join")
        .expect("the second daemon's lease");
    let cli = Command::new(BIN)
        .args(["history", "--nats", &server.url(), "--nats-prefix", "E2E"])
        .args(["--gate", "g1", "--limit", "1000"])
        .output()
        .expect("gatewatch history --nats");
    let printed = String::from_utf8_lossy(&cli.stdout);
    assert!(
        cli.status.success(),
        "{}",
        String::from_utf8_lossy(&cli.stderr)
    );
    let printed: Vec<f64> = printed
        .lines()
        .map(|l| {
            let v: Value = serde_json::from_str(l).expect("JSON line");
            v["window_end"].as_f64().expect("window_end")
        })
        .collect();
    for r in &rows {
        assert!(
            printed.contains(&r.window_end),
            "window ending {} missing from gatewatch history: {printed:?}",
            r.window_end
        );
    }
    let s = store.clone();
    let (_, after) = tokio::task::spawn_blocking(move || s.owner_lease().expect("lease"))
        .await
        .expect("join")
        .expect("the second daemon's lease");
    assert_eq!(after.instance, lease.instance, "the reader took the lease");
    assert_eq!(after.pid, second_run.id());
    assert!(after.live(
        SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .expect("clock")
            .as_secs_f64()
    ));
    wait_ready(&client, &url, &mut second_run, &log).await;
    // the stored alert state was resumed, not fired afresh (which would rewrite it with a new
    // start): after a few stale periods it is what the first run wrote
    tokio::time::sleep(Duration::from_secs(3)).await;
    let s = store.clone();
    let states = tokio::task::spawn_blocking(move || s.alert_states().expect("states"))
        .await
        .expect("join");
    let now = states.into_iter().find(|(g, _)| g == "g2").map(|(_, s)| s);
    assert_eq!(now.as_deref(), Some(g2_state.as_str()), "alert state of g2");
    // a clean stop releases the lease: the next daemon would not wait
    let stopped = Command::new("kill")
        .args(["-TERM", &second_run.id().to_string()])
        .status()
        .expect("kill -TERM");
    assert!(stopped.success());
    let deadline = Instant::now() + WAIT;
    while second_run.try_wait().ok().flatten().is_none() {
        assert!(Instant::now() < deadline, "the daemon did not stop");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let s = store.clone();
    let (_, lease) = tokio::task::spawn_blocking(move || s.owner_lease().expect("lease"))
        .await
        .expect("join")
        .expect("a lease record");
    let now = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64();
    assert!(
        !lease.live(now),
        "lease not released at a clean stop: {lease:?}: {}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
}
