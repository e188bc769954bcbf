//! The REAL Influx clients against a REAL `gatewatch serve` (the binary, on a free loopback
//! port): the official Python clients, v2 `influxdb-client` and v1 `influxdb`, installed into a
//! virtual environment inside the test's temporary directory, and Debian's 1.x `influx` CLI
//! (package `influxdb-client`). Every sample they write is then read back through
//! `GET /api/v1/gates/{id}`.
//!
//! Without network access to PyPI (or without the `influx` CLI) the test is skipped with a
//! message, except in CI (`CI` set), where it fails: `.ci/run` installs what it needs.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::Value;

use crate::python_common;
use python_common::{free_port, http_get, missing, venv_python, Daemon};

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");

fn serve(dir: &Path, port: u16) -> Daemon {
    // long windows: the few samples written here never start an identification
    let cfg = dir.join("gatewatch.toml");
    std::fs::write(
        &cfg,
        format!(
            "[server]\nlisten = \"127.0.0.1:{port}\"\nworker_threads = 1\n\
             [defaults]\nrate_hz = 100.0\nwindow_seconds = 60.0\nidentify_every_seconds = 30.0\n"
        ),
    )
    .unwrap();
    let child = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(&cfg)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let daemon = Daemon(child);
    for _ in 0..400 {
        if http_get(port, "/readyz", None).is_some_and(|(s, _)| s == 200) {
            return daemon;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!("gatewatch serve never got ready on port {port}");
}

fn samples(port: u16, gate: &str) -> u64 {
    let (status, body) = http_get(port, &format!("/api/v1/gates/{gate}"), None).expect("GET gate");
    assert_eq!(status, 200, "gate `{gate}`: {body}");
    let v: Value = serde_json::from_str(&body).unwrap();
    v["window"]["samples"].as_u64().unwrap()
}

/// Drives both Python clients; prints one JSON object with what they returned.
const SCRIPT: &str = r#"
import json, sys, time
from influxdb_client import InfluxDBClient, WritePrecision
from influxdb_client.client.write_api import SYNCHRONOUS
import influxdb

port = int(sys.argv[1])
url = f"http://127.0.0.1:{port}"
# 5 samples at 100 Hz ending a second ago (gatewatch refuses nothing recent)
t0 = time.time_ns() - 2_000_000_000
out = {}

def lines(gate):
    return [f"m,gate={gate} force={i * 0.5} {t0 + i * 10_000_000}" for i in range(5)]

for gz in (False, True):
    with InfluxDBClient(url=url, token="unused", org="o", enable_gzip=gz) as c:
        out[f"v2_ping_gzip_{gz}"] = c.ping()
        h = c.health()
        out[f"v2_health_gzip_{gz}"] = {"name": h.name, "status": h.status}
        c.write_api(write_options=SYNCHRONOUS).write(
            bucket="b", record=lines(f"v2gzip{int(gz)}"), write_precision=WritePrecision.NS)

v1 = influxdb.InfluxDBClient(host="127.0.0.1", port=port, database="gw", gzip=True)
out["v1_ping"] = v1.ping()
v1.create_database("gw")
out["v1_create_database"] = True
points = [{"measurement": "m", "tags": {"gate": "v1gzip"},
           "time": t0 // 1_000_000 + i * 10, "fields": {"force": float(i)}} for i in range(5)]
out["v1_write_points"] = v1.write_points(points, time_precision="ms")
print(json.dumps(out))
"#;

#[test]
fn python_clients_write_plain_and_gzip_ping_health_and_create_database() {
    let dir = tempfile::tempdir().unwrap();
    let Some(python) = venv_python(dir.path(), &["influxdb-client", "influxdb"]) else {
        return;
    };
    let port = free_port();
    let _daemon = serve(dir.path(), port);
    let script = dir.path().join("clients.py");
    std::fs::write(&script, SCRIPT).unwrap();
    let run = Command::new(python)
        .arg(&script)
        .arg(port.to_string())
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "the clients failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let out: Value = serde_json::from_slice(&run.stdout).unwrap();
    for gz in ["False", "True"] {
        assert_eq!(out[format!("v2_ping_gzip_{gz}")], true, "{out}");
        assert_eq!(
            out[format!("v2_health_gzip_{gz}")],
            serde_json::json!({"name": "gatewatch", "status": "pass"})
        );
    }
    assert!(out["v1_ping"].as_str().unwrap().starts_with("gatewatch-"));
    assert_eq!(out["v1_create_database"], true);
    assert_eq!(out["v1_write_points"], true);
    for gate in ["v2gzip0", "v2gzip1", "v1gzip"] {
        assert_eq!(samples(port, gate), 5, "gate {gate}");
    }
}

#[test]
fn influx_cli_1x_inserts_a_point() {
    let found = std::env::var_os("PATH")
        .is_some_and(|p| std::env::split_paths(&p).any(|d| d.join("influx").is_file()));
    if !found {
        missing("the `influx` CLI (Debian package influxdb-client)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _daemon = serve(dir.path(), port);
    // no timestamp: the server's clock, as InfluxDB does
    let out = Command::new("influx")
        .args(["-host", "127.0.0.1", "-port", &port.to_string()])
        .args(["-database", "gw", "-execute", "INSERT m,gate=cli force=1.5"])
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "influx CLI: {text}");
    assert!(!text.contains("ERR"), "influx CLI: {text}");
    assert_eq!(samples(port, "cli"), 1);
}
