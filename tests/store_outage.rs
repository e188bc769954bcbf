//! Issue 10's acceptance: a webhook receiver that is DOWN across both transitions of an onset
//! and a recovery (`GateNegativeDamping` firing, then resolved) gets both after it comes up, in
//! order, the same alert. The REAL binary (`gatewatch serve`, real analyzers, its own SQLite
//! file), a simulated gate streamed over HTTP, and a real receiver whose port is closed (connection
//! refused) until the daemon is past both transitions and the outage is longer than the old
//! give-up time (retries at 0.5, 1, 2, 4, 8 s: about 15 s).
//!
//! The stream runs in lockstep with the daemon (as in tests/e2e.rs): after each cadence step the
//! test waits until the daemon finished that window, so no window is skipped whatever the
//! machine's speed. `[notify]` keeps its DEFAULT backoff (500 ms doubling to the 30 s cap), so
//! the test also shows how late the first retry after an outage comes. Every wait is bounded;
//! nothing asserts on wall-clock durations.
//!
//! The CI test keeps the outage at 20 s after the resolve (about a minute after the firing);
//! `ten_minute_webhook_outage_...` (ignored; `GATEWATCH_OUTAGE_MINUTES`, default 10) is the
//! issue's 10 minutes: `cargo test --release --test integration store_outage:: -- --ignored --nocapture`.

use crate::stream_common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gatewatch::simulate::{GateParams, GateSimulator, ZetaSchedule};
use serde_json::Value;

use crate::store_common;
use store_common::{free_port, outbox_rows, receiver};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
/// Longest wait for the daemon to answer, or for one window's identification.
const WINDOW_TIMEOUT: Duration = Duration::from_secs(180);
/// Longest wait for a delivery once the receiver is up: the backoff cap (30 s) and a margin.
const DELIVERY_TIMEOUT: Duration = Duration::from_secs(90);
/// Start of the stream, Unix seconds (in the past: `max_past_seconds = 0` lets it in).
const START: f64 = 1_700_000_000.0;
const RATE: f64 = 200.0;
const WINDOW: f64 = 10.0;
const EVERY: f64 = 5.0;

