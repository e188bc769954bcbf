//! The shipped Grafana dashboard (`deploy/grafana/gatewatch-dashboard.json`) checked as far as
//! this machine can without a Grafana (not packaged in Debian): the JSON is a dashboard Grafana
//! provisions (uid, title, schemaVersion, unique panel ids, panels inside the 24-column grid,
//! every query on the `datasource` variable), every query is valid PromQL to the real
//! Prometheus parser (`promtool check rules`, with Grafana's variables substituted), and every
//! metric a query names exists in the `/metrics` of a real `gatewatch serve` that identified a
//! window of a simulated gate.

use serde_json::Value;
use std::collections::BTreeSet;
use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn dashboard() -> Value {
    let text =
        std::fs::read_to_string(Path::new(ROOT).join("deploy/grafana/gatewatch-dashboard.json"))
            .unwrap();
    serde_json::from_str(&text).expect("the dashboard is valid JSON")
}

/// Every panel, rows' nested panels included.
fn panels(d: &Value) -> Vec<&Value> {
    let mut out = Vec::new();
    for p in d["panels"].as_array().expect("panels") {
        out.push(p);
        out.extend(p["panels"].as_array().into_iter().flatten());
    }
    out
}

/// Every PromQL expression: the panels' targets and the query variables.
fn expressions(d: &Value) -> Vec<String> {
    let mut out: Vec<String> = panels(d)
        .iter()
        .flat_map(|p| p["targets"].as_array().into_iter().flatten())
        .filter_map(|t| t["expr"].as_str().map(str::to_string))
        .collect();
    assert!(!out.is_empty(), "the dashboard queries nothing");
    for v in d["templating"]["list"].as_array().into_iter().flatten() {
        if v["type"] == "query" {
            let q = v["definition"].as_str().expect("query variable definition");
            // label_values(METRIC, label) is Grafana's, not PromQL: check its metric
            let metric = q
                .strip_prefix("label_values(")
                .and_then(|r| r.split(',').next())
                .expect("label_values(metric, label)");
            out.push(metric.trim().to_string());
        }
    }
    out
}

/// Grafana's variables replaced by values Prometheus accepts.
fn substitute(expr: &str) -> String {
    expr.replace("$__rate_interval", "1m")
        .replace("$gate", ".*")
}

