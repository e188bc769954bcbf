//! Helpers shared by the `service_*` daemon tests: a scripted analyzer, the test
//! configuration, `oneshot` requests without a socket, and a real server on port 0.
//! Every wait is bounded by a timeout.
#![allow(dead_code)]

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use axum::Router;
use gatewatch::analysis::{AnalysisError, DampingReport, Verdict, WindowAnalysis, WindowInput};
use gatewatch::service::config::Config;
use gatewatch::service::server::{build_app, run_with_analyzer, Listeners};
use gatewatch::service::state::AppState;
use gatewatch::service::worker::WindowAnalyzer;
use serde_json::{json, Value};
use tower::ServiceExt;

pub const TOKEN: &str = "test-token-0123456789";

/// What the fake analyzer saw.
#[derive(Debug, Clone)]
pub struct Call {
    pub gate: String,
    pub t0: f64,
    pub len: usize,
    pub warm: Option<Vec<f64>>,
    pub seed: u64,
}

/// Scripted analyzer: zeta0 from a schedule, optional sleep, optional panic on a call number.
#[derive(Default)]
pub struct Fake {
    pub zeta: Vec<f64>,
    pub sleep: Duration,
    /// Call number `n` (from 0) waits until [`Fake::release`] (at most `HOLD_LIMIT`): one job
    /// held in flight for as long as the test needs it, however slow the machine.
    pub hold_call: Option<usize>,
    pub released: AtomicBool,
    pub panic_on: Option<usize>,
    /// Every window reported untrusted (`damping.trusted = false`).
    pub untrusted: bool,
    pub calls: Mutex<Vec<Call>>,
    pub n: AtomicUsize,
}

/// How long a held call waits for [`Fake::release`] before going on by itself: a test that
/// forgets to release (or fails first) does not hang its worker.
pub const HOLD_LIMIT: Duration = Duration::from_secs(30);

impl Fake {
    /// Lets the held call (`hold_call`) finish.
    pub fn release(&self) {
        self.released.store(true, Ordering::SeqCst);
    }
}

impl WindowAnalyzer for Fake {
    fn analyze(
        &self,
        gate: &str,
        input: WindowInput<'_>,
        warm: Option<&[f64]>,
        seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        let n = self.n.fetch_add(1, Ordering::SeqCst);
        self.calls.lock().unwrap().push(Call {
            gate: gate.into(),
            t0: input.t0,
            len: input.values.len(),
            warm: warm.map(<[f64]>::to_vec),
            seed,
        });
        std::thread::sleep(self.sleep);
        if self.hold_call == Some(n) {
            let start = std::time::Instant::now();
            while !self.released.load(Ordering::SeqCst) && start.elapsed() < HOLD_LIMIT {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        if self.panic_on == Some(n) {
            panic!("scripted numerical bug");
        }
        let zeta0 = self
            .zeta
            .get(n)
            .or(self.zeta.last())
            .copied()
            .unwrap_or(0.05);
        Ok(WindowAnalysis {
            equation: format!("ydd + {zeta0}*yd + y = 0"),
            coefficients: vec![("c1".into(), zeta0), ("c2".into(), 1.0)],
            damping: DampingReport {
                zeta0: Some(zeta0),
                // a sharp 95 % interval: the alert engine decides on the interval, and a
                // window without one is no evidence
                zeta0_interval: Some((zeta0 - 0.0005, zeta0 + 0.0005)),
                zeta_eq: Some(zeta0),
                frequency_hz: Some(1.5),
                amplitude: Some(2.5),
                agrees: Some(true),
                fit_nmae: 0.01,
                trusted: !self.untrusted,
                verdict: if zeta0 < 0.0 {
                    Verdict::SelfExcited
                } else {
                    Verdict::Damped
                },
                ..DampingReport::unknown()
            },
            evaluations: 1,
            seconds: 0.0,
            warm_start: vec![n as f64],
            path: Default::default(),
        })
    }
}

/// The service tests' configuration: 1 s windows every 0.5 s at 100 Hz, the first window as
/// soon as it is full (`stagger = false`: these tests count windows from the start; the stagger
/// has its own tests in `service_workers` and `service::window`).
pub fn config(extra: &str) -> Config {
    config_with_defaults(extra, "")
}

/// [`config`] with more keys of `[defaults]` (`defaults`, TOML lines).
pub fn config_with_defaults(extra: &str, defaults: &str) -> Config {
    Config::from_toml(&format!(
        "[server]\nworker_threads = 1\nlisten = \"127.0.0.1:0\"\n{extra}\n\
         [defaults]\nrate_hz = 100.0\nwindow_seconds = 1.0\nidentify_every_seconds = 0.5\n\
         max_past_seconds = 0.0\nstagger = false\n{defaults}\n"
    ))
    .unwrap()
}

pub fn app_with(cfg: Config, fake: Arc<Fake>) -> (Router, Arc<AppState>) {
    build_app(cfg, fake).unwrap()
}

pub fn make_app(extra: &str) -> (Router, Arc<AppState>) {
    app_with(config(extra), Arc::new(Fake::default()))
}

pub async fn send(
    app: &Router,
    method: &str,
    uri: &str,
    body: impl Into<Body>,
    token: Option<&str>,
) -> (StatusCode, Value, axum::http::HeaderMap) {
    let mut req = Request::builder().method(method).uri(uri);
    if let Some(t) = token {
        req = req.header("authorization", format!("Bearer {t}"));
    }
    let resp = tokio::time::timeout(
        Duration::from_secs(10),
        app.clone().oneshot(req.body(body.into()).unwrap()),
    )
    .await
    .expect("request timed out")
    .unwrap();
    let status = resp.status();
    let headers = resp.headers().clone();
    let bytes = axum::body::to_bytes(resp.into_body(), usize::MAX)
        .await
        .unwrap();
    let v = serde_json::from_slice(&bytes)
        .unwrap_or(Value::String(String::from_utf8_lossy(&bytes).into()));
    (status, v, headers)
}

pub async fn post_json(app: &Router, body: Value) -> (StatusCode, Value) {
    let (s, v, _) = send(app, "POST", "/api/v1/samples", body.to_string(), None).await;
    (s, v)
}

pub fn uniform(gate: &str, start: f64, n: usize) -> Value {
    let values: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).sin()).collect();
    json!({"gate": gate, "start": start, "rate_hz": 100.0, "values": values})
}

