//! What an operator's tools read from the daemon: the metrics (gatewatch's own alerts as
//! gauges, the amplitude, build and process information, counters that exist from the start,
//! one unit per counter, HTTP `code`) and the logs (no colour codes in a file, plain peers).

use crate::service_common;

use std::io::Write;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use axum::body::Body;
use axum::http::StatusCode;

use service_common::*;

/// The value of the one sample named exactly `series` (name and labels as exposed).
fn sample(text: &str, series: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(series)?.strip_prefix(' ')?.parse().ok())
}

#[tokio::test]
async fn alert_firing_follows_the_alert_not_the_displayed_state() {
    let fake = Arc::new(Fake {
        zeta: vec![-0.03],
        ..Default::default()
    });
    let (app, state) = app_with(config(""), fake.clone());
    let firing = |name: &str| {
        sample(
            &state.render_metrics(),
            &format!("gatewatch_alert_firing{{alertname=\"{name}\",gate=\"g1\"}}"),
        )
    };
    // the gate's series exist from its creation, not firing
    post_json(&app, uniform("g1", 0.0, 50)).await;
    assert_eq!(firing("GateNegativeDamping"), Some(0.0));
    assert_eq!(firing("GateDataStale"), Some(0.0));
    let m = state.render_metrics();
    assert_eq!(
        sample(&m, "gatewatch_window_gaps_total{gate=\"g1\"}"),
        Some(0.0)
    );
    // two negative windows (for_windows = 2): GateNegativeDamping fires
    let mut sent = 50usize;
    for k in 0..2 {
        post_json(&app, uniform("g1", sent as f64 / 100.0, 50)).await;
        sent += 50;
        wait_until(|| fake.calls.lock().unwrap().len() == k + 1 && state.pool().in_flight() == 0)
            .await;
    }
    assert_eq!(state.alert_state("g1"), Some("firing"));
    assert_eq!(firing("GateNegativeDamping"), Some(1.0));
    // the window's amplitude, as the analysis reports it
    let m = state.render_metrics();
    assert_eq!(sample(&m, "gatewatch_amplitude{gate=\"g1\"}"), Some(2.5));
    // the data stops: the displayed state turns unknown, the alert keeps firing, and the
    // staleness alert fires too
    state.tick(SystemTime::now() + Duration::from_secs(120));
    assert_eq!(state.alert_state("g1"), Some("unknown"));
    let m = state.render_metrics();
    assert_eq!(
        sample(&m, "gatewatch_alert_state{gate=\"g1\",state=\"firing\"}"),
        Some(0.0)
    );
    assert_eq!(firing("GateNegativeDamping"), Some(1.0));
    assert_eq!(firing("GateDataStale"), Some(1.0));
    // data again: the staleness alert resolves, the damping alert still fires
    post_json(&app, uniform("g1", sent as f64 / 100.0, 10)).await;
    assert_eq!(firing("GateDataStale"), Some(0.0));
    assert_eq!(firing("GateNegativeDamping"), Some(1.0));
}

#[tokio::test]
async fn known_label_sets_start_at_zero_and_process_metrics_exist() {
    let (_app, state) = make_app("");
    let m = state.render_metrics();
    for series in [
        "gatewatch_samples_rejected_total{reason=\"duplicate\"}",
        "gatewatch_samples_rejected_total{reason=\"non_finite\"}",
        "gatewatch_samples_rejected_total{reason=\"bad_line\"}",
        "gatewatch_ingest_requests_rejected_total{reason=\"body_too_large\"}",
        "gatewatch_ingest_requests_rejected_total{reason=\"invalid\"}",
        "gatewatch_ingest_requests_rejected_total{reason=\"overloaded\"}",
        "gatewatch_identification_failures_total{reason=\"window\"}",
        "gatewatch_identification_failures_total{reason=\"panic\"}",
        "gatewatch_identification_failures_total{reason=\"queue_full\"}",
        "gatewatch_notifications_queued_total",
        "gatewatch_notifications_total{outcome=\"delivered\",target=\"webhook\"}",
        "gatewatch_notifications_total{outcome=\"dropped\",target=\"alertmanager\"}",
        "gatewatch_tcp_connections_rejected_total{reason=\"connection_limit\"}",
        "gatewatch_tcp_connections_rejected_total{reason=\"not_allowed\"}",
    ] {
        assert_eq!(sample(&m, series), Some(0.0), "{series} in\n{m}");
    }
    // one unit per counter: request-level reasons are not samples
    assert!(!m.contains("gatewatch_samples_rejected_total{reason=\"body_too_large\"}"));
    assert_eq!(
        sample(
            &m,
            &format!(
                "gatewatch_build_info{{version=\"{}\"}}",
                env!("CARGO_PKG_VERSION")
            )
        ),
        Some(1.0)
    );
    // the `process` collector (Linux)
    let rss = sample(&m, "process_resident_memory_bytes").expect("process_* metrics");
    assert!(rss > 0.0);
    assert!(m.contains("process_open_fds "));
}