struct Daemon {
    child: Child,
    url: String,
    db: PathBuf,
    client: reqwest::Client,
    _dir: tempfile::TempDir,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The real daemon on a temporary config and store; `hook_port` is the webhook receiver's.
async fn daemon(hook_port: u16) -> Daemon {
    gatewatch::service::client::ensure_crypto_provider();
    let dir = tempfile::tempdir().expect("tempdir");
    let port = free_port();
    let cfg = dir.path().join("gatewatch.toml");
    // notify: the defaults (initial_backoff_ms 500, max_backoff_ms 30000, max_attempts 6, which
    // the outbox overrides); stale_after_seconds far away: the stream pauses during the outage
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{port}\"\nworker_threads = 1\nshutdown_grace_seconds = 2.0\n\
             [storage]\npath = \"gw.db\"\n\
             [[notify.webhooks]]\nurl = \"http://127.0.0.1:{hook_port}/hook\"\n\
             [defaults]\nrate_hz = {RATE}\nmax_past_seconds = 0.0\nwindow_seconds = {WINDOW}\n\
             identify_every_seconds = {EVERY}\n\
             [defaults.alert]\nstale_after_seconds = 86400.0\n"
        ),
    )
    .expect("write config");
    let child = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(&cfg)
        .env("GATEWATCH_LOG_LEVEL", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn gatewatch serve");
    let d = Daemon {
        child,
        url: format!("http://127.0.0.1:{port}"),
        db: dir.path().join("gw.db"),
        client: reqwest::Client::new(),
        _dir: dir,
    };
    let deadline = Instant::now() + WINDOW_TIMEOUT;
    loop {
        let ready = d.client.get(format!("{}/readyz", d.url)).send().await;
        if ready.is_ok_and(|r| r.status().is_success()) {
            return d;
        }
        assert!(Instant::now() < deadline, "the daemon did not get ready");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

impl Daemon {
    async fn metric(&self, line_start: &str) -> Option<f64> {
        store_common::metric(&self.client, &self.url, line_start).await
    }

    /// Sends `n` samples of `sim` from sample `first` on (one request).
    async fn send(&self, sim: &mut GateSimulator, first: u64, n: u64) {
        let got = stream_common::send(&self.url, "g1", sim, START, first, n).await;
        assert_eq!(got, n);
    }
}

/// `(alertname, status)` of the persisted outbox rows, oldest first.
fn outbox(db: &Path) -> Vec<(String, String)> {
    outbox_rows(db)
        .into_iter()
        .map(|(status, v)| (v["name"].as_str().unwrap_or("").to_string(), status))
        .collect()
}

/// The statuses of `GateNegativeDamping` in the outbox (the trend warning,
/// `GateDampingDeclining`, may come and go during the onset too: it is not this test's).
fn negative_damping(db: &Path) -> Vec<String> {
    outbox(db)
        .into_iter()
        .filter(|(name, _)| name == "GateNegativeDamping")
        .map(|(_, status)| status)
        .collect()
}

/// Streams the onset and recovery in lockstep until the daemon has fired
/// `GateNegativeDamping` and resolved it. Returns the wall-clock instants of both.
async fn onset_and_recovery(d: &Daemon) -> (Instant, Instant) {
    // the e2e stream: +2 % for 40 s, ramp to -2 % at 140 s, hold, back to +2 % at 240 s
    let table = vec![
        (0.0, 0.02),
        (40.0, 0.02),
        (140.0, -0.02),
        (200.0, -0.02),
        (240.0, 0.02),
        (420.0, 0.02),
    ];
    let mut sim = GateSimulator::new(GateParams::default(), ZetaSchedule::Table(table), 11);
    let every_n = (EVERY * RATE) as u64;
    let window_n = stream_common::first_window_samples("g1", (WINDOW * RATE) as u64, every_n);
    let total = (420.0 * RATE) as u64;
    let mut sent = 0u64;
    let mut fired = None;
    while sent < total {
        let n = if sent < window_n {
            window_n - sent
        } else {
            every_n
        };
        d.send(&mut sim, sent, n).await;
        sent += n;
        let end = START + (sent - 1) as f64 / RATE;
        let span = (START, end, 0.5 / RATE);
        let v = stream_common::wait_analysed(&d.client, &d.url, "g1", span, WINDOW_TIMEOUT).await;
        let firing = v["firing"].as_bool().unwrap_or(false);
        eprintln!(
            "t {:6.1} s  true {:+.4}  zeta0 {}  firing {firing}",
            end - START,
            sim.true_zeta(end - START),
            v["identification"]["damping"]["zeta0"]
        );
        match (fired, firing) {
            (None, true) => fired = Some(Instant::now()),
            (Some(f), false) => return (f, Instant::now()),
            _ => {}
        }
    }
    panic!(
        "GateNegativeDamping did not fire and resolve within 420 s of stream (fired: {fired:?})"
    );
}

/// The whole scenario with an outage lasting `after_resolve` past the resolve.
async fn outage_during_onset_and_recovery(after_resolve: Duration) {
    let hook_port = free_port(); // nothing listens there: connection refused
    let d = daemon(hook_port).await;
    let (fired_at, resolved_at) = onset_and_recovery(&d).await;

    // both transitions are in the outbox, undelivered, and nothing was given up
    let rows = tokio::time::timeout(WINDOW_TIMEOUT, async {
        loop {
            let rows = negative_damping(&d.db);
            if rows.len() >= 2 {
                return rows;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await
    .expect("both transitions persisted in the outbox");
    assert_eq!(
        rows,
        ["firing", "resolved"],
        "outbox while the receiver is down"
    );

    tokio::time::sleep(after_resolve).await;
    let outage = fired_at.elapsed();
    assert!(
        outage > Duration::from_secs(16),
        "the outage ({outage:?}) must be longer than the old give-up time (~15 s)"
    );
    assert_eq!(
        negative_damping(&d.db),
        ["firing", "resolved"],
        "nothing given up"
    );
    let failed = "gatewatch_notifications_total{outcome=\"failed\",target=\"webhook\"}";
    assert_eq!(d.metric(failed).await, Some(0.0), "no give-up counted");

    let up = Instant::now();
    let mut rx = receiver(hook_port).await;
    let mut seen: Vec<(Instant, Value)> = Vec::new();
    tokio::time::timeout(DELIVERY_TIMEOUT, async {
        while let Some((at, payload)) = rx.recv().await {
            for a in payload["alerts"].as_array().into_iter().flatten() {
                if a["labels"]["alertname"] == "GateNegativeDamping" {
                    seen.push((at, a.clone()));
                }
            }
            if seen.iter().any(|(_, a)| a["status"] == "resolved") {
                return;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("firing and resolved not both delivered; got {seen:?}"));
    let first = seen[0].0.duration_since(up);
    let last = seen[seen.len() - 1].0.duration_since(up);
    eprintln!(
        "outage: {:.1} s from the firing, {:.1} s from the resolve; first delivery {:.1} s \
         after the receiver came up, the resolve {:.1} s after",
        outage.as_secs_f64(),
        resolved_at.elapsed().as_secs_f64() - up.elapsed().as_secs_f64(),
        first.as_secs_f64(),
        last.as_secs_f64()
    );

    let statuses: Vec<&str> = seen
        .iter()
        .map(|(_, a)| a["status"].as_str().unwrap_or(""))
        .collect();
    assert_eq!(
        statuses,
        ["firing", "resolved"],
        "in order, once each: {seen:?}"
    );
    let (firing, resolved) = (&seen[0].1, &seen[1].1);
    for a in [firing, resolved] {
        assert_eq!(a["labels"]["alertname"], "GateNegativeDamping", "{a}");
        assert_eq!(a["labels"]["gate"], "g1", "{a}");
    }
    assert_eq!(
        firing["fingerprint"], resolved["fingerprint"],
        "the same alert"
    );
    assert_eq!(firing["startsAt"], resolved["startsAt"], "the same episode");
    // a firing alert's `endsAt` is a string too (Go's zero time): the resolved one ends after
    // it started (RFC 3339 in UTC, which orders as text)
    let (starts, ends) = (
        resolved["startsAt"].as_str().unwrap(),
        resolved["endsAt"].as_str().unwrap(),
    );
    assert!(
        ends != "0001-01-01T00:00:00Z" && ends > starts,
        "{resolved}"
    );
    // acknowledged: the outbox empties
    let empty = tokio::time::timeout(WINDOW_TIMEOUT, async {
        while !outbox(&d.db).is_empty() {
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await;
    assert!(empty.is_ok(), "delivered rows deleted: {:?}", outbox(&d.db));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn webhook_down_across_an_onset_and_a_recovery_gets_both_transitions_in_order() {
    outage_during_onset_and_recovery(Duration::from_secs(20)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "the issue's 10-minute outage: GATEWATCH_OUTAGE_MINUTES (default 10)"]
async fn ten_minute_webhook_outage_during_an_onset_and_a_recovery() {
    let minutes: f64 = std::env::var("GATEWATCH_OUTAGE_MINUTES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10.0);
    outage_during_onset_and_recovery(Duration::from_secs_f64(60.0 * minutes)).await;
}
