//! What the tests that drive real Python clients against the real binary share
//! (`influx_clients.rs`, `python_notebooks.rs`): a virtual environment with packages from PyPI,
//! the daemon's process, a free port and a plain HTTP GET.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

/// A `gatewatch serve`, killed when dropped so a failed assertion leaves no process behind.
pub struct Daemon(pub Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `GET path` on the loopback `port`, with a bearer `token` when given: (status, body).
/// HTTP/1.0, so a streamed answer (the history) comes whole, not in chunks.
pub fn http_get(port: u16, path: &str, token: Option<&str>) -> Option<(u16, String)> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    write!(
        s,
        "GET {path} HTTP/1.0\r\nHost: x\r\n{auth}Connection: close\r\n\r\n"
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    let status = out.get(9..12)?.parse().ok()?;
    let body = out.split_once("\r\n\r\n")?.1.to_string();
    Some((status, body))
}

/// Skips (outside CI) or fails (in CI) for a missing component.
pub fn missing(what: &str) {
    assert!(
        std::env::var_os("CI").is_none(),
        "{what} is required in CI (see .ci/run)"
    );
    eprintln!("SKIP: {what}");
}

/// The python of a new virtual environment under `dir` with `packages` installed, or `None`
/// (after [`missing`]) when python3's venv module or PyPI is out of reach.
pub fn venv_python(dir: &Path, packages: &[&str]) -> Option<PathBuf> {
    let venv = dir.join("venv");
    let made = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&venv)
        .status();
    if !made.is_ok_and(|s| s.success()) {
        missing("python3 with the venv module");
        return None;
    }
    let pip = Command::new(venv.join("bin/pip"))
        .args(["install", "--quiet", "--disable-pip-version-check"])
        .args(packages)
        .output()
        .unwrap();
    if !pip.status.success() {
        missing(&format!(
            "pip install {} (PyPI unreachable?): {}",
            packages.join(" "),
            String::from_utf8_lossy(&pip.stderr)
        ));
        return None;
    }
    Some(venv.join("bin/python"))
}