#[tokio::test]
async fn body_too_large_counts_requests_and_http_metrics_label_code() {
    let (app, state) = make_app("body_limit_bytes = 1024");
    let big = serde_json::json!({"gate": "g1", "start": 0.0, "rate_hz": 100.0,
        "values": vec![0.5; 1000]});
    let (s, _) = post_json(&app, big).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE);
    let (s, _) = post_json(&app, uniform("g1", 0.0, 10)).await;
    assert_eq!(s, StatusCode::NO_CONTENT);
    let (s, _, _) = send(&app, "GET", "/nowhere", Body::empty(), None).await;
    assert_eq!(s, StatusCode::NOT_FOUND);
    let m = state.render_metrics();
    assert_eq!(
        sample(
            &m,
            "gatewatch_ingest_requests_rejected_total{reason=\"body_too_large\"}"
        ),
        Some(1.0)
    );
    assert_eq!(
        sample(
            &m,
            "gatewatch_http_requests_total{code=\"204\",route=\"/api/v1/samples\"}"
        ),
        Some(1.0),
        "{m}"
    );
    assert!(
        m.contains("gatewatch_http_requests_total{code=\"413\""),
        "{m}"
    );
    assert!(!m.contains("status=\""), "{m}");
}

fn free_port() -> u16 {
    port_in_use().1
}

/// A listener on a port chosen by the system (held while it lives), and that port.
fn port_in_use() -> (std::net::TcpListener, u16) {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    (taken, port)
}

/// Starts `gatewatch serve --config CFG` without `RUST_LOG`, its stderr written to `log`.
fn serve_logging_to(cfg: &std::path::Path, log: &std::path::Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["serve", "--config"])
        .arg(cfg)
        .env_remove("RUST_LOG")
        .stdout(Stdio::null())
        .stderr(Stdio::from(std::fs::File::create(log).unwrap()))
        .spawn()
        .unwrap()
}

