//! The store through the REAL binary (`gatewatch serve`) and a real SQLite file: an alert
//! survives kill -9 while its webhook receiver is down, with its original `startsAt`; a corrupt
//! or unusable database file stops the start with an error naming it; a full database
//! (SQLite's real `SQLITE_FULL`, through `max_size_mb`) is counted and logged while ingestion
//! and identification go on; SIGTERM flushes the identifications into the `.db` file.
//!
//! The alert is `GateDataStale` of a configured gate that never sends (stale after 1 s): a real
//! firing alert without waiting for identifications. Every wait is bounded.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;

use crate::store_common;
use store_common::brim::fill_to_the_brim;
use store_common::{free_port, metric, outbox_rows, receiver};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const WAIT: Duration = Duration::from_secs(60);

fn write_config(dir: &Path, hook_port: u16) -> PathBuf {
    write_config_with(dir, hook_port, "")
}

/// The test configuration, with `storage` lines added to `[storage]`.
fn write_config_with(dir: &Path, hook_port: u16, storage: &str) -> PathBuf {
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{}\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
             [storage]\npath = \"gw.db\"\n{storage}\n\
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

/// A `gatewatch serve` child killed and reaped when dropped: a test that fails half-way (a
/// panicking assertion) leaves no daemon running, holding its port and its store.
struct Daemon(Child);

impl std::ops::Deref for Daemon {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for Daemon {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}

fn serve(cfg: &Path) -> Daemon {
    spawn_serve(cfg, Stdio::null())
}

/// `gatewatch serve --config cfg` at log level info, its stderr to `stderr`.
fn spawn_serve(cfg: &Path, stderr: Stdio) -> Daemon {
    Daemon(
        Command::new(BIN)
            .args(["serve", "--config"])
            .arg(cfg)
            .env("GATEWATCH_LOG_LEVEL", "info")
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .expect("spawn gatewatch serve"),
    )
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
        let rows = outbox_rows(&db);
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
    let (_, payload) = tokio::time::timeout(WAIT, rx.recv())
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
    let v = &persisted.1["starts_at"];
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
    let err = refused_start(&cfg);
    assert!(err.contains("gw.db"), "names the file: {err}");
    assert!(err.contains("not a database"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    // a directory where the file should be: unwritable as a database, even for root
    std::fs::remove_file(dir.path().join("gw.db")).expect("rm");
    std::fs::create_dir(dir.path().join("gw.db")).expect("mkdir");
    let err = refused_start(&cfg);
    assert!(
        err.contains("gw.db") && err.contains("is a directory"),
        "{err}"
    );

    // a real store with a damaged page of history: refused at start, one line naming the
    // file and SQLite's finding (it used to start and log a read error without the file)
    std::fs::remove_dir(dir.path().join("gw.db")).expect("rmdir");
    let db = dir.path().join("gw.db");
    {
        use gatewatch::store::{SqliteStore, Store, WriteBatch};
        let store = SqliteStore::open(&db, 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: (0..400).map(|i| recent_record(f64::from(i))).collect(),
                ..Default::default()
            })
            .expect("write");
        store.checkpoint().expect("checkpoint");
    }
    let mut bytes = std::fs::read(&db).expect("read");
    // the file's own page size (header bytes 16-17, big-endian): one whole page, mid-file
    let size = usize::from(u16::from_be_bytes([bytes[16], bytes[17]]));
    let page = bytes.len() / size / 2;
    bytes[page * size..(page + 1) * size].fill(0x5a);
    std::fs::write(&db, &bytes).expect("damage a page");
    let err = refused_start(&cfg);
    let line = err
        .lines()
        .find(|l| l.starts_with("gatewatch: "))
        .expect("the message line");
    assert!(
        line.contains(&db.display().to_string()) && line.contains("quick_check"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// `http://127.0.0.1:PORT` of the daemon a test configuration starts.
fn daemon_url(cfg: &Path) -> String {
    let text = std::fs::read_to_string(cfg).expect("read config");
    let addr = text
        .lines()
        .find_map(|l| l.strip_prefix("listen = \""))
        .and_then(|l| l.strip_suffix('"'))
        .expect("listen");
    format!("http://{addr}")
}

/// The daemon with its log (info) in `log`.
fn serve_logging(cfg: &Path, log: &Path) -> Daemon {
    spawn_serve(cfg, std::fs::File::create(log).expect("log file").into())
}

const IDENTIFIED: &str = "gatewatch_identifications_total{gate=\"g1\",path=\"full\"}";
const WRITE_FAILED: &str = "gatewatch_store_write_errors_total{reason=\"failed\"}";

/// A simulated stable gate (100 Hz) streamed one second at a time, in sample time from 30 s
/// ago on (consecutive: no gap restarts the window; ahead of the clock by less than the
/// default `max_future_seconds`).
struct Stream {
    sim: gatewatch::simulate::GateSimulator,
    next: f64,
}

impl Stream {
    fn new() -> Stream {
        let params = gatewatch::simulate::GateParams {
            rate_hz: 100.0,
            ..Default::default()
        };
        let now = SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .expect("clock")
            .as_secs_f64();
        Stream {
            sim: gatewatch::simulate::GateSimulator::scenario(
                params,
                gatewatch::simulate::Scenario::Stable,
                7,
            ),
            next: now - 30.0,
        }
    }

    /// Sends the next second; the HTTP status, or 0 while the daemon does not answer (then
    /// the same second is sent again next time).
    async fn send(&mut self, client: &reqwest::Client, url: &str) -> u16 {
        let mut values = vec![0.0; 100];
        self.sim.fill(&mut values);
        let body = serde_json::json!({"gate": "g1", "start": self.next, "rate_hz": 100.0,
            "values": values});
        match client
            .post(format!("{url}/api/v1/samples"))
            .json(&body)
            .send()
            .await
        {
            Ok(r) => {
                self.next += 1.0;
                r.status().as_u16()
            }
            Err(_) => 0,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_database_is_counted_and_logged_naming_the_file_and_ingestion_goes_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    // max_size_mb = 1 is SQLite's max_page_count on the writer: its real SQLITE_FULL
    let cfg = write_config_with(dir.path(), free_port(), "max_size_mb = 1");
    let db = dir.path().join("gw.db");
    {
        use gatewatch::store::SqliteStore;
        // bounded to 1 MiB, as the daemon will open it
        let store = SqliteStore::open(&db, 1).expect("open");
        fill_to_the_brim(&store, "old");
        store.checkpoint().expect("checkpoint");
    }
    let log = dir.path().join("gatewatch.log");
    let mut child = serve_logging(&cfg, &log);
    let url = daemon_url(&cfg);
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();
    let mut stream = Stream::new();

    // stream until identifications went on while writes failed
    let deadline = Instant::now() + WAIT;
    let (identified, failed) = loop {
        let status = stream.send(&client, &url).await;
        assert!(
            status == 0 || status < 300,
            "ingestion refused: HTTP {status}"
        );
        let identified = metric(&client, &url, IDENTIFIED).await.unwrap_or(0.0);
        let failed = metric(&client, &url, WRITE_FAILED).await.unwrap_or(0.0);
        if identified >= 3.0 && failed >= 3.0 {
            break (identified, failed);
        }
        assert!(
            Instant::now() < deadline,
            "identified {identified}, failed writes {failed}"
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    };
    // not ready while the store refuses writes, saying which file and why (it said 200)
    let r = client
        .get(format!("{url}/readyz"))
        .send()
        .await
        .expect("/readyz");
    let ready = r.status().as_u16();
    let body = r.text().await.expect("body");
    assert_eq!(ready, 503, "{body}");
    assert!(
        body.contains(&db.display().to_string()) && body.contains("full"),
        "{body}"
    );
    // still answering: ingestion accepted, the gate's identification readable
    let status = stream.send(&client, &url).await;
    assert!(
        (200..300).contains(&status),
        "ingestion refused: HTTP {status}"
    );
    let gate: Value = client
        .get(format!("{url}/api/v1/gates/g1"))
        .send()
        .await
        .expect("gate")
        .json()
        .await
        .expect("JSON");
    assert!(gate["identification"]["window_end"].is_number(), "{gate}");
    let _ = child.kill();
    let _ = child.wait();

    // nothing of the daemon's went into the full file
    let c = rusqlite::Connection::open_with_flags(&db, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
        .expect("open");
    let rows: i64 = c
        .query_row("SELECT count(*) FROM history WHERE gate = 'g1'", [], |r| {
            r.get(0)
        })
        .expect("count");
    assert_eq!(rows, 0, "{rows} rows of {identified} windows");
    // the log names the file and SQLite's reason, once per 30 s (not once per write)
    let text = std::fs::read_to_string(&log).expect("log");
    let errors: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("write failed"))
        .collect();
    assert!(!errors.is_empty(), "no error logged:\n{text}");
    assert!(
        errors[0].contains(&db.display().to_string()) && errors[0].contains("full"),
        "{}",
        errors[0]
    );
    assert!(
        (errors.len() as f64) < failed,
        "{} lines for {failed} failed writes",
        errors.len()
    );
    assert!(!text.contains("panicked"), "{text}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_flushes_the_last_identifications_into_the_database_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let url = daemon_url(&cfg);
    let child = serve(&cfg);
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();
    let mut stream = Stream::new();
    let deadline = Instant::now() + WAIT;
    // a burst of samples, then SIGTERM right after the daemon counted the identifications
    let identified = loop {
        stream.send(&client, &url).await;
        let n = metric(&client, &url, IDENTIFIED).await.unwrap_or(0.0);
        if n >= 4.0 {
            break n;
        }
        assert!(Instant::now() < deadline, "identified {n}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let status = terminate(child).await;
    assert_eq!(status.code(), Some(0), "clean exit on SIGTERM");

    // the .db file ALONE holds them (the WAL was checkpointed at shutdown)
    let copy = dir.path().join("copy");
    std::fs::create_dir(&copy).expect("mkdir");
    std::fs::copy(dir.path().join("gw.db"), copy.join("gw.db")).expect("copy the .db alone");
    let c = rusqlite::Connection::open(copy.join("gw.db")).expect("open the copy");
    let rows: i64 = c
        .query_row("SELECT count(*) FROM history WHERE gate = 'g1'", [], |r| {
            r.get(0)
        })
        .expect("count");
    assert!(
        rows as f64 >= identified,
        "{rows} rows in the file, {identified} identifications counted before SIGTERM"
    );
    let state: i64 = c
        .query_row(
            "SELECT count(*) FROM alert_state WHERE gate = 'g1'",
            [],
            |r| r.get(0),
        )
        .expect("alert state");
    assert_eq!(state, 1, "the gate's alert state too");
}

/// `serve` on `cfg` logging to `log`, once it is ready: the child, its URL and a client.
async fn serve_ready(cfg: &Path, log: &Path) -> (Daemon, String, reqwest::Client) {
    let child = serve_logging(cfg, log);
    let url = daemon_url(cfg);
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();
    wait_ready(&client, &url).await;
    (child, url, client)
}

/// `serve` on [`write_config`] in a new directory, once it is ready: the directory (deleted
/// when dropped, so kept until the test ends), the store file, the log, the child, its URL and a
/// client.
async fn serve_default() -> (
    tempfile::TempDir,
    PathBuf,
    PathBuf,
    Daemon,
    String,
    reqwest::Client,
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let db = dir.path().join("gw.db");
    let log = dir.path().join("gatewatch.log");
    let (child, url, client) = serve_ready(&cfg, &log).await;
    (dir, db, log, child, url, client)
}

/// Polls `/readyz` until 200 (bounded by [`WAIT`]).
async fn wait_ready(client: &reqwest::Client, url: &str) {
    let deadline = Instant::now() + WAIT;
    loop {
        if let Ok(r) = client.get(format!("{url}/readyz")).send().await {
            if r.status().is_success() {
                return;
            }
        }
        assert!(
            Instant::now() < deadline,
            "the daemon at {url} never got ready"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// `/readyz`'s status and body, `None` while the daemon does not answer.
async fn readyz(client: &reqwest::Client, url: &str) -> Option<(u16, String)> {
    let r = client.get(format!("{url}/readyz")).send().await.ok()?;
    Some((r.status().as_u16(), r.text().await.unwrap_or_default()))
}

/// Streams a second of samples every 300 ms until `/readyz` answers 503 (bounded by [`WAIT`],
/// else fails with `never`); returns its body.
async fn stream_until_not_ready(
    stream: &mut Stream,
    client: &reqwest::Client,
    url: &str,
    never: &str,
) -> String {
    let deadline = Instant::now() + WAIT;
    loop {
        stream.send(client, url).await;
        if let Some((503, body)) = readyz(client, url).await {
            return body;
        }
        assert!(Instant::now() < deadline, "{never}");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
}

/// Stops the daemon with SIGTERM, asserts its exit code is `code` and returns its log.
async fn terminate_with_log(child: Daemon, log: &Path, code: i32) -> String {
    let status = terminate(child).await;
    let text = std::fs::read_to_string(log).expect("log");
    assert_eq!(status.code(), Some(code), "{text}");
    text
}

/// One identification of gate `g1` that ended `ago` seconds before now (inside the retention).
fn recent_record(ago: f64) -> gatewatch::store::IdentificationRecord {
    let end = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64()
        - ago;
    gatewatch::store::IdentificationRecord {
        gate: "g1".into(),
        time: end + 0.5,
        window_start: end - 1.0,
        window_end: end,
        equation: "ydd + 0.1*yd + y = 0".into(),
        coefficients: vec![("c1".into(), 0.1)],
        damping: serde_json::json!({"zeta0": 0.05}),
        verdict: "damped".into(),
        fit_nmae: 0.02,
        path: "full".into(),
    }
}

/// Two daemons on one store file: the second exits 1 with one line naming the file and the
/// first's pid, and writes nothing; `gatewatch history` still reads the file meanwhile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_daemon_on_the_same_store_is_refused_naming_the_holder() {
    use gatewatch::store::{SqliteStore, Store, WriteBatch};
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let db = dir.path().join("gw.db");
    {
        let store = SqliteStore::open(&db, 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: vec![recent_record(60.0)],
                ..Default::default()
            })
            .expect("write");
        store.checkpoint().expect("checkpoint");
    }
    let mut first = serve(&cfg);
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();
    wait_ready(&client, &daemon_url(&cfg)).await;

    // another configuration (its own port), the same file
    let other = dir.path().join("other");
    std::fs::create_dir(&other).expect("mkdir");
    let cfg2 = write_config(&other, free_port());
    let out = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(&cfg2)
        .env("GATEWATCH_STORAGE_PATH", &db)
        .output()
        .expect("run the second daemon");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    // the message line (the log has its own copy of it at level error)
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("gatewatch: "))
        .collect();
    assert_eq!(lines.len(), 1, "one line: {err}");
    assert!(
        lines[0].contains(&db.display().to_string()),
        "names the file: {err}"
    );
    assert!(
        lines[0].contains(&format!("process {}", first.id())),
        "names the holder: {err}"
    );
    assert!(!other.join("gw.db").exists());

    // the read-only CLI is not locked out
    let out = Command::new(BIN)
        .args(["history", "--gate", "g1", "--db"])
        .arg(&db)
        .output()
        .expect("gatewatch history");
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(text.lines().count(), 1, "{text}");
    let _ = first.kill();
    let _ = first.wait();
}

/// `rm gw.db*` under the running daemon: `/readyz` turns 503, and so does `/healthz` (only a
/// restart gets a store again: a liveness probe must restart the pod, not leave it out of its
/// endpoints for ever), both naming the file; the writes are counted as `file_gone`, the log
/// names the file, and SIGTERM exits 1 (the `.db` file does not hold what the daemon
/// identified) with a line naming it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deleted_store_file_fails_readiness_is_counted_and_exits_1() {
    let (_dir, db, log, child, url, client) = serve_default().await;
    let mut stream = Stream::new();
    for _ in 0..3 {
        stream.send(&client, &url).await;
    }
    for suffix in ["", "-wal", "-shm"] {
        let _ = std::fs::remove_file(format!("{}{suffix}", db.display()));
    }
    const GONE: &str = "gatewatch_store_write_errors_total{reason=\"file_gone\"}";
    let deadline = Instant::now() + WAIT;
    loop {
        stream.send(&client, &url).await;
        let ready = client
            .get(format!("{url}/readyz"))
            .send()
            .await
            .map(|r| r.status().as_u16())
            .unwrap_or(0);
        let gone = metric(&client, &url, GONE).await.unwrap_or(0.0);
        if ready == 503 && gone >= 1.0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "readyz {ready}, file_gone writes {gone}"
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    let name = db.display().to_string();
    for (path, start) in [("/healthz", "unhealthy: "), ("/readyz", "not ready: ")] {
        let r = client.get(format!("{url}{path}")).send().await.expect(path);
        let status = r.status().as_u16();
        let body = r.text().await.expect("body");
        assert_eq!(status, 503, "{path}: {body}");
        assert!(
            body.starts_with(start) && body.contains(&name) && body.contains("deleted"),
            "{path} names the file: {body}"
        );
    }
    let text = terminate_with_log(child, &log, 1).await;
    assert!(
        text.lines()
            .any(|l| l.contains("ERROR") && l.contains(&name) && l.contains("deleted")),
        "an error naming the file:\n{text}"
    );
    let last = text
        .lines()
        .rfind(|l| l.starts_with("gatewatch: "))
        .expect("the exit line");
    assert!(last.contains(&name) && last.contains("deleted"), "{last}");
    assert!(!text.contains("panicked"), "{text}");
}

/// SIGHUP (what `systemctl reload`, `kill -HUP` or a closed terminal sends) is logged as
/// ignored and the daemon goes on: it still answers, and SIGTERM then flushes the store and
/// exits 0. SIGHUP's default action used to kill it (exit 129) with no flush.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_is_logged_and_ignored_and_sigterm_still_exits_0() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let log = dir.path().join("gatewatch.log");
    let (child, url, client) = serve_ready(&cfg, &log).await;
    let ignored = gatewatch::service::shutdown::SIGHUP_IGNORED;
    for n in 1..=2 {
        let hup = Command::new("kill")
            .args(["-HUP", &child.id().to_string()])
            .status()
            .expect("kill -HUP");
        assert!(hup.success());
        let deadline = Instant::now() + WAIT;
        while std::fs::read_to_string(&log)
            .unwrap_or_default()
            .matches(ignored)
            .count()
            < n
        {
            assert!(Instant::now() < deadline, "SIGHUP {n} was never logged");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let r = client
            .get(format!("{url}/healthz"))
            .send()
            .await
            .expect("the daemon still answers after SIGHUP");
        assert_eq!(r.status().as_u16(), 200);
    }
    let text = terminate_with_log(child, &log, 0).await;
    assert!(
        text.lines()
            .any(|l| l.contains("WARN") && l.contains(ignored)),
        "{text}"
    );
    assert!(text.contains("store flushed and checkpointed"), "{text}");
}

/// Sends SIGTERM to the daemon and waits for its exit.
async fn terminate(mut child: Daemon) -> std::process::ExitStatus {
    let term = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .expect("kill -TERM");
    assert!(term.success());
    tokio::task::spawn_blocking(move || child.wait())
        .await
        .expect("join")
        .expect("wait")
}

/// Runs `serve` on `cfg`, which must stop at start with exit 1 (a store it cannot use); its
/// stderr.
fn refused_start(cfg: &Path) -> String {
    let mut child = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(cfg)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run");
    // bounded: a daemon that starts after all (the test's damage missed) must fail the test,
    // not hang it
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the daemon started (still running after 60 s) instead of refusing");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().expect("stderr"), &mut err)
        .expect("stderr");
    assert_eq!(status.code(), Some(1), "{err}");
    err
}

/// The one-daemon lock follows the file, not its name: a symbolic link to the store (another
/// directory's `gw.db -> ../a/gw.db`) is refused while a daemon holds the file, naming the link,
/// the real file and the holder; a hard link (a second name of the same inode, which SQLite
/// would give a second `-wal` file, losing one daemon's rows) is refused under either name,
/// naming it and why. Before, the lock was `<path>.lock` on the path's text and both opened.
#[test]
fn a_second_name_of_the_store_file_is_refused_naming_the_file() {
    use gatewatch::store::SqliteStore;
    let dir = tempfile::tempdir().expect("tempdir");
    for d in ["a", "b", "c"] {
        std::fs::create_dir(dir.path().join(d)).expect("mkdir");
    }
    let db = dir.path().join("a").join("gw.db");
    let first = SqliteStore::open(&db, 64).expect("open");
    let link = dir.path().join("b").join("gw.db");
    std::os::unix::fs::symlink("../a/gw.db", &link).expect("symlink");
    let err = match SqliteStore::open(&link, 64) {
        Ok(_) => panic!("a second open through a symbolic link was not refused"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains(&link.display().to_string()),
        "names the link: {err}"
    );
    let real = std::fs::canonicalize(&db).expect("canonicalize");
    assert!(
        err.contains(&real.display().to_string()),
        "names the real file: {err}"
    );
    assert!(
        err.contains(&format!("process {}", std::process::id())),
        "names the holder: {err}"
    );
    drop(first);

    let hard = dir.path().join("c").join("gw.db");
    std::fs::hard_link(&db, &hard).expect("hard link");
    for name in [&hard, &db] {
        let err = match SqliteStore::open(name, 64) {
            Ok(_) => panic!("{} (hard-linked) was not refused", name.display()),
            Err(e) => e.to_string(),
        };
        assert!(
            err.contains(&name.display().to_string()),
            "names the file: {err}"
        );
        assert!(err.contains("2 hard links"), "says why: {err}");
    }
    assert!(
        !dir.path().join("c").join("gw.db-wal").exists(),
        "nothing opened"
    );
}

/// SIGTERM while another process holds SQLite's write lock on the store (`BEGIN EXCLUSIVE` in
/// a connection of this test, while a gate streams): the daemon exits within
/// `shutdown_grace_seconds` (10 s here, as by default) plus a generous margin, with exit 1 and a
/// log line giving the number of writes not committed. Before, the checkpoint still ran after
/// the failed flush, waiting for the writer (which retried its queued requests one by one,
/// each waiting out SQLite's 5 s busy timeout) and for the busy timeout itself: 16 to 30 s,
/// past systemd's `TimeoutStopSec=30s` and Kubernetes' 30 s grace. The bound is a behaviour
/// (the orchestrator's kill), not a speed: its margin is 5 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_under_a_foreign_write_lock_exits_within_the_grace_period() {
    const GRACE: f64 = 10.0;
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let text = std::fs::read_to_string(&cfg).expect("read config");
    std::fs::write(
        &cfg,
        text.replace(
            "shutdown_grace_seconds = 2.0",
            &format!("shutdown_grace_seconds = {GRACE:.1}"),
        ),
    )
    .expect("write config");
    let db = dir.path().join("gw.db");
    let log = dir.path().join("gatewatch.log");
    let (child, url, client) = serve_ready(&cfg, &log).await;
    let mut stream = Stream::new();
    for _ in 0..3 {
        stream.send(&client, &url).await;
    }
    // the foreign lock: every write of the daemon now waits out its busy timeout and fails
    let foreign = rusqlite::Connection::open(&db).expect("open the store");
    foreign
        .busy_timeout(Duration::from_secs(10))
        .expect("busy timeout");
    foreign
        .execute_batch("BEGIN EXCLUSIVE")
        .expect("take the write lock");
    // windows keep being identified, their writes queue behind the lock
    for _ in 0..8 {
        stream.send(&client, &url).await;
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    let signalled = Instant::now();
    let status = terminate(child).await;
    let took = signalled.elapsed();
    let text = std::fs::read_to_string(&log).expect("log");
    drop(foreign);
    assert!(
        took < Duration::from_secs_f64(GRACE + 5.0),
        "exited {took:?} after SIGTERM (grace {GRACE} s):\n{text}"
    );
    assert_eq!(status.code(), Some(1), "{text}");
    let line = text
        .lines()
        .find(|l| l.contains("writes not committed"))
        .unwrap_or_else(|| panic!("no line gives the writes not committed:\n{text}"));
    let count = line
        .split("writes not committed")
        .next()
        .and_then(|before| before.split_whitespace().last())
        .and_then(|n| n.parse::<u64>().ok())
        .unwrap_or_else(|| panic!("the count before `writes not committed`: {line}"));
    assert!(count > 0, "{line}");
    assert!(
        line.contains(&db.display().to_string()),
        "names the file: {line}"
    );
    assert!(!text.contains("panicked"), "{text}");
}

/// A zero-byte store file (a failed copy, a full disk) opens as a new store, as SQLite does,
/// but no longer silently: a warning names the file and what is missing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_empty_store_file_is_a_warning_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let db = dir.path().join("gw.db");
    std::fs::write(&db, b"").expect("empty file");
    let log = dir.path().join("gatewatch.log");
    let (child, _, _) = serve_ready(&cfg, &log).await;
    let text = terminate_with_log(child, &log, 0).await;
    assert!(
        text.lines().any(|l| l.contains("WARN")
            && l.contains(&db.display().to_string())
            && l.contains("empty: starting without history or alert state")),
        "{text}"
    );
}

/// A byte flipped in a middle frame of the `-wal` file a `kill -9` left behind: SQLite's
/// recovery drops that frame and every one after it without a word (and `quick_check` passes).
/// Now the daemon finds it first: a warning names the WAL, the byte offset and the frames
/// dropped, the whole WAL is kept as `gw.db-wal.damaged-SECS` (byte for byte the damaged one),
/// the frames are counted in `gatewatch_store_restore_skipped_total{what="wal_frame"}`, and
/// the daemon starts. Before, none of it: the rows were gone silently.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_damaged_wal_is_kept_and_its_dropped_frames_logged_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), free_port());
    let db = dir.path().join("gw.db");
    let wal = dir.path().join("gw.db-wal");
    let log = dir.path().join("first.log");
    let (mut first, url, client) = serve_ready(&cfg, &log).await;
    let mut stream = Stream::new();
    let deadline = Instant::now() + WAIT;
    loop {
        stream.send(&client, &url).await;
        let n = metric(&client, &url, IDENTIFIED).await.unwrap_or(0.0);
        if n >= 6.0 {
            break;
        }
        assert!(Instant::now() < deadline, "identified {n}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // the writes committed (the store's writer thread commits them after the metric counts
    // them), then kill -9: they are in the WAL
    let wal_frames = || {
        let bytes = std::fs::read(&wal).unwrap_or_default();
        if bytes.len() < 32 {
            return 0;
        }
        let page = u32::from_be_bytes(bytes[8..12].try_into().expect("4 bytes")) as usize;
        (bytes.len() - 32) / (24 + page)
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    while wal_frames() < 4 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    first.kill().expect("kill -9");
    let _ = first.wait();
    let frames = wal_frames();
    let mut bytes = std::fs::read(&wal).expect("the WAL kill -9 left");
    let page = u32::from_be_bytes(bytes[8..12].try_into().expect("4 bytes")) as usize;
    let frame = 24 + page;
    assert!(frames >= 4, "{frames} frames in the WAL");
    let middle = frames / 2;
    let offset = 32 + middle * frame;
    bytes[offset + 24 + page / 2] ^= 0x01;
    std::fs::write(&wal, &bytes).expect("damage the WAL");

    let log = dir.path().join("second.log");
    let (second, url, client) = serve_ready(&cfg, &log).await;
    let dropped = metric(
        &client,
        &url,
        "gatewatch_store_restore_skipped_total{what=\"wal_frame\"}",
    )
    .await
    .unwrap_or(0.0);
    let text = terminate_with_log(second, &log, 0).await;
    let line = text
        .lines()
        .find(|l| l.contains("WARN") && l.contains("damaged at byte"))
        .unwrap_or_else(|| panic!("no warning of the damaged WAL:\n{text}"));
    assert!(
        line.contains(&wal.display().to_string()),
        "names the WAL: {line}"
    );
    assert!(
        line.contains(&format!("byte {offset}")),
        "the offset {offset}: {line}"
    );
    let copies: Vec<PathBuf> = std::fs::read_dir(dir.path())
        .expect("read dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("gw.db-wal.damaged-"))
        })
        .collect();
    assert_eq!(copies.len(), 1, "one copy: {copies:?}");
    assert!(
        line.contains(&copies[0].display().to_string()),
        "names the copy: {line}"
    );
    assert_eq!(
        std::fs::read(&copies[0]).expect("copy"),
        bytes,
        "the damaged WAL, whole"
    );
    assert!(dropped >= 1.0, "wal_frame counted {dropped}");
    assert!(line.contains(&format!("{dropped} frames")), "{line}");
    assert!(db.exists());
    assert!(!text.contains("panicked"), "{text}");
}

/// `gatewatch serve --config cfg` as a user file permissions apply to: this test's own when it
/// is not root, `nobody` (setpriv) when it is (root writes anywhere). `None` when neither can
/// be had (no setpriv): the caller skips. Exit code and stderr.
fn serve_unprivileged(cfg: &Path) -> Option<(Option<i32>, String)> {
    let probe = tempfile::tempdir().expect("tempdir");
    let sealed = probe.path().join("sealed");
    std::fs::create_dir(&sealed).expect("mkdir");
    set_mode(&sealed, 0o555);
    let root = std::fs::write(sealed.join("probe"), b"").is_ok();
    let mut cmd = if root {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups", BIN]);
        c
    } else {
        Command::new(BIN)
    };
    let out = match cmd.args(["serve", "--config"]).arg(cfg).output() {
        Ok(o) => o,
        Err(e) => {
            // setpriv is util-linux's, on every Debian machine CI runs on
            assert!(
                std::env::var_os("CI").is_none(),
                "CI must be able to run gatewatch as an unprivileged user: {e}"
            );
            eprintln!("skipped: cannot run gatewatch as an unprivileged user ({e})");
            return None;
        }
    };
    Some((
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    ))
}

fn set_mode(path: &Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).expect("chmod");
}

/// A store directory for `nobody` (uid 65534, what [`serve_unprivileged`] runs as under root):
/// the test directory traversable, `store` and what is in it owned by it.
fn hand_to_nobody(top: &Path, store: &Path) {
    set_mode(top, 0o755);
    for p in std::iter::once(store.to_path_buf()).chain(
        std::fs::read_dir(store)
            .expect("read dir")
            .map(|e| e.expect("entry").path()),
    ) {
        // as another user than root this fails, and the files are the test's own anyway
        let _ = std::os::unix::fs::chown(&p, Some(65534), Some(65534));
    }
}

/// A store directory the daemon cannot write, holding a store and a non-empty `-wal` (writes
/// not yet checkpointed): SQLite would open it, read-only, and every write would fail. The
/// start is refused, exit 1, naming the directory and why.
#[test]
fn a_store_directory_it_cannot_write_stops_the_start_naming_it() {
    use gatewatch::store::{SqliteStore, Store, WriteBatch};
    let dir = tempfile::tempdir().expect("tempdir");
    let store_dir = dir.path().join("store");
    std::fs::create_dir(&store_dir).expect("mkdir");
    let cfg = write_config(&store_dir, free_port());
    {
        let live = dir.path().join("live.db");
        let store = SqliteStore::open(&live, 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: vec![recent_record(60.0)],
                ..Default::default()
            })
            .expect("write");
        std::fs::copy(&live, store_dir.join("gw.db")).expect("copy");
        std::fs::copy(dir.path().join("live.db-wal"), store_dir.join("gw.db-wal"))
            .expect("copy the WAL");
    }
    assert!(
        std::fs::metadata(store_dir.join("gw.db-wal"))
            .expect("wal")
            .len()
            > 0
    );
    hand_to_nobody(dir.path(), &store_dir);
    set_mode(&store_dir, 0o555);
    let result = serve_unprivileged(&cfg);
    set_mode(&store_dir, 0o755);
    let Some((code, err)) = result else { return };
    assert_eq!(code, Some(1), "{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("gatewatch: "))
        .unwrap_or_else(|| panic!("the message line: {err}"));
    assert!(
        line.contains(&format!(
            "its directory {} is not writable",
            store_dir.display()
        )),
        "{line}"
    );
    assert!(line.to_lowercase().contains("permission denied"), "{line}");
    assert!(!err.contains("panicked"), "{err}");
}

/// A store file with mode 000: the start stops, exit 1, with a line naming the file, "permission
/// denied" and what the daemon cannot do with it (read, write), its mode and owner. Before:
/// "is not writable" (or SQLite's "unable to open database file").
#[test]
fn a_store_file_it_cannot_read_stops_the_start_saying_permission_denied() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store_dir = dir.path().join("store");
    std::fs::create_dir(&store_dir).expect("mkdir");
    let cfg = write_config(&store_dir, free_port());
    let db = store_dir.join("gw.db");
    drop(gatewatch::store::SqliteStore::open(&db, 64).expect("create the store"));
    hand_to_nobody(dir.path(), &store_dir);
    set_mode(&db, 0o000);
    let Some((code, err)) = serve_unprivileged(&cfg) else {
        return;
    };
    assert_eq!(code, Some(1), "{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("gatewatch: "))
        .unwrap_or_else(|| panic!("the message line: {err}"));
    assert!(
        line.contains(&db.display().to_string()),
        "names the file: {line}"
    );
    assert!(line.contains("permission denied"), "{line}");
    assert!(line.contains("cannot read or write it"), "{line}");
    assert!(line.contains("mode 000"), "{line}");
    assert!(!err.contains("panicked"), "{err}");
}

/// `/readyz` while the store's writes fail for real: another process holds the store's write
/// lock (`BEGIN EXCLUSIVE`), so each write fails after SQLite's busy timeout, as on a full
/// disk or an I/O error. `/readyz` answers 503 naming the file and the error; once the lock is
/// let go (and no more samples sent: a load balancer stops them when `/readyz` fails) a write
/// succeeds, a line at level info says writes resumed with the write requests lost, and
/// `/readyz` answers 200 again. Before, `/readyz` stayed 200 throughout.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failing_store_writes_fail_readiness_until_a_write_succeeds() {
    let (_dir, db, log, child, url, client) = serve_default().await;
    let mut stream = Stream::new();
    let foreign = rusqlite::Connection::open(&db).expect("open the store");
    foreign
        .execute_batch("BEGIN EXCLUSIVE")
        .expect("take the write lock");
    let body = stream_until_not_ready(&mut stream, &client, &url, "/readyz never failed").await;
    assert!(
        body.starts_with("not ready: ")
            && body.contains(&db.display().to_string())
            && body.contains("writes fail")
            && body.contains("locked"),
        "{body}"
    );
    foreign.execute_batch("ROLLBACK").expect("let go");
    drop(foreign);
    wait_ready(&client, &url).await;
    let text = terminate_with_log(child, &log, 0).await;
    let line = text
        .lines()
        .find(|l| l.contains("writes resumed"))
        .unwrap_or_else(|| panic!("no line says writes resumed:\n{text}"));
    assert!(
        line.contains("INFO") && line.contains(&db.display().to_string()),
        "{line}"
    );
    assert!(
        line.contains("write requests were lost meanwhile"),
        "{line}"
    );
    assert!(!text.contains("panicked"), "{text}");
}

/// An alert state whose write failed is written once the store takes writes again. The gate
/// goes stale (`GateDataStale` fires) while a foreign connection holds the write lock, so that
/// state's write fails; nothing changes afterwards. Before, the daemon took the state as
/// written when it queued it and never wrote it again: the file kept the gate's older state
/// (not stale) and a restart restored that one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_alert_state_whose_write_failed_is_written_when_writes_resume() {
    let (_dir, db, log, child, url, client) = serve_default().await;
    let mut stream = Stream::new();
    let deadline = Instant::now() + WAIT;
    while metric(&client, &url, IDENTIFIED).await.unwrap_or(0.0) < 1.0 {
        stream.send(&client, &url).await;
        assert!(Instant::now() < deadline, "g1 was never identified");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    // the stored state is not stale (the gate's first state, or none yet)
    let stale_stored = || {
        let c =
            rusqlite::Connection::open_with_flags(&db, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
                .ok()?;
        let state: String = c
            .query_row("SELECT state FROM alert_state WHERE gate = 'g1'", [], |r| {
                r.get(0)
            })
            .ok()?;
        let v: Value = serde_json::from_str(&state).expect("stored state is JSON");
        Some(v["stale"].is_object())
    };
    assert_ne!(
        stale_stored(),
        Some(true),
        "stale before it stopped sending"
    );
    let foreign = rusqlite::Connection::open(&db).expect("open the store");
    foreign
        .execute_batch("BEGIN EXCLUSIVE")
        .expect("take the write lock");
    // g1 stops sending: stale after 1 s, and its state's write waits out the lock and fails
    const FIRING: &str = "gatewatch_alert_firing{alertname=\"GateDataStale\",gate=\"g1\"}";
    let deadline = Instant::now() + WAIT;
    while metric(&client, &url, FIRING).await != Some(1.0) {
        assert!(Instant::now() < deadline, "GateDataStale never fired");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // held for two of the store's 5-s busy timeouts: the write in flight when it fired, then
    // the one with the stale state; both fail
    tokio::time::sleep(Duration::from_secs(12)).await;
    let (status, body) = readyz(&client, &url).await.expect("/readyz answers");
    assert_eq!(
        status, 503,
        "the writes under the lock did not fail: {body}"
    );
    assert_ne!(stale_stored(), Some(true), "written through the lock?");
    foreign.execute_batch("ROLLBACK").expect("let go");
    drop(foreign);
    let deadline = Instant::now() + Duration::from_secs(20);
    while stale_stored() != Some(true) {
        assert!(
            Instant::now() < deadline,
            "the stale state was never written after the lock was released ({:?})",
            stale_stored()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let text = terminate_with_log(child, &log, 0).await;
    assert!(!text.contains("panicked"), "{text}");
}

/// Size of the small file system the low-space test puts the store on, and what a file made
/// before the daemon starts takes of it: about 4 MiB left, under `store::LOW_SPACE_BYTES`
/// (16 MiB), and over it again once that file is deleted.
const SMALL_FS: &str = "24m";
const FILLER_BYTES: u64 = 20 << 20;

/// Whether this test runs as root (`id -u`).
fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// `unshare` into a mount namespace of its own (with a user namespace when not root): a tmpfs
/// mounted there is seen by that process and its children only, and goes with them, so a
/// failed test leaves nothing mounted.
fn unshare(script: &str, args: &[&std::ffi::OsStr]) -> Command {
    let mut c = Command::new("unshare");
    c.arg("--mount");
    if !is_root() {
        c.arg("--map-root-user");
    }
    c.args(["sh", "-c", script, "sh"]).args(args);
    c
}

/// Mounts a tmpfs of [`SMALL_FS`] on `dir` in a namespace of its own, and unmounts it: `Err`
/// with why when this machine does not let the test do that.
fn can_mount_small_fs(dir: &Path) -> Result<(), String> {
    let out = unshare(
        "mount -t tmpfs -o size=\"$1\" tmpfs \"$2\"",
        &[SMALL_FS.as_ref(), dir.as_os_str()],
    )
    .output()
    .map_err(|e| format!("cannot run unshare: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).trim().to_string())
    }
}

/// A store on a real, nearly full file system (a tmpfs of 24 MiB, 20 MiB of it taken before
/// the start): the daemon warns at start, before it listens, naming the file and the bytes
/// left, and `/readyz` answers 200 (its writes still succeed: docs/api.md). The disk filled to
/// the last byte, its writes fail with SQLite's real `SQLITE_FULL` and `/readyz` answers 503
/// naming the file; the space freed, it says so at level info and `/readyz` is 200 again.
/// Before, the warning had no test (a real full disk needs root and a small file system).
///
/// The tmpfs is mounted in a mount namespace of the daemon's own (`unshare`): as root, or
/// where unprivileged user namespaces are allowed; elsewhere the test is skipped with a
/// message, under CI too: a CI runner in a container without `CAP_SYS_ADMIN` cannot mount
/// even as root, and that is the runner's limit, not a defect of the store (this machine and
/// `.ci/run`'s rehearsals mount it).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_nearly_full_disk_is_warned_at_start_and_readiness_follows_the_writes() {
    use gatewatch::store::LOW_SPACE_BYTES;
    let dir = tempfile::tempdir().expect("tempdir");
    let small = dir.path().join("small");
    std::fs::create_dir(&small).expect("mkdir");
    if let Err(why) = can_mount_small_fs(&small) {
        eprintln!(
            "skipped: cannot mount a small tmpfs in a mount namespace here ({why}); the \
             low-space warning needs a real small file system (root, or unprivileged user \
             namespaces)"
        );
        return;
    }
    let cfg = write_config(dir.path(), free_port());
    let db = small.join("gw.db");
    let text = std::fs::read_to_string(&cfg).expect("config");
    std::fs::write(
        &cfg,
        text.replace("path = \"gw.db\"", &format!("path = \"{}\"", db.display())),
    )
    .expect("config");
    let log = dir.path().join("gatewatch.log");
    let child = Daemon(unshare(
        "mount -t tmpfs -o size=\"$1\" tmpfs \"$2\" && head -c \"$3\" /dev/zero > \"$2/filler\" \
         && exec \"$4\" serve --config \"$5\"",
        &[
            SMALL_FS.as_ref(),
            small.as_os_str(),
            FILLER_BYTES.to_string().as_ref(),
            BIN.as_ref(),
            cfg.as_os_str(),
        ],
    )
    .env("GATEWATCH_LOG_LEVEL", "info")
    .stdout(Stdio::null())
    .stderr(std::fs::File::create(&log).expect("log file"))
    .spawn()
    .expect("spawn gatewatch serve in a mount namespace"));
    // unshare and sh exec: the child is the daemon, and its view of the tmpfs is under
    // /proc/PID/root
    let inside = PathBuf::from(format!("/proc/{}/root", child.id())).join(
        small
            .strip_prefix("/")
            .expect("an absolute temporary directory"),
    );
    let url = daemon_url(&cfg);
    gatewatch::service::client::ensure_crypto_provider();
    let client = reqwest::Client::new();

    // at start: the warning, before the listener is up, and ready all the same
    wait_ready(&client, &url).await;
    let (_, body) = readyz(&client, &url).await.expect("/readyz answers");
    assert_eq!(body.trim(), "ready");
    let text = std::fs::read_to_string(&log).expect("log");
    let lines: Vec<&str> = text.lines().collect();
    let warned = lines
        .iter()
        .position(|l| l.contains("bytes free:"))
        .unwrap_or_else(|| panic!("no low-space warning at start:\n{text}"));
    let line = lines[warned];
    assert!(
        line.contains("WARN") && line.contains(&format!("store {}:", db.display())),
        "{line}"
    );
    let free: u64 = line
        .split("its file system has ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no byte count: {line}"));
    assert!(
        free > 0 && free < LOW_SPACE_BYTES && free <= (24 << 20) - FILLER_BYTES,
        "{free} bytes free: {line}"
    );
    let listening = lines
        .iter()
        .position(|l| l.contains("HTTP listener up"))
        .unwrap_or_else(|| panic!("no listener line:\n{text}"));
    assert!(warned < listening, "warned after the start:\n{text}");

    // the disk full to the last byte: the daemon's writes fail for real, and /readyz says so
    {
        use std::io::Write;
        let mut f = std::fs::File::create(inside.join("filler2")).expect("a second filler");
        let chunk = vec![0u8; 64 << 10];
        let mut n = chunk.len();
        loop {
            match f.write(&chunk[..n]) {
                Ok(0) => break,
                Ok(_) => {}
                Err(e) if e.raw_os_error() == Some(28) && n > 1 => n /= 2, // ENOSPC
                Err(e) if e.raw_os_error() == Some(28) => break,
                Err(e) => panic!("filling the tmpfs: {e}"),
            }
        }
    }
    let mut stream = Stream::new();
    let never = "/readyz never failed on a full disk";
    let body = stream_until_not_ready(&mut stream, &client, &url, never).await;
    assert!(
        body.starts_with("not ready: ")
            && body.contains(&db.display().to_string())
            && body.contains("writes fail")
            && body.contains("full"),
        "{body}"
    );

    // the space freed: said at level info, and ready again (by the write probe, with no
    // samples: a load balancer stops them while /readyz fails)
    for f in ["filler", "filler2"] {
        std::fs::remove_file(inside.join(f)).expect("free the space");
    }
    wait_ready(&client, &url).await;
    // the space check runs every 5 s (store::CHECK_INTERVAL): the next one says it is back
    let deadline = Instant::now() + WAIT;
    while !std::fs::read_to_string(&log)
        .expect("log")
        .contains("bytes free again")
    {
        assert!(
            Instant::now() < deadline,
            "the space back never said:\n{}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let text = terminate_with_log(child, &log, 0).await;
    let again = text
        .lines()
        .find(|l| l.contains("bytes free again"))
        .unwrap_or_else(|| panic!("no line says the space is back:\n{text}"));
    assert!(
        again.contains("INFO") && again.contains(&db.display().to_string()),
        "{again}"
    );
    assert!(text.contains("writes resumed"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
}
