//! Streaming a simulated gate into a daemon through `POST /api/v1/samples` (the `simulate`
//! client with the simulator as its source): shared by the end-to-end tests that drive the
//! daemon in lockstep, in sample time.

use std::time::Duration;

use gatewatch::service::client::{simulate_with_source, Protocol, Scenario, SimulateArgs};
use gatewatch::simulate::GateSimulator;

/// Sends `n` samples of `sim` for `gate` to the daemon at `url` in one request, the first of
/// them sample `first` of a stream that starts at `start` (Unix seconds); returns the samples
/// the daemon accepted. Panics when the daemon does not accept them within 60 s.
pub async fn send(
    url: &str,
    gate: &str,
    sim: &mut GateSimulator,
    start: f64,
    first: u64,
    n: u64,
) -> u64 {
    let rate = sim.params().rate_hz;
    let seconds = n as f64 / rate;
    let args = SimulateArgs {
        url: url.to_string(),
        tcp_addr: String::new(),
        gate: gate.into(),
        scenario: Scenario::Stable, // unused: the source is `sim`
        speed: 0.0,
        duration: Some(seconds),
        seed: 0,
        protocol: Protocol::Json,
        rate,
        token: None,
        chunk_seconds: seconds,
        start: Some(start + first as f64 / rate),
        onset_hold: None,
        onset_ramp: None,
        sensor: Default::default(),
    };
    tokio::time::timeout(
        Duration::from_secs(60),
        simulate_with_source(&args, |b: &mut [f64]| sim.fill(b)),
    )
    .await
    .expect("samples accepted in time")
    .expect("samples accepted")
}

/// `GET /api/v1/gates/{gate}` of the daemon at `url` as JSON (`Null` when it does not answer or
/// the gate does not exist).
pub async fn gate_view(client: &reqwest::Client, url: &str, gate: &str) -> serde_json::Value {
    match client
        .get(format!("{url}/api/v1/gates/{gate}"))
        .send()
        .await
    {
        Ok(r) => r.json().await.unwrap_or(serde_json::Value::Null),
        Err(_) => serde_json::Value::Null,
    }
}

/// `GET /metrics` of the daemon at `url`: the Prometheus text. (`store_outage` reads its
/// metrics from a daemon that may be down, with its own fallible form.)
#[allow(dead_code)]
pub async fn metrics(client: &reqwest::Client, url: &str) -> String {
    client
        .get(format!("{url}/metrics"))
        .send()
        .await
        .expect("the daemon answers /metrics")
        .text()
        .await
        .expect("a text body")
}

/// Waits until the daemon at `url` has analysed `gate` up to sample time `end` (its
/// `analysed_until` within half a sample period `half` of it: sample times are sums of floats
/// near 1.7e9) and returns the gate's view then; panics after `timeout`, naming `end - start`.
pub async fn wait_analysed(
    client: &reqwest::Client,
    url: &str,
    gate: &str,
    (start, end, half): (f64, f64, f64),
    timeout: Duration,
) -> serde_json::Value {
    tokio::time::timeout(timeout, async {
        loop {
            let v = gate_view(client, url, gate).await;
            if v["analysed_until"]
                .as_f64()
                .is_some_and(|t| t >= end - half)
            {
                return v;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("window ending at {} s not analysed", end - start))
}

/// Samples up to a gate's first due window: a full window and the gate's stagger offset (the
/// shipped default staggers each gate's first window by a fraction of the cadence fixed by its
/// ID, `service::window::stagger_offset`).
pub fn first_window_samples(gate: &str, window_n: u64, every_n: u64) -> u64 {
    window_n + gatewatch::service::window::stagger_offset(gate, every_n as usize) as u64
}

/// The daemon's task run in this process.
type DaemonTask = tokio::task::JoinHandle<anyhow::Result<()>>;

/// Runs the daemon in this process on `cfg`, its HTTP listener on a port the system chose:
/// its address, the sender that stops it, and its task.
#[allow(dead_code)]
pub async fn run_daemon(
    cfg: gatewatch::service::config::Config,
) -> (
    std::net::SocketAddr,
    tokio::sync::oneshot::Sender<()>,
    DaemonTask,
) {
    use gatewatch::service::server::{run, Listeners};
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = http.local_addr().unwrap();
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(run(cfg, Listeners::http_only(http), async move {
        let _ = rx.await;
    }));
    (addr, stop, task)
}

/// Stops a daemon [`run_daemon`] started and waits (30 s at most) for its clean end.
#[allow(dead_code)]
pub async fn stop_daemon(stop: tokio::sync::oneshot::Sender<()>, task: DaemonTask) {
    let _ = stop.send(());
    tokio::time::timeout(Duration::from_secs(30), task)
        .await
        .expect("shutdown within the deadline")
        .unwrap()
        .unwrap();
}