/// Waits (up to `timeout`, else fails with `never`) until the file `log` holds `what`.
fn wait_for_log(log: &std::path::Path, what: &str, timeout: Duration, never: &str) {
    let deadline = Instant::now() + timeout;
    while !std::fs::read_to_string(log)
        .unwrap_or_default()
        .contains(what)
    {
        assert!(Instant::now() < deadline, "{never}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Stops `child` with SIGTERM and returns its exit status.
fn terminate(child: &mut std::process::Child) -> std::process::ExitStatus {
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    child.wait().unwrap()
}

/// `gatewatch ARGS CFG` with `RUST_LOG` set to `rust_log` (removed when `None`): its exit
/// status and its stderr.
fn gw_with_config(
    args: &[&str],
    cfg: &std::path::Path,
    rust_log: Option<&str>,
) -> (std::process::ExitStatus, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gatewatch"));
    cmd.args(args).arg(cfg);
    match rust_log {
        Some(v) => cmd.env("RUST_LOG", v),
        None => cmd.env_remove("RUST_LOG"),
    };
    let out = cmd.output().unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `serve` with text logs and stderr to a file (as under systemd with `StandardError=file:`
/// or a shell redirect): no ESC byte, and the TCP peer printed as an address.
#[test]
fn text_logs_to_a_file_have_no_colour_codes_and_plain_peers() {
    let dir = tempfile::tempdir().unwrap();
    let (http, tcp) = (free_port(), free_port());
    let cfg = dir.path().join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{http}\"\ntcp_listen = \"127.0.0.1:{tcp}\"\n\
             shutdown_grace_seconds = 2.0\nworker_threads = 1\n[log]\nformat = \"text\"\n\
             level = \"info\"\n"
        ),
    )
    .unwrap();
    let log = dir.path().join("stderr.log");
    let mut child = serve_logging_to(&cfg, &log);
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut sock = loop {
        if let Ok(s) = std::net::TcpStream::connect(("127.0.0.1", tcp)) {
            break s;
        }
        assert!(Instant::now() < deadline, "the TCP listener never came up");
        std::thread::sleep(Duration::from_millis(50));
    };
    // a bad line: logged with the peer
    sock.write_all(b"this is not line protocol\n").unwrap();
    wait_for_log(
        &log,
        "bad line",
        Duration::from_secs(10),
        "the bad line was never logged",
    );
    drop(sock);
    let status = terminate(&mut child);
    let text = std::fs::read(&log).unwrap();
    let shown = String::from_utf8_lossy(&text);
    assert!(status.success(), "{shown}");
    assert!(!text.contains(&0x1b), "ANSI escape in a log file:\n{shown}");
    assert!(shown.contains("peer=127.0.0.1:"), "{shown}");
    assert!(!shown.contains("Some("), "{shown}");
    assert!(shown.contains("shut down"), "logs go to stderr:\n{shown}");
    // loopback only: no plain-HTTP warning, no missing-authentication one (see the next test)
    assert!(!shown.contains("plain HTTP"), "{shown}");
    assert!(!shown.contains("no authentication"), "{shown}");
}

/// Issue 12 point 10: `serve` on a non-loopback address warns at start that tokens and data
/// cross the network in clear, and names the remedy (docs/security.md, "TLS").
#[test]
fn plain_http_on_a_non_loopback_address_is_a_logged_warning() {
    let dir = tempfile::tempdir().unwrap();
    let http = free_port();
    let cfg = dir.path().join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"0.0.0.0:{http}\"\nshutdown_grace_seconds = 2.0\n\
             worker_threads = 1\n[log]\nformat = \"text\"\nlevel = \"info\"\n"
        ),
    )
    .unwrap();
    let log = dir.path().join("stderr.log");
    let mut child = serve_logging_to(&cfg, &log);
    wait_for_log(
        &log,
        "HTTP listener up",
        Duration::from_secs(30),
        "the HTTP listener never came up",
    );
    assert!(terminate(&mut child).success());
    let shown = std::fs::read_to_string(&log).unwrap();
    let warning = shown
        .lines()
        .find(|l| l.contains("plain HTTP on a non-loopback address"))
        .unwrap_or_else(|| panic!("no warning:\n{shown}"));
    assert!(warning.contains("WARN"), "{warning}");
    assert!(warning.contains(&format!("0.0.0.0:{http}")), "{warning}");
    assert!(warning.contains("TLS reverse proxy"), "{warning}");
    // and, without tokens, that anyone who reaches the port can write, naming the keys
    let warning = shown
        .lines()
        .find(|l| l.contains("no authentication on a non-loopback address"))
        .unwrap_or_else(|| panic!("no warning about the missing tokens:\n{shown}"));
    assert!(warning.contains("WARN"), "{warning}");
    assert!(warning.contains(&format!("0.0.0.0:{http}")), "{warning}");
    for key in [
        "server.auth_tokens",
        "GATEWATCH_AUTH_TOKENS",
        "server.listen",
    ] {
        assert!(warning.contains(key), "{key}: {warning}");
    }
    assert!(warning.contains("create gates"), "{warning}");
}

/// A port already in use stops `serve` (exit 1) with a line naming the key and the address,
/// for either listener: the OS's `Address already in use (os error 98)` alone did not say
/// which of the two ports clashed, nor with what.
#[test]
fn a_port_in_use_is_named_by_its_key_and_address() {
    let (taken, port) = port_in_use();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("gatewatch.toml");
    for (key, server) in [
        ("server.listen", format!("listen = \"127.0.0.1:{port}\"")),
        (
            "server.tcp_listen",
            format!(
                "listen = \"127.0.0.1:{}\"\ntcp_listen = \"127.0.0.1:{port}\"",
                free_port()
            ),
        ),
    ] {
        std::fs::write(
            &cfg,
            format!("[server]\n{server}\nworker_threads = 1\n[storage]\npath = \"gw.db\"\n"),
        )
        .unwrap();
        let (status, err) = gw_with_config(&["serve", "--config"], &cfg, None);
        assert_eq!(status.code(), Some(1), "{err}");
        let line = err
            .lines()
            .rfind(|l| l.starts_with("gatewatch: "))
            .unwrap_or_else(|| panic!("no error line:\n{err}"));
        assert_eq!(
            line,
            format!("gatewatch: {key} 127.0.0.1:{port}: cannot bind: Address already in use"),
            "{err}"
        );
    }
    drop(taken);
}

/// An invalid `RUST_LOG` was replaced by `log.level` without a word, and a misspelt level
/// (`debugg`, valid syntax for "the target `debugg` only") silenced every line. Now `serve`
/// uses `log.level` and says so in a warning naming `RUST_LOG`, its value and the reason;
/// `check-config` and `demo` say it too.
#[test]
fn an_invalid_rust_log_is_a_warning_naming_it_and_log_level_is_used() {
    let (taken, port) = port_in_use();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{port}\"\nworker_threads = 1\n[storage]\n\
             path = \"gw.db\"\n[log]\nlevel = \"info\"\n"
        ),
    )
    .unwrap();
    for (value, reason) in [
        ("debugg", "`debugg` is not a level"),
        (
            "gatewatch=lol",
            "`gatewatch=lol`: error parsing level filter",
        ),
    ] {
        // serve (it stops at the port in use, after its first log lines)
        let (status, err) = gw_with_config(&["serve", "--config"], &cfg, Some(value));
        assert_eq!(status.code(), Some(1), "{err}");
        let warning = err
            .lines()
            .find(|l| l.contains("RUST_LOG is invalid"))
            .unwrap_or_else(|| panic!("RUST_LOG={value}: no warning:\n{err}"));
        assert!(warning.contains("WARN"), "{warning}");
        assert!(warning.contains(&format!("rust_log={value}")), "{warning}");
        assert!(warning.contains(reason), "{warning}");
        assert!(warning.contains("log_level=info"), "{warning}");
        // log.level in force (`debugg` as a filter silenced even this error)
        assert!(
            err.lines()
                .any(|l| l.contains("ERROR") && l.contains("cannot bind")),
            "RUST_LOG={value}:\n{err}"
        );

        // check-config: still valid (exit 0), with the warning
        let (status, err) = gw_with_config(&["check-config"], &cfg, Some(value));
        assert_eq!(status.code(), Some(0), "{err}");
        assert!(
            err.contains(&format!("warning: RUST_LOG={value:?} is invalid"))
                && err.contains(reason),
            "{err}"
        );
    }
    // a valid RUST_LOG stays silent about itself
    let (status, err) = gw_with_config(&["check-config"], &cfg, Some("warn,gatewatch=debug"));
    assert!(status.success() && !err.contains("RUST_LOG"), "{err}");
    // demo: the same warning, on its own default (`warn`)
    let out = Command::new(env!("CARGO_BIN_EXE_gatewatch"))
        .args(["demo", "--duration", "0.2"])
        .env("RUST_LOG", "inof")
        .stdout(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.lines()
            .any(|l| l.contains("RUST_LOG is invalid") && l.contains("rust_log=inof")),
        "{err}"
    );
    drop(taken);
}

