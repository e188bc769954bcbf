//! gatewatch against the alerting stack operators run, as they ship: Debian's `prometheus` and
//! `prometheus-alertmanager` on loopback, the shipped `deploy/prometheus` files, and the real
//! `gatewatch serve` and `gatewatch simulate` binaries (nothing in-process, nothing mocked).
//!
//! One scenario, in the order an operator lives it:
//! 1. a gate's damping drifts through zero: gatewatch's own `GateNegativeDamping` reaches
//!    Alertmanager, and the shipped Prometheus rule `GateSelfExcited` fires for it too;
//! 2. gatewatch is restarted while the gate is still self-excited: Alertmanager must not send a
//!    "resolved" for it (the alert is re-asserted before Alertmanager's resolve timeout);
//! 3. the gate recovers: both alerts resolve, and Alertmanager says so to its receiver.
//!
//! The test copies the shipped files and changes only what a test must: the addresses (free
//! loopback ports), the scrape and evaluation intervals, and the rules' `for:` durations (seconds
//! instead of minutes, so the test takes a minute, not ten). The expressions and labels are the
//! shipped ones. Without the binaries the test is skipped, except under CI (`CI` set), where
//! `.ci/run` installs them and a missing one is a failure.

use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const PROMETHEUS: &str = "prometheus";
const ALERTMANAGER: &str = "prometheus-alertmanager";

/// Alertmanager resolves an alert not re-sent within this; short, so that a restart that fails
/// to re-assert its alerts shows as a false "resolved" within the test.
const AM_RESOLVE_TIMEOUT_S: u64 = 20;

fn have(bin: &str) -> bool {
    Command::new(bin)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Whether every server in `bins` is installed; when one is not, the test skips with a message,
/// except under CI, which must install them (Debian's packages) and fails instead.
fn servers_installed(bins: &[&str]) -> bool {
    let missing: Vec<&str> = bins.iter().copied().filter(|b| !have(b)).collect();
    if missing.is_empty() {
        return true;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI must install Debian's packages for {missing:?}"
    );
    eprintln!("skipped: {missing:?} not installed");
    false
}

/// `N` distinct free loopback ports. The listeners are all held until every port is chosen, so
/// the kernel cannot hand the same port out twice (released one by one, two calls could collide,
/// and a server started on a taken port dies before it is ready).
fn free_ports<const N: usize>() -> [u16; N] {
    let held: Vec<TcpListener> = (0..N)
        .map(|_| TcpListener::bind("127.0.0.1:0").unwrap())
        .collect();
    std::array::from_fn(|i| held[i].local_addr().unwrap().port())
}

/// A child process killed when dropped (a failing assertion must not leave servers behind).
struct Proc {
    child: Child,
    name: &'static str,
    log: PathBuf,
}

impl Proc {
    fn spawn(name: &'static str, cmd: &mut Command, dir: &Path) -> Proc {
        let log = dir.join(format!("{name}.log"));
        let f = std::fs::File::create(&log).unwrap();
        let child = cmd
            .stdout(Stdio::from(f.try_clone().unwrap()))
            .stderr(Stdio::from(f))
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Proc { child, name, log }
    }

    fn log_tail(&self) -> String {
        let s = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = s.lines().collect();
        let from = lines.len().saturating_sub(20);
        format!("--- {} log ---\n{}", self.name, lines[from..].join("\n"))
    }

    /// Waits up to `timeout` until `ready` holds. Fails at once, with the server's log, when the
    /// server exits (a port taken, a bad flag), and with the log on a timeout.
    fn wait_ready(&mut self, timeout: Duration, mut ready: impl FnMut() -> bool) {
        let deadline = Instant::now() + timeout;
        loop {
            if ready() {
                return;
            }
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!(
                    "{} exited ({status}) before it was ready\n{}",
                    self.name,
                    self.log_tail()
                );
            }
            assert!(
                Instant::now() < deadline,
                "timed out after {timeout:?} waiting for {} to be ready\n{}",
                self.name,
                self.log_tail()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// SIGTERM, then wait up to `grace` for a clean exit (SIGKILL after).
    fn terminate(&mut self, grace: Duration) -> bool {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline {
            if let Ok(Some(s)) = self.child.try_wait() {
                return s.success();
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        false
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Debian's Alertmanager on `port` with `config`, its data in `dir`. Its cluster (gossip)
/// listener is off: one instance needs no peers, and one port fewer is one race fewer.
fn spawn_alertmanager(config: &Path, port: u16, dir: &Path) -> Proc {
    Proc::spawn(
        "alertmanager",
        Command::new(ALERTMANAGER)
            .arg(format!("--config.file={}", config.display()))
            .arg(format!("--storage.path={}", dir.join("am-data").display()))
            .arg(format!("--web.listen-address=127.0.0.1:{port}"))
            .arg("--cluster.listen-address="),
        dir,
    )
}

/// GET over HTTP/1.0 (no chunked encoding, connection closed by the server): status and body.
fn http_get(port: u16, path: &str) -> Option<(u16, String)> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n").ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    let status = out.split(' ').nth(1)?.parse().ok()?;
    let body = out.split_once("\r\n\r\n").map(|x| x.1.to_string())?;
    Some((status, body))
}

fn get_json(port: u16, path: &str) -> Option<Value> {
    let (status, body) = http_get(port, path)?;
    (status == 200).then(|| serde_json::from_str(&body).ok())?
}

fn wait_until<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(250));
    }
}

/// Alertmanager's webhook notifications, as received: `(status, alertname, gate)` per alert.
type Seen = Arc<Mutex<Vec<(String, String, String)>>>;

/// A webhook receiver for Alertmanager's notifications: plain HTTP/1.1 on a std thread.
fn receiver() -> (u16, Seen) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let seen: Seen = Arc::default();
    let sink = seen.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let sink = sink.clone();
            std::thread::spawn(move || {
                let _ = serve_one(stream, &sink);
            });
        }
    });
    (port, seen)
}