/// Metric names a PromQL expression reads (histogram series mapped to their family).
fn metric_names(expr: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let bytes = expr.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let rest = &expr[i..];
        let starts = (rest.starts_with("gatewatch_") || rest.starts_with("process_"))
            && (i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_'));
        if starts {
            let len = rest
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(rest.len());
            let name = &rest[..len];
            let family = ["_bucket", "_sum", "_count"]
                .iter()
                .find_map(|s| name.strip_suffix(s))
                .unwrap_or(name);
            out.insert(family.to_string());
            i += len;
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn dashboard_is_well_formed() {
    let d = dashboard();
    assert_eq!(d["uid"], "gatewatch");
    assert!(d["title"].as_str().is_some_and(|t| !t.is_empty()));
    assert!(d["schemaVersion"].as_u64().is_some_and(|v| v >= 36));
    let mut ids = BTreeSet::new();
    for p in panels(&d) {
        let id = p["id"].as_u64().expect("panel id");
        assert!(ids.insert(id), "duplicate panel id {id}");
        let g = &p["gridPos"];
        let (x, w) = (g["x"].as_u64().unwrap(), g["w"].as_u64().unwrap());
        assert!(
            x + w <= 24 && g["h"].as_u64().unwrap() > 0,
            "panel {id} outside the grid"
        );
        if p["type"] != "row" {
            assert_eq!(p["datasource"]["uid"], "${datasource}", "panel {id}");
            assert!(p["title"].as_str().is_some_and(|t| !t.is_empty()));
            assert!(!p["targets"].as_array().expect("targets").is_empty());
        }
    }
    let vars: Vec<&str> = d["templating"]["list"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v["name"].as_str())
        .collect();
    assert!(vars.contains(&"datasource") && vars.contains(&"gate"));
    // the provisioning files point Grafana at the dashboard's folder
    let prov = std::fs::read_to_string(
        Path::new(ROOT).join("deploy/grafana/provisioning/dashboards/gatewatch.yaml"),
    )
    .unwrap();
    assert!(prov.contains("path: /var/lib/grafana/dashboards/gatewatch"));
}

/// Grafana draws the top-level panels where their `gridPos` says, and a row holds the panels
/// below it down to the next row: each panel must lie under the row it is listed after, a
/// panel of the gates' figures (a query on `$gate`) under the "Gates" row, and no two panels
/// may overlap. The trend panel (a gate's figure) sat at the bottom, under the "Daemon" row.
#[test]
fn every_panel_lies_under_its_row_and_none_overlap() {
    let d = dashboard();
    let top = d["panels"].as_array().expect("panels");
    let pos = |p: &Value, k: &str| p["gridPos"][k].as_u64().expect("gridPos");
    let rows: Vec<u64> = top
        .iter()
        .filter(|p| p["type"] == "row")
        .map(|p| pos(p, "y"))
        .collect();
    let mut row: Option<(u64, &Value)> = None;
    for p in top {
        let y = pos(p, "y");
        if p["type"] == "row" {
            row = Some((y, &p["title"]));
            continue;
        }
        let (above, title) = row.expect("a panel before the first row");
        let of_gates = p["targets"]
            .as_array()
            .into_iter()
            .flatten()
            .any(|t| t["expr"].as_str().is_some_and(|e| e.contains("$gate")));
        if of_gates {
            assert_eq!(
                title, "Gates",
                "panel {} ({}) shows gates' figures under the row {title}",
                p["id"], p["title"]
            );
        }
        let next = rows
            .iter()
            .copied()
            .find(|&r| r > above)
            .unwrap_or(u64::MAX);
        assert!(
            y > above && y + pos(p, "h") <= next,
            "panel {} ({}) at y {y} is not under its row at y {above} (next row at {next})",
            p["id"],
            p["title"]
        );
    }
    let cells = |p: &Value| {
        let (x, y, w, h) = (pos(p, "x"), pos(p, "y"), pos(p, "w"), pos(p, "h"));
        (x..x + w).flat_map(move |cx| (y..y + h).map(move |cy| (cx, cy)))
    };
    let mut taken = std::collections::HashMap::new();
    for p in top {
        for c in cells(p) {
            if let Some(other) = taken.insert(c, p["id"].clone()) {
                panic!("panels {other} and {} overlap at {c:?}", p["id"]);
            }
        }
    }
}

#[test]
fn every_query_parses_with_promtool() {
    if Command::new("promtool").arg("--version").output().is_err() {
        assert!(std::env::var_os("CI").is_none(), "CI must install promtool");
        eprintln!("skipped: promtool not installed");
        return;
    }
    let d = dashboard();
    let mut rules = String::from("groups:\n  - name: dashboard\n    rules:\n");
    for (i, e) in expressions(&d).iter().enumerate() {
        let e = substitute(e).replace('\'', "''");
        rules.push_str(&format!(
            "      - record: dashboard:q{i}\n        expr: '{e}'\n"
        ));
    }
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("rules.yml");
    std::fs::write(&f, rules).unwrap();
    let out = Command::new("promtool")
        .args(["check", "rules"])
        .arg(&f)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn get(port: u16, path: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: x\r\n\r\n").ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    // the server answers an HTTP/1.0 request as HTTP/1.0
    (out.starts_with("HTTP/1.0 200") || out.starts_with("HTTP/1.1 200"))
        .then(|| out.split_once("\r\n\r\n").map(|x| x.1.to_string()))?
}

#[test]
fn every_metric_the_dashboard_reads_is_exported() {
    let port = free_port();
    // the shipped config's store is `gatewatch.db` next to it, in the checkout: a file of
    // this test's own instead (the systemd unit overrides it the same way)
    let store = tempfile::tempdir().unwrap();
    let mut child = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(Path::new(ROOT).join("config/gatewatch.toml"))
        .env("GATEWATCH_LISTEN", format!("127.0.0.1:{port}"))
        .env("GATEWATCH_STORAGE_PATH", store.path().join("gatewatch.db"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while get(port, "/readyz").is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    // a gate that sent a few samples and was never identified (a dead sensor, a gate with a
    // firing GateDataStale): the `gate` variable must list it all the same
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let body = format!(
        "{{\"gate\": \"silent\", \"start\": {now}, \"rate_hz\": 200.0, \"values\": [0.0, 0.1, 0.2]}}"
    );
    assert_eq!(
        post(port, "/api/v1/samples", &body).as_deref(),
        Some("HTTP/1.0 204"),
        "{body}"
    );
    // one gate with an identified window, so that the per-gate families have series
    let sim = Command::new(BIN)
        .args(["simulate", "--url", &format!("http://127.0.0.1:{port}")])
        .args(["--gate", "g1", "--duration", "16", "--speed", "20"])
        .output()
        .unwrap();
    let mut metrics = String::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline {
        metrics = get(port, "/metrics").unwrap_or_default();
        if metrics.contains("gatewatch_damping_ratio{") {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    let exported: BTreeSet<&str> = metrics
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split(' ').next())
        .collect();
    let d = dashboard();
    let read: BTreeSet<String> = expressions(&d)
        .iter()
        .flat_map(|e| metric_names(e))
        .collect();
    // Series absent by design until there is evidence (an interval, a trend of 6 windows, a
    // significant decline): they must at least be defined by the daemon.
    let source = std::fs::read_to_string(Path::new(ROOT).join("src/service/metrics.rs")).unwrap();
    let absent_until_evidence = [
        "gatewatch_damping_ratio_lower",
        "gatewatch_damping_ratio_upper",
        "gatewatch_damping_ratio_trend_per_second",
        "gatewatch_damping_zero_crossing_seconds",
    ];
    let missing: Vec<&String> = read
        .iter()
        .filter(|m| !exported.contains(m.as_str()))
        .filter(|m| {
            !(absent_until_evidence.contains(&m.as_str()) && source.contains(&format!("\"{m}\"")))
        })
        .collect();
    assert!(
        missing.is_empty(),
        "the dashboard reads metrics /metrics does not export: {missing:?}"
    );
    // label names the queries group by exist on their metrics
    assert!(metrics.contains("gatewatch_http_requests_total{code="));
    // the `gate` variable's metric has a series of every gate from its creation, identified
    // (g1) or not (silent); gatewatch_damping_ratio, which it read before, hid the silent one
    let gate_var = d["templating"]["list"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["name"] == "gate")
        .and_then(|v| v["definition"].as_str())
        .unwrap();
    let metric = gate_var
        .strip_prefix("label_values(")
        .and_then(|r| r.strip_suffix(", gate)"))
        .unwrap_or_else(|| panic!("{gate_var}"));
    for gate in ["g1", "silent"] {
        assert!(
            metrics
                .lines()
                .any(|l| l.starts_with(&format!("{metric}{{"))
                    && l.contains(&format!("gate=\"{gate}\""))),
            "{gate_var} does not list gate {gate}:\n{metrics}"
        );
    }
    assert!(!metrics.contains("gatewatch_damping_ratio{gate=\"silent\"}"));
}

/// POSTs a JSON body; the status line without its reason (`HTTP/1.0 204`).
fn post(port: u16, path: &str, body: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "POST {path} HTTP/1.0\r\nHost: x\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    let line = out.lines().next()?;
    Some(line.splitn(3, ' ').take(2).collect::<Vec<_>>().join(" "))
}