/// With `log.format = "json"`, a failing `serve` wrote its fatal error as a plain
/// `gatewatch: ...` line after the JSON logs (and its start-up warnings in plain text), which
/// a shipper parsing JSON drops. Every line is JSON now, the fatal one with the whole reason,
/// also when `log.level` mutes errors.
#[test]
fn json_logs_keep_the_fatal_line_and_the_warnings_json() {
    let (taken, port) = port_in_use();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("gatewatch.toml");
    let missing = dir.path().join("no-such-dir").join("gw.db");
    for (server, storage, level, reason) in [
        (
            format!("listen = \"127.0.0.1:{port}\""),
            "gw.db".to_string(),
            "info",
            format!("server.listen 127.0.0.1:{port}: cannot bind"),
        ),
        (
            "listen = \"127.0.0.1:0\"".to_string(),
            missing.display().to_string(),
            "off",
            format!("storage file {}", missing.display()),
        ),
    ] {
        std::fs::write(
            &cfg,
            format!(
                "[server]\n{server}\nworker_threads = 1\n[storage]\npath = {storage:?}\n\
                 [log]\nformat = \"json\"\nlevel = \"{level}\"\n[notify]\n\
                 alertmanager_urls = [\"http://127.0.0.1:9093\"]\nresend_interval_seconds = 900\n"
            ),
        )
        .unwrap();
        let (status, err) = gw_with_config(&["serve", "--config"], &cfg, None);
        assert_eq!(status.code(), Some(1), "{err}");
        let lines: Vec<serde_json::Value> = err
            .lines()
            .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
            .collect();
        let fatal: Vec<_> = lines.iter().filter(|v| v["level"] == "ERROR").collect();
        assert_eq!(fatal.len(), 1, "one fatal line:\n{err}");
        assert_eq!(fatal[0]["fields"]["message"], "gatewatch failed", "{err}");
        let error = fatal[0]["fields"]["error"].as_str().unwrap_or_default();
        assert!(error.starts_with(&reason), "{error}");
        assert!(fatal[0]["timestamp"].as_str().is_some(), "{err}");
        assert!(
            lines.iter().any(|v| v["level"] == "WARN"
                && v["fields"]["message"]
                    .as_str()
                    .is_some_and(|m| m.contains("resend_interval_seconds = 900"))),
            "the configuration's warning:\n{err}"
        );
    }
    drop(taken);
}

