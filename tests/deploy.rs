//! The shipped configurations and the deployment command line, against the real binary:
//! `gatewatch check-config` accepts every shipped configuration (config/, the Kubernetes
//! ConfigMap), and `gatewatch serve --config config/gatewatch.toml` (the Dockerfile's and the
//! systemd unit's command) starts, gets ready and stops cleanly on SIGTERM.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_gatewatch");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The `gatewatch.toml: |` block of the Kubernetes ConfigMap, unindented.
fn configmap_toml() -> String {
    let yaml =
        std::fs::read_to_string(Path::new(ROOT).join("deploy/kubernetes/gatewatch.yaml")).unwrap();
    let mut lines = yaml.lines().skip_while(|l| l.trim() != "gatewatch.toml: |");
    let header = lines.next().expect("ConfigMap has gatewatch.toml");
    let indent = header.len() - header.trim_start().len() + 2;
    lines
        .take_while(|l| l.trim().is_empty() || l.len() - l.trim_start().len() >= indent)
        .map(|l| l.get(indent..).unwrap_or("").to_string() + "\n")
        .collect()
}

fn shipped_configs(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("config"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    let k8s = dir.join("kubernetes-configmap.toml");
    std::fs::write(&k8s, configmap_toml()).unwrap();
    files.push(k8s);
    files
}

#[test]
fn check_config_accepts_every_shipped_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let files = shipped_configs(dir.path());
    assert!(files.len() >= 2);
    for f in files {
        let out = Command::new(BIN)
            .arg("check-config")
            .arg(&f)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}: {}{}",
            f.display(),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // and a broken one is refused with exit 2 and the key named
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[[notify.webhooks]]\nurl = \"ftp://x\"\n").unwrap();
    let out = Command::new(BIN)
        .arg("check-config")
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("notify"));
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn http_get(port: u16, path: &str) -> Option<String> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    Some(out)
}

#[cfg(unix)]
#[test]
fn serve_with_the_shipped_config_gets_ready_and_stops_on_sigterm() {
    // the Dockerfile's CMD and the systemd unit's ExecStart, on a free loopback port
    let port = free_port();
    // the shipped config's store is `gatewatch.db` next to it, in the checkout: a file of
    // this test's own instead (the systemd unit overrides it the same way)
    let store = tempfile::tempdir().unwrap();
    let mut child = Command::new(BIN)
        .args(["serve", "--config"])
        .arg(Path::new(ROOT).join("config/gatewatch.toml"))
        .env("GATEWATCH_LISTEN", format!("127.0.0.1:{port}"))
        .env("GATEWATCH_STORAGE_PATH", store.path().join("gatewatch.db"))
        .env("GATEWATCH_LOG_FORMAT", "json")
        .env_remove("RUST_LOG")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(store.path().join("stderr.log")).unwrap())
        .spawn()
        .unwrap();
    let mut ready = false;
    for _ in 0..200 {
        if http_get(port, "/readyz").is_some_and(|r| r.starts_with("HTTP/1.1 200")) {
            ready = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let metrics = http_get(port, "/metrics").unwrap_or_default();
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let mut exit = None;
    for _ in 0..400 {
        if let Some(s) = child.try_wait().unwrap() {
            exit = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    if exit.is_none() {
        let _ = child.kill();
    }
    assert!(
        ready,
        "serve --config config/gatewatch.toml never got ready"
    );
    assert!(metrics.contains(
        "gatewatch_notifications_total{outcome=\"delivered\",target=\"alertmanager\"} 0"
    ));
    assert!(exit.expect("exited after SIGTERM").success());
    // one JSON object a line, and none of the JIT compiler's IR: at the shipped `info` level
    // cranelift_jit logged every compiled function (about 300 lines a start)
    let log = std::fs::read_to_string(store.path().join("stderr.log")).unwrap();
    let lines: Vec<&str> = log.lines().collect();
    for line in &lines {
        let v: serde_json::Value = serde_json::from_str(line)
            .unwrap_or_else(|e| panic!("a log line that is not JSON ({e}): {line}"));
        let target = v["target"].as_str().unwrap_or_default();
        assert!(!target.starts_with("cranelift"), "{line}");
    }
    assert!(
        lines.iter().any(|l| l.contains("HTTP listener up")),
        "the start is logged: {log}"
    );
    assert!(
        lines.len() < 40,
        "{} lines at start and stop: {log}",
        lines.len()
    );
}
