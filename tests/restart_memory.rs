//! A gate's analysis memory across a restart (`service::resume`): the REAL daemon
//! (`server::run`, real analyzers, a real SQLite file) identifies a stable lab gate for a
//! minute of sample time, stops, and starts again on the same file. The trend it showed comes
//! back before any new sample, and the first window after the restart already has the gate's
//! ambient level and the tracking model; with `storage.resume_analysis = false` none of that
//! survives. Streams run in lockstep with the daemon (sample time); every wait is bounded.

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use gatewatch::service::config::Config;
use gatewatch::simulate::{GatePreset, GateSimulator, NoiseLevel, ScenarioName};
use serde_json::Value;

use crate::stream_common;

/// Longest wait for one window's identification.
const WINDOW_TIMEOUT: Duration = Duration::from_secs(180);
const RATE: f64 = 200.0;

/// Start of the stream, Unix seconds: ten minutes ago, whole seconds, so that the store's
/// retention (30 days, pruned at each start) keeps the windows.
fn start() -> f64 {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    (now - 600) as f64
}

struct Daemon {
    start: f64,
    addr: SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    client: reqwest::Client,
}

/// The daemon on its store file `dir/gw.db`, the lab gate `g1` (10 s windows every 5 s).
async fn daemon(dir: &Path, resume: bool, start: f64) -> Daemon {
    gatewatch::service::client::ensure_crypto_provider();
    let cfg = Config::from_toml(&format!(
        "[server]\nlisten = \"127.0.0.1:0\"\nworker_threads = 1\nshutdown_grace_seconds = 5.0\n\
         [storage]\npath = \"{}\"\nresume_analysis = {resume}\n\
         [defaults]\nrate_hz = {RATE}\nmax_past_seconds = 0.0\n\
         [defaults.alert]\nstale_after_seconds = 600.0\n\
         [gates.g1]\n",
        dir.join("gw.db").display()
    ))
    .unwrap();
    let (addr, stop, task) = stream_common::run_daemon(cfg).await;
    let d = Daemon {
        start,
        addr,
        stop,
        task,
        client: reqwest::Client::new(),
    };
    tokio::time::timeout(Duration::from_secs(30), async {
        while d.gate("g1").await.is_null() {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("the daemon serves its configured gate");
    d
}

impl Daemon {
    async fn gate(&self, gate: &str) -> Value {
        let url = format!("http://{}", self.addr);
        stream_common::gate_view(&self.client, &url, gate).await
    }

    /// Sends samples `first..first + n` of `sim` and waits until the window ending with the
    /// last one is identified; returns the gate's view then.
    async fn step(&self, sim: &mut GateSimulator, first: u64, n: u64) -> Value {
        let url = format!("http://{}", self.addr);
        let sent = stream_common::send(&url, "g1", sim, self.start, first, n).await;
        assert_eq!(sent, n);
        let end = self.start + (first + n - 1) as f64 / RATE;
        let url = format!("http://{}", self.addr);
        let span = (self.start, end, 0.5 / RATE);
        stream_common::wait_analysed(&self.client, &url, "g1", span, WINDOW_TIMEOUT).await
    }

    async fn metrics(&self) -> String {
        stream_common::metrics(&self.client, &format!("http://{}", self.addr)).await
    }

    async fn stop(self) {
        stream_common::stop_daemon(self.stop, self.task).await;
    }
}

/// Streams `sim` from sample `from` for `seconds`: the first window whole (with the gate's
/// stagger) if the daemon has no samples yet (`fresh`), then one 5 s cadence step at a time. Returns the views and the next
/// sample index.
async fn stream(
    d: &Daemon,
    sim: &mut GateSimulator,
    from: u64,
    seconds: f64,
    fresh: bool,
) -> (Vec<Value>, u64) {
    let every = (5.0 * RATE) as u64;
    let window = stream_common::first_window_samples("g1", (10.0 * RATE) as u64, every);
    let end = from + (seconds * RATE) as u64;
    let mut sent = from;
    let mut views = Vec::new();
    let mut first = fresh;
    while sent < end {
        let n = if first { window } else { every };
        first = false;
        views.push(d.step(sim, sent, n).await);
        sent += n;
    }
    (views, sent)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_keeps_the_trend_the_ambient_level_and_the_tracking_model() {
    let dir = tempfile::tempdir().unwrap();
    let p = GatePreset::Lab.params();
    let def = ScenarioName::Stable.def(&p);
    let mut sim = def.simulator(&p, NoiseLevel::Relative(0.125), 7).unwrap();
    let mut warm = vec![0.0; (def.warmup_s * RATE).round() as usize];
    sim.fill(&mut warm);

    let t0 = start();
    let d = daemon(dir.path(), true, t0).await;
    // 9 windows (10 s every 5 s up to 50 s); the windows ending at 35 to 60 s are tracked
    let (views, next) = stream(&d, &mut sim, 0, 50.0, true).await;
    let before = views.last().unwrap().clone();
    assert!(
        before["trend"].is_object(),
        "9 windows make a trend: {}",
        before["trend"]
    );
    assert!(before["identification"]["damping"]["ambient_ratio"].is_number());
    d.stop().await;

    // restarted on the same file: the trend is back before any sample, exactly
    let d = daemon(dir.path(), true, t0).await;
    let resumed = d.gate("g1").await;
    assert_eq!(resumed["trend"], before["trend"]);
    // and on the dashboard: the trend's gauge, before any window
    let slope = before["trend"]["slope_per_second"].as_f64().unwrap();
    let metrics = d.metrics().await;
    let gauge = metrics
        .lines()
        .find(|l| l.starts_with("gatewatch_damping_ratio_trend_per_second{gate=\"g1\"}"))
        .and_then(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("no trend gauge after the restart:\n{metrics}"));
    assert_eq!(gauge, slope);
    assert!(resumed["identification"].is_null(), "no window yet");
    // the first window after the restart (10 s of new samples) has the level and the model
    let (views, next) = stream(&d, &mut sim, next, 10.0, true).await;
    let first = &views[0]["identification"];
    eprintln!(
        "after the restart: path {} ratio {} trend {}",
        first["path"], first["damping"]["ambient_ratio"], views[0]["trend"]
    );
    assert!(
        first["damping"]["ambient_ratio"].is_number(),
        "the ambient level survived: {}",
        first["damping"]
    );
    assert_eq!(first["path"], "tracked", "the tracking model survived");
    assert!(views[0]["trend"].is_object());
    d.stop().await;

    // without the resumption: the same file, but every gate starts afresh
    let d = daemon(dir.path(), false, t0).await;
    assert!(d.gate("g1").await["trend"].is_null());
    let (views, _) = stream(&d, &mut sim, next, 10.0, true).await;
    let first = &views[0]["identification"];
    assert!(first["damping"]["ambient_ratio"].is_null(), "{first}");
    assert_eq!(first["path"], "full");
    assert!(views[0]["trend"].is_null());
    d.stop().await;
}
