//! A real `nats-server` with JetStream on a free loopback port and a store directory of its
//! own, killed when dropped; and the skip-or-fail rule for a machine without it.

use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Debian's package installs the server here; `PATH` is tried first.
const NATS_SERVER: &str = "nats-server";
const NATS_SERVER_DEBIAN: &str = "/usr/sbin/nats-server";

/// How long a server may take to listen (it starts in well under a second).
const READY_WAIT: Duration = Duration::from_secs(20);

/// The server's program, when it is installed.
fn program() -> Option<&'static str> {
    let runs = |p: &str| {
        Command::new(p)
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    [NATS_SERVER, NATS_SERVER_DEBIAN]
        .into_iter()
        .find(|p| runs(p))
}

/// Whether `nats-server` is installed; when it is not, the test skips with a message, except
/// under CI, which must install it (Debian's package `nats-server`) and fails instead.
pub fn nats_installed() -> bool {
    if program().is_some() {
        return true;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI must install Debian's package nats-server"
    );
    eprintln!("skipped: nats-server not installed");
    false
}

/// A free loopback port (the listener is closed before the server binds it).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("free port")
}

/// A running `nats-server -js`, killed when dropped.
pub struct NatsServer {
    child: Option<Child>,
    port: u16,
    store_dir: PathBuf,
    log: PathBuf,
}

impl NatsServer {
    /// Starts a server keeping its JetStream data under `dir`, on a free port.
    pub fn start(dir: &Path) -> NatsServer {
        let mut s = NatsServer {
            child: None,
            port: free_port(),
            store_dir: dir.join("jetstream"),
            log: dir.join("nats-server.log"),
        };
        s.restart();
        s
    }

    /// The client URL.
    pub fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// Whether the server still runs, and its log: for the message of a test that lost its
    /// server.
    pub fn report(&mut self) -> String {
        let state = match self.child.as_mut().map(|c| c.try_wait()) {
            None => "stopped by the test".to_string(),
            Some(Ok(None)) => "running".to_string(),
            Some(Ok(Some(status))) => format!("exited: {status}"),
            Some(Err(e)) => format!("state unknown: {e}"),
        };
        let log = std::fs::read_to_string(&self.log).unwrap_or_default();
        format!("nats-server on port {} {state}; its log:\n{log}", self.port)
    }

    /// Kills the server (its data stays in the store directory).
    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Starts the server again on the same port and store directory (stopping it first if it
    /// runs), and waits until it listens; a server that exits or does not listen in time fails
    /// the test with its log.
    pub fn restart(&mut self) {
        self.stop();
        let log = std::fs::File::create(&self.log).expect("nats-server log");
        let child = Command::new(program().expect("nats-server installed"))
            .args([
                "-js",
                "-a",
                "127.0.0.1",
                "-p",
                &self.port.to_string(),
                "-sd",
            ])
            .arg(&self.store_dir)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("spawn nats-server");
        self.child = Some(child);
        let deadline = Instant::now() + READY_WAIT;
        loop {
            if TcpStream::connect(("127.0.0.1", self.port)).is_ok() {
                return;
            }
            let exited = self
                .child
                .as_mut()
                .and_then(|c| c.try_wait().ok().flatten());
            if exited.is_some() || Instant::now() > deadline {
                panic!(
                    "nats-server on port {} {}: {}",
                    self.port,
                    if exited.is_some() {
                        "exited"
                    } else {
                        "not listening in time"
                    },
                    std::fs::read_to_string(&self.log).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for NatsServer {
    fn drop(&mut self) {
        self.stop();
    }
}