/// A `gatewatch serve` child on free ports with text logs at info to a file, a store in a
/// temporary directory, 100 Hz gates with a 1 s window identified every 0.5 s, and `extra`
/// appended to its `[server]` table; returned once `/readyz` answers 200.
struct LoggingDaemon {
    child: std::process::Child,
    base: String,
    tcp: u16,
    log: std::path::PathBuf,
    _dir: tempfile::TempDir,
}

impl LoggingDaemon {
    async fn start(extra: &str) -> LoggingDaemon {
        gatewatch::service::client::ensure_crypto_provider();
        let dir = tempfile::tempdir().unwrap();
        let (http, tcp) = (free_port(), free_port());
        let cfg = dir.path().join("gatewatch.toml");
        std::fs::write(
            &cfg,
            format!(
                "[server]\nlisten = \"127.0.0.1:{http}\"\ntcp_listen = \"127.0.0.1:{tcp}\"\n\
                 shutdown_grace_seconds = 2.0\nworker_threads = 1\n{extra}\n\
                 [log]\nformat = \"text\"\nlevel = \"info\"\n\
                 [storage]\npath = \"{}\"\n\
                 [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
                 stagger = false\n",
                dir.path().join("gw.db").display()
            ),
        )
        .unwrap();
        let log = dir.path().join("stderr.log");
        let child = serve_logging_to(&cfg, &log);
        let base = format!("http://127.0.0.1:{http}");
        let deadline = Instant::now() + Duration::from_secs(30);
        while !reqwest::get(format!("{base}/readyz"))
            .await
            .is_ok_and(|r| r.status() == 200)
        {
            assert!(Instant::now() < deadline, "the daemon never got ready");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        LoggingDaemon {
            child,
            base,
            tcp,
            log,
            _dir: dir,
        }
    }

    /// POSTs `body` to `/api/v1/samples`, asserting it is accepted.
    async fn post(&self, client: &reqwest::Client, body: &serde_json::Value) {
        let r = client
            .post(format!("{}/api/v1/samples", self.base))
            .json(body)
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{}", r.status());
    }

    /// The value of `series` on `/metrics` now (0 when absent).
    async fn metric(&self, series: &str) -> f64 {
        let m = reqwest::get(format!("{}/metrics", self.base))
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        sample(&m, series).unwrap_or(0.0)
    }

    /// Stops the daemon (SIGTERM, a clean exit) and returns its log's WARN lines holding `what`.
    fn stop_and_count_warnings(mut self, what: &str) -> (usize, String) {
        assert!(terminate(&mut self.child).success());
        let shown = std::fs::read_to_string(&self.log).unwrap();
        let warned = shown
            .lines()
            .filter(|l| l.contains("WARN") && l.contains(what))
            .count();
        (warned, shown)
    }
}

/// Unix seconds `ago` seconds before now.
fn seconds_ago(ago: f64) -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
        - ago
}