fn serve_one(stream: TcpStream, sink: &Seen) -> std::io::Result<()> {
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut r = BufReader::new(stream.try_clone()?);
    let mut len = 0usize;
    loop {
        let mut line = String::new();
        if r.read_line(&mut line)? == 0 {
            return Ok(());
        }
        let l = line.trim_end();
        if l.is_empty() {
            break;
        }
        if let Some((k, v)) = l.split_once(':') {
            if k.eq_ignore_ascii_case("content-length") {
                len = v.trim().parse().unwrap_or(0);
            }
        }
    }
    let mut body = vec![0; len];
    r.read_exact(&mut body)?;
    if let Ok(v) = serde_json::from_slice::<Value>(&body) {
        let mut seen = sink.lock().unwrap();
        for a in v["alerts"].as_array().into_iter().flatten() {
            seen.push((
                a["status"].as_str().unwrap_or("").to_string(),
                a["labels"]["alertname"].as_str().unwrap_or("").to_string(),
                a["labels"]["gate"].as_str().unwrap_or("").to_string(),
            ));
        }
    }
    let mut w = stream;
    w.write_all(b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
}

/// The shipped rules with their durations shortened for a test of a minute or two: `for: 1m`
/// to 5 s, `for: 2m` to 30 s, `keep_firing_for: 2m` to 40 s (both still longer than the
/// test's restart gap, as the shipped ones are longer than a real one); expressions and labels
/// untouched.
fn test_rules() -> String {
    let shipped =
        std::fs::read_to_string(Path::new(ROOT).join("deploy/prometheus/gatewatch-rules.yml"))
            .unwrap();
    assert!(shipped.contains("keep_firing_for: 2m"));
    shipped
        .replace("keep_firing_for: 2m", "keep_firing_for: 40s")
        .replace("for: 1m", "for: 5s")
        .replace("for: 2m", "for: 30s")
}

/// The shipped prometheus.yml with the test's addresses and one-second intervals.
fn test_prometheus_yml(gw: u16, am: u16) -> String {
    let shipped =
        std::fs::read_to_string(Path::new(ROOT).join("deploy/prometheus/prometheus.yml")).unwrap();
    assert!(
        shipped.contains("alerting:") && shipped.contains("alertmanagers:"),
        "the shipped prometheus.yml must send its alerts to Alertmanager (an `alerting:` block)"
    );
    shipped
        .replace("127.0.0.1:9464", &format!("127.0.0.1:{gw}"))
        .replace("127.0.0.1:9093", &format!("127.0.0.1:{am}"))
        .replace(
            "scrape_interval: 15s",
            "scrape_interval: 1s\n  evaluation_interval: 1s",
        )
}

fn gatewatch_toml(gw: u16, am: u16) -> String {
    format!(
        r#"[server]
listen = "127.0.0.1:{gw}"
shutdown_grace_seconds = 5.0
[log]
format = "json"
[notify]
alertmanager_urls = ["http://127.0.0.1:{am}"]
resend_interval_seconds = 5.0
"#
    )
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// `gatewatch simulate` on the gate `g1`: `args` after the common ones.
fn simulate(gw: u16, args: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .args(["simulate", "--url", &format!("http://127.0.0.1:{gw}")])
        .args(["--gate", "g1"])
        .args(args)
        .output()
        .unwrap()
}

fn prometheus_alert_state(prom: u16, name: &str) -> Option<String> {
    let v = get_json(prom, "/api/v1/alerts")?;
    v["data"]["alerts"]
        .as_array()?
        .iter()
        .find(|a| a["labels"]["alertname"] == name && a["labels"]["gate"] == "g1")
        .and_then(|a| a["state"].as_str().map(str::to_string))
}

fn alertmanager_has(am: u16, name: &str) -> bool {
    get_json(am, "/api/v2/alerts").is_some_and(|v| {
        v.as_array().into_iter().flatten().any(|a| {
            a["labels"]["alertname"] == name
                && a["labels"]["gate"] == "g1"
                && a["status"]["state"] == "active"
        })
    })
}

#[test]
fn onset_restart_and_recovery_through_prometheus_and_alertmanager() {
    if !servers_installed(&[PROMETHEUS, ALERTMANAGER]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let [gw, prom, am] = free_ports();
    let (hook, seen) = receiver();

    // Alertmanager: one route to the test's receiver, resolved notifications on.
    std::fs::write(
        d.join("alertmanager.yml"),
        format!(
            "global:\n  resolve_timeout: {AM_RESOLVE_TIMEOUT_S}s\nroute:\n  receiver: hook\n  \
             group_by: ['alertname', 'gate']\n  group_wait: 1s\n  group_interval: 1s\n  \
             repeat_interval: 1h\nreceivers:\n  - name: hook\n    webhook_configs:\n      - url: \
             http://127.0.0.1:{hook}/am\n        send_resolved: true\n"
        ),
    )
    .unwrap();
    let mut am_proc = spawn_alertmanager(&d.join("alertmanager.yml"), am, d);
    std::fs::write(d.join("prometheus.yml"), test_prometheus_yml(gw, am)).unwrap();
    std::fs::write(d.join("gatewatch-rules.yml"), test_rules()).unwrap();
    let mut prom_proc = Proc::spawn(
        "prometheus",
        Command::new(PROMETHEUS)
            .arg(format!(
                "--config.file={}",
                d.join("prometheus.yml").display()
            ))
            .arg(format!(
                "--storage.tsdb.path={}",
                d.join("prom-data").display()
            ))
            .arg(format!("--web.listen-address=127.0.0.1:{prom}")),
        d,
    );
    std::fs::write(d.join("gatewatch.toml"), gatewatch_toml(gw, am)).unwrap();
    let serve = || {
        Proc::spawn(
            "gatewatch",
            Command::new(BIN)
                .args(["serve", "--config"])
                .arg(d.join("gatewatch.toml")),
            d,
        )
    };
    let mut gw_proc = serve();
    let ready = |port: u16, path: &str| http_get(port, path).is_some_and(|r| r.0 == 200);
    let up = Duration::from_secs(30);
    gw_proc.wait_ready(up, || ready(gw, "/readyz"));
    am_proc.wait_ready(up, || ready(am, "/-/ready"));
    prom_proc.wait_ready(up, || ready(prom, "/-/ready"));
    let logs = || {
        format!(
            "{}\n{}\n{}",
            am_proc.log_tail(),
            prom_proc.log_tail(),
            std::fs::read_to_string(d.join("gatewatch.log")).unwrap_or_default()
        )
    };

    // 1. Onset: 20 s at +2 %, a 20 s ramp to -2 %, then -2 %; 5x real time.
    let t0 = now_s() - 120.0;
    let out = simulate(
        gw,
        &[
            "--scenario",
            "onset",
            "--onset-hold",
            "20",
            "--onset-ramp",
            "20",
            "--duration",
            "90",
            "--speed",
            "5",
            "--start",
            &format!("{t0}"),
        ],
    );
    assert!(
        out.status.success(),
        "simulate: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let minute = Duration::from_secs(60);
    wait_until("GateNegativeDamping at Alertmanager", minute, || {
        alertmanager_has(am, "GateNegativeDamping").then_some(())
    });
    wait_until("the shipped rule GateSelfExcited firing", minute, || {
        (prometheus_alert_state(prom, "GateSelfExcited").as_deref() == Some("firing")).then_some(())
    });
    wait_until("GateSelfExcited at Alertmanager", minute, || {
        alertmanager_has(am, "GateSelfExcited").then_some(())
    });

    // 2. Restart gatewatch while the gate stays self-excited (a limit cycle at -2 %), and keep
    // the stream going for longer than Alertmanager's resolve timeout.
    assert!(
        gw_proc.terminate(Duration::from_secs(15)),
        "gatewatch did not stop cleanly"
    );
    drop(gw_proc);
    gw_proc = serve();
    gw_proc.wait_ready(up, || ready(gw, "/readyz"));
    let out = simulate(
        gw,
        &[
            "--scenario",
            "limit-cycle",
            "--duration",
            "60",
            "--speed",
            "2",
            "--start",
            &format!("{}", t0 + 90.0),
            "--seed",
            "2",
        ],
    );
    assert!(
        out.status.success(),
        "simulate: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let false_resolves: Vec<_> = seen
        .lock()
        .unwrap()
        .iter()
        .filter(|(s, _, _)| s == "resolved")
        .cloned()
        .collect();
    assert!(
        false_resolves.is_empty(),
        "Alertmanager resolved {false_resolves:?} while the gate was self-excited\n{}",
        logs()
    );
    assert!(alertmanager_has(am, "GateNegativeDamping"), "{}", logs());

    // 3. Recovery: a well-damped gate (+2 %: the onset scenario before its ramp) resolves
    // gatewatch's alert and the shipped rule. KNOWN LIMIT (issue 8, open): at +1 % the honest
    // ambient interval of a pooled 15 s record (about +-0.7 points) rarely lies above
    // `clear_above` (+0.5 %) twice in a row, so a gate recovering only to +1 % stays firing
    // for minutes (docs/alerts.md, "Resolving at +1 %").
    let out = simulate(
        gw,
        &[
            "--scenario",
            "onset",
            "--onset-hold",
            "600",
            "--duration",
            "150",
            "--speed",
            "5",
            "--start",
            &format!("{}", t0 + 150.0),
            "--seed",
            "3",
        ],
    );
    assert!(
        out.status.success(),
        "simulate: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut last_end = 0.0;
    let mut trace = || {
        // the gate's windows while waiting, for the failure message's context
        if let Some(v) = get_json(gw, "/api/v1/gates/g1") {
            let d = &v["identification"]["damping"];
            let end = v["identification"]["window_end"].as_f64().unwrap_or(0.0);
            if end != last_end {
                last_end = end;
                eprintln!(
                    "window end {:.1}: zeta0 {} {} {} trusted {} regime {} state {}",
                    end - t0,
                    d["zeta0"],
                    d["zeta0_interval"],
                    d["zeta0_source"],
                    d["trusted"],
                    d["regime"],
                    v["alert_state"]
                );
            }
        }
    };
    let resolved = |name: &str| {
        seen.lock()
            .unwrap()
            .iter()
            .any(|(s, n, g)| s == "resolved" && n == name && g == "g1")
    };
    wait_until(
        "GateNegativeDamping resolved by Alertmanager",
        2 * minute,
        || {
            trace();
            resolved("GateNegativeDamping").then_some(())
        },
    );
    // after keep_firing_for (40 s here)
    wait_until(
        "GateSelfExcited resolved by Alertmanager",
        2 * minute,
        || resolved("GateSelfExcited").then_some(()),
    );
    assert!(gw_proc.terminate(Duration::from_secs(15)));
}

/// POST a JSON body over HTTP/1.0: the status.
fn http_post_json(port: u16, path: &str, body: &str) -> Option<u16> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "POST {path} HTTP/1.0\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    out.split(' ').nth(1)?.parse().ok()
}

/// The shipped `deploy/alertmanager/alertmanager.yml`, run by the real Alertmanager: a gate's
/// `GateDampingDeclining` is inhibited while its `GateNegativeDamping` fires, another gate's is
/// not. The alerts carry the labels gatewatch sends (`alertname`, `gate`, `severity`).
#[test]
fn the_shipped_alertmanager_config_inhibits_the_warning_under_the_critical_alert() {
    if !servers_installed(&[ALERTMANAGER]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let [am] = free_ports();
    let shipped = Path::new(ROOT).join("deploy/alertmanager/alertmanager.yml");
    let mut am_proc = spawn_alertmanager(&shipped, am, d);
    am_proc.wait_ready(Duration::from_secs(30), || {
        http_get(am, "/-/ready").is_some_and(|(s, _)| s == 200)
    });
    let alert = |name: &str, gate: &str, severity: &str| {
        json!({"labels": {"alertname": name, "gate": gate, "severity": severity},
               "annotations": {"summary": format!("{name} on {gate}")}})
    };
    let body = json!([
        alert("GateNegativeDamping", "g1", "critical"),
        alert("GateDampingDeclining", "g1", "warning"),
        alert("GateDampingDeclining", "g2", "warning"),
    ])
    .to_string();
    assert_eq!(
        http_post_json(am, "/api/v2/alerts", &body),
        Some(200),
        "{}",
        am_proc.log_tail()
    );
    // state of each (alertname, gate) as Alertmanager reports it
    let states = wait_until(
        "the three alerts in Alertmanager",
        Duration::from_secs(30),
        || {
            let v = get_json(am, "/api/v2/alerts")?;
            let s: Vec<(String, String, String, usize)> = v
                .as_array()?
                .iter()
                .map(|a| {
                    (
                        a["labels"]["alertname"].as_str().unwrap_or("").to_string(),
                        a["labels"]["gate"].as_str().unwrap_or("").to_string(),
                        a["status"]["state"].as_str().unwrap_or("").to_string(),
                        a["status"]["inhibitedBy"].as_array().map_or(0, Vec::len),
                    )
                })
                .collect();
            // inhibition is evaluated as the alerts arrive; wait until the warning shows it
            (s.len() == 3 && s.iter().any(|a| a.2 == "suppressed")).then_some(s)
        },
    );
    let state = |name: &str, gate: &str| {
        states
            .iter()
            .find(|a| a.0 == name && a.1 == gate)
            .map(|a| (a.2.as_str(), a.3))
            .unwrap_or_else(|| panic!("{name} {gate} missing: {states:?}"))
    };
    assert_eq!(
        state("GateNegativeDamping", "g1"),
        ("active", 0),
        "{states:?}"
    );
    assert_eq!(
        state("GateDampingDeclining", "g1"),
        ("suppressed", 1),
        "{states:?}"
    );
    assert_eq!(
        state("GateDampingDeclining", "g2"),
        ("active", 0),
        "{states:?}"
    );
}