pub async fn wait_until(mut f: impl FnMut() -> bool) {
    tokio::time::timeout(Duration::from_secs(10), async {
        while !f() {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("condition not reached within 10 s");
}

pub fn metric(state: &AppState, prefix: &str) -> f64 {
    state
        .metrics
        .render()
        .lines()
        .filter(|l| l.starts_with(prefix))
        .map(|l| l.rsplit(' ').next().unwrap().parse::<f64>().unwrap())
        .sum()
}

// ---------------------------------------------------------------- a real server on port 0

pub struct Running {
    pub http: std::net::SocketAddr,
    pub tcp: std::net::SocketAddr,
    /// The health listener (`server.health_listen`: the probes and `/metrics`).
    pub health: std::net::SocketAddr,
    pub stop: tokio::sync::oneshot::Sender<()>,
    pub task: tokio::task::JoinHandle<anyhow::Result<()>>,
}

pub async fn start(extra: &str, fake: Arc<Fake>) -> Running {
    gatewatch::service::client::ensure_crypto_provider();
    let cfg = config(&format!(
        "tcp_listen = \"127.0.0.1:0\"\nshutdown_grace_seconds = 2.0\n{extra}"
    ));
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let tcp = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let health = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let (ha, ta) = (http.local_addr().unwrap(), tcp.local_addr().unwrap());
    let health_addr = health.local_addr().unwrap();
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(run_with_analyzer(
        cfg,
        Listeners {
            http,
            tcp: Some(tcp),
            health: Some(health),
        },
        fake,
        async move {
            let _ = rx.await;
        },
    ));
    Running {
        http: ha,
        tcp: ta,
        health: health_addr,
        stop,
        task,
    }
}

pub async fn get(addr: std::net::SocketAddr, path: &str) -> (u16, String) {
    let r = reqwest::get(format!("http://{addr}{path}")).await.unwrap();
    (r.status().as_u16(), r.text().await.unwrap())
}

/// A real server on port 0 (as `start`) with a default scripted analyzer.
pub async fn start_default(extra: &str) -> Running {
    start(extra, Arc::new(Fake::default())).await
}

/// Connects to `addr` and writes `bytes` on the new connection.
pub async fn connect_and_write(addr: std::net::SocketAddr, bytes: &[u8]) -> tokio::net::TcpStream {
    use tokio::io::AsyncWriteExt;
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(bytes).await.unwrap();
    s
}

/// Polls `GET path` every 20 ms until `done(status, body)`, for at most `secs` s (else fails
/// naming `what`).
pub async fn wait_for_get(
    addr: std::net::SocketAddr,
    path: &str,
    secs: u64,
    what: &str,
    done: impl Fn(u16, &str) -> bool,
) {
    tokio::time::timeout(Duration::from_secs(secs), async {
        loop {
            let (status, body) = get(addr, path).await;
            if done(status, &body) {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{what}: not within {secs} s"));
}

/// Waits (up to 10 s) until gate `gate` has `n` samples.
pub async fn wait_for_samples(addr: std::net::SocketAddr, gate: &str, n: usize) {
    let want = format!("\"samples_total\":{n}");
    let what = format!("{n} samples of `{gate}`");
    wait_for_get(
        addr,
        &format!("/api/v1/gates/{gate}"),
        10,
        &what,
        |_, body| body.contains(&want),
    )
    .await;
}

pub async fn stop(r: Running) {
    let _ = r.stop.send(());
    tokio::time::timeout(Duration::from_secs(15), r.task)
        .await
        .expect("shutdown within the deadline")
        .unwrap()
        .unwrap();
}

/// `promtool` on PATH (required in CI).
pub fn promtool() -> Option<std::path::PathBuf> {
    let found = std::env::var_os("PATH").and_then(|p| {
        std::env::split_paths(&p)
            .map(|d| d.join("promtool"))
            .find(|f| f.is_file())
    });
    if found.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "promtool is required in CI (Debian package `prometheus`)"
        );
        eprintln!("SKIP: promtool not on PATH");
    }
    found
}