/// A gate whose windows cannot be analysed (a constant signal: a sensor stuck, a gate at rest)
/// fails every `identify_every_seconds`; each failure logged a warning (17 280 lines a day per
/// gate at 5 s). Now a gate's failures are logged once per `FAILURE_LOG_INTERVAL` (60 s), each
/// still counted in `gatewatch_identification_failures_total`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gate_whose_windows_fail_logs_one_warning_per_interval() {
    let d = LoggingDaemon::start("").await;
    let client = reqwest::Client::new();
    let failed = "gatewatch_identification_failures_total{reason=\"window\"}";
    // a constant signal, a second at a time: a window due with each request
    let start = seconds_ago(30.0);
    let mut sent = 0;
    let deadline = Instant::now() + Duration::from_secs(60);
    while d.metric(failed).await < 8.0 {
        assert!(Instant::now() < deadline, "the windows never failed");
        let body = serde_json::json!({
            "gate": "flat", "start": start + sent as f64, "rate_hz": 100, "values": vec![0.5; 100]
        });
        d.post(&client, &body).await;
        sent += 1;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let (warned, shown) = d.stop_and_count_warnings("identification failed");
    assert_eq!(warned, 1, "{shown}");
    assert!(shown.contains("gate=\"flat\""), "{shown}");
}

/// A source at another rate than its gate's mismatches every window, and each mismatch logged
/// a warning; now once per `FAILURE_LOG_INTERVAL` per gate, each sample still counted in
/// `gatewatch_samples_rejected_total{reason="rate_mismatch"}`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_source_at_the_wrong_rate_logs_one_warning_per_interval() {
    let d = LoggingDaemon::start("").await;
    let mut sock = std::net::TcpStream::connect(("127.0.0.1", d.tcp)).unwrap();
    // 30 s at 125 Hz on a 100 Hz gate: every window of 100 samples mismatches
    let start = seconds_ago(40.0);
    let lines: String = (0..3750)
        .map(|i| {
            let ns = ((start + f64::from(i) / 125.0) * 1e9) as i64;
            format!("m,gate=fast force={} {ns}\n", f64::from(i % 5) * 0.1)
        })
        .collect();
    sock.write_all(lines.as_bytes()).unwrap();
    drop(sock);
    let deadline = Instant::now() + Duration::from_secs(30);
    // every line applied (the window takes each sample, mismatched or not)
    while d
        .metric("gatewatch_samples_ingested_total{gate=\"fast\"}")
        .await
        < 3750.0
    {
        assert!(
            Instant::now() < deadline,
            "the lines were never all applied"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mismatched = d
        .metric("gatewatch_samples_rejected_total{reason=\"rate_mismatch\"}")
        .await;
    assert!(mismatched > 1000.0, "{mismatched}");
    let (warned, shown) = d.stop_and_count_warnings("imply another sample rate");
    assert_eq!(warned, 1, "{shown}");
}

/// With `server.job_queue` under the gates that have a window due, windows are dropped; each
/// drop logged a warning. Now at most one per `FAILURE_LOG_INTERVAL` for the daemon, each drop
/// still counted in `gatewatch_identification_failures_total{reason="queue_full"}`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn windows_dropped_on_a_full_queue_log_one_warning_per_interval() {
    let d = LoggingDaemon::start("job_queue = 1").await;
    let client = reqwest::Client::new();
    let dropped = "gatewatch_identification_failures_total{reason=\"queue_full\"}";
    let start = seconds_ago(60.0);
    let mut sent = 0;
    let deadline = Instant::now() + Duration::from_secs(60);
    // eight gates, a noisy second each at once: one identifies, one waits, the rest are dropped
    while d.metric(dropped).await < 8.0 {
        assert!(Instant::now() < deadline, "no window was dropped");
        let batches: Vec<serde_json::Value> = (0..8)
            .map(|g| {
                let values: Vec<f64> = (0..100)
                    .map(|i| ((sent * 100 + i) as f64 * 0.65).sin() + 0.1 * f64::from(g))
                    .collect();
                serde_json::json!({
                    "gate": format!("q{g}"), "start": start + sent as f64, "rate_hz": 100,
                    "values": values
                })
            })
            .collect();
        d.post(&client, &serde_json::Value::from(batches)).await;
        sent += 1;
    }
    let (warned, shown) = d.stop_and_count_warnings("identification queue full");
    assert_eq!(warned, 1, "{shown}");
}
