//! The store through the REAL binary (`gatewatch serve`) and a real SQLite file: an alert
//! survives kill -9 while its webhook receiver is down, with its original `startsAt`; a corrupt
//! or unusable database file stops the start with an error naming it.
//!
//! The alert is `GateDataStale` of a configured gate that never sends (stale after 1 s): a real
//! firing alert without waiting for identifications. Every wait is bounded.

use std::net::TcpListener as StdListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;
use tokio::sync::mpsc;

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const WAIT: Duration = Duration::from_secs(60);

fn free_port() -> u16 {
    StdListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

fn write_config(dir: &Path, hook_port: u16) -> PathBuf {
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{}\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
             [storage]\npath = \"gw.db\"\n\
             [notify]\ninitial_backoff_ms = 100\nmax_backoff_ms = 300\nresend_interval_seconds = 0\n\
             [[notify.webhooks]]\nurl = \"http://127.0.0.1:{hook_port}/hook\"\n\
             [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
             [defaults.alert]\nstale_after_seconds = 1.0\n\
             [gates.g1]\n",
            free_port()
        ),
    )
    .expect("write config");
    cfg
}

fn serve(cfg: &Path) -> Child {
    Command::new(BIN)
        .args(["serve", "--config"])
        .arg(cfg)
        .env("GATEWATCH_LOG_LEVEL", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn gatewatch serve")
}

/// `(status, startsAt)` of the persisted outbox rows (the daemon's file, read-only, while it
/// runs: WAL).
fn outbox(db: &Path) -> Vec<(String, String)> {
    let Ok(c) =
        rusqlite::Connection::open_with_flags(db, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
    else {
        return Vec::new();
    };
    let Ok(mut s) = c.prepare("SELECT status, payload FROM outbox ORDER BY id") else {
        return Vec::new();
    };
    s.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?)))
        .map(|rows| {
            rows.filter_map(Result::ok)
                .map(|(st, p)| {
                    let v: Value = serde_json::from_str(&p).unwrap_or(Value::Null);
                    (st, v["starts_at"].to_string())
                })
                .collect()
        })
        .unwrap_or_default()
}

/// A webhook receiver on `port`: every payload, through a bounded queue.
async fn receiver(port: u16) -> mpsc::Receiver<Value> {
    let (tx, rx) = mpsc::channel::<Value>(256);
    let app = axum::Router::new()
        .route(
            "/hook",
            axum::routing::post(
                |axum::extract::State(tx): axum::extract::State<mpsc::Sender<Value>>,
                 axum::Json(v): axum::Json<Value>| async move {
                    let _ = tx.try_send(v);
                    axum::http::StatusCode::OK
                },
            ),
        )
        .with_state(tx);
    let l = tokio::net::TcpListener::bind(("127.0.0.1", port))
        .await
        .expect("bind the receiver");
    tokio::spawn(async move {
        let _ = axum::serve(l, app).await;
    });
    rx
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_while_firing_with_the_receiver_down_delivers_the_original_alert_after_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let hook_port = free_port(); // nothing listens there yet: the receiver is down
    let cfg = write_config(dir.path(), hook_port);
    let db = dir.path().join("gw.db");

    let mut first = serve(&cfg);
    let deadline = Instant::now() + WAIT;
    let persisted = loop {
        let rows = outbox(&db);
        if let Some(r) = rows.iter().find(|r| r.0 == "firing") {
            break r.clone();
        }
        assert!(Instant::now() < deadline, "no firing alert persisted");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    // let a few deliveries fail, then crash
    tokio::time::sleep(Duration::from_millis(500)).await;
    first.kill().expect("kill -9"); // SIGKILL
    let _ = first.wait();
    let restarted_at = SystemTime::now();

    let mut second = serve(&cfg);
    // the receiver comes up after the restart
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut rx = receiver(hook_port).await;
    let payload = tokio::time::timeout(WAIT, rx.recv())
        .await
        .expect("a delivery after the restart")
        .expect("receiver open");
    let _ = second.kill();
    let _ = second.wait();

    let alert = &payload["alerts"][0];
    assert_eq!(alert["status"], "firing", "{payload}");
    assert_eq!(alert["labels"]["alertname"], "GateDataStale", "{payload}");
    assert_eq!(alert["labels"]["gate"], "g1", "{payload}");
    let starts_at = alert["startsAt"].as_str().expect("startsAt");
    let starts = humantime::parse_rfc3339(starts_at).expect("RFC 3339");
    assert!(
        starts < restarted_at,
        "the ORIGINAL startsAt ({starts_at}), not one from after the restart"
    );
    // the same instant as the persisted one (seconds + nanoseconds in the store)
    let v: Value = serde_json::from_str(&persisted.1).expect("stored time");
    let secs = v["secs_since_epoch"].as_u64().expect("secs");
    let stored = SystemTime::UNIX_EPOCH + Duration::from_secs(secs);
    let diff = starts
        .duration_since(stored)
        .unwrap_or_else(|e| e.duration());
    assert!(diff < Duration::from_secs(1), "{starts_at} vs stored {v}");
}

#[test]
fn a_corrupt_or_unusable_database_stops_the_start_naming_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    std::fs::write(dir.path().join("gw.db"), vec![0x5au8; 16_384]).expect("junk");
    let out = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(&cfg)
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("gw.db"), "names the file: {err}");
    assert!(err.contains("not a database"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    // a directory where the file should be: unwritable as a database, even for root
    std::fs::remove_file(dir.path().join("gw.db")).expect("rm");
    std::fs::create_dir(dir.path().join("gw.db")).expect("mkdir");
    let out = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(&cfg)
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("gw.db") && err.contains("is a directory"),
        "{err}"
    );
}
