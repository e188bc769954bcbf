//! End to end: the REAL daemon (`server::run`, real analyzers) on a loopback port 0, a simulated
//! gate streamed through `POST /api/v1/samples` (the `simulate` client), and a REAL webhook
//! receiver (a small axum server in the test) registered as the notifier's target.
//!
//! The stream runs as fast as possible, in lockstep with the daemon: identification windows are
//! cut in sample time, so after each `identify_every_seconds` of samples the test waits until the
//! daemon has finished that window (`analysed_until` of `GET /api/v1/gates/{id}`). No window is
//! skipped, whatever the machine's speed, and the results are in stream time. Every wait is
//! bounded by a timeout; nothing asserts on wall-clock durations.

use crate::stream_common;

use std::net::SocketAddr;
use std::time::Duration;

use gatewatch::service::config::Config;
use gatewatch::simulate::{
    GateParams, GatePreset, GateSimulator, NoiseLevel, ScenarioName, ZetaSchedule,
};
use serde_json::Value;
use tokio::sync::mpsc;

/// Longest wait for one window's identification.
const WINDOW_TIMEOUT: Duration = Duration::from_secs(180);
/// Longest wait for a webhook delivery.
const HOOK_TIMEOUT: Duration = Duration::from_secs(30);
/// Start of the streams, Unix seconds.
const START: f64 = 1_700_000_000.0;

/// The webhook receiver: every payload POSTed to /hook, through a bounded queue.
struct Hook {
    addr: SocketAddr,
    rx: mpsc::Receiver<Value>,
    task: tokio::task::JoinHandle<()>,
}

async fn hook() -> Hook {
    let (tx, rx) = mpsc::channel::<Value>(1024);
    let app = axum::Router::new()
        .route(
            "/hook",
            axum::routing::post(
                |axum::extract::State(tx): axum::extract::State<mpsc::Sender<Value>>,
                 axum::Json(v): axum::Json<Value>| async move {
                    match tx.try_send(v) {
                        Ok(()) => axum::http::StatusCode::OK,
                        Err(_) => axum::http::StatusCode::SERVICE_UNAVAILABLE,
                    }
                },
            ),
        )
        .with_state(tx);
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    let task = tokio::spawn(async move {
        axum::serve(l, app).await.unwrap();
    });
    Hook { addr, rx, task }
}

/// `(status, alertname, gate)` of every alert in a webhook payload.
fn alerts_of(payload: &Value) -> Vec<(String, String, String)> {
    payload["alerts"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|a| {
                    (
                        a["status"].as_str().unwrap_or("").to_string(),
                        a["labels"]["alertname"].as_str().unwrap_or("").to_string(),
                        a["labels"]["gate"].as_str().unwrap_or("").to_string(),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

impl Hook {
    /// Waits (bounded) for an alert `(status, alertname)` of `gate`; returns every alert seen.
    async fn wait_for(
        &mut self,
        status: &str,
        name: &str,
        gate: &str,
    ) -> Vec<(String, String, String)> {
        let mut seen = Vec::new();
        let found = tokio::time::timeout(HOOK_TIMEOUT, async {
            while let Some(p) = self.rx.recv().await {
                assert_eq!(p["version"], "4", "Alertmanager webhook format: {p}");
                for a in alerts_of(&p) {
                    let hit = a.0 == status && a.1 == name && a.2 == gate;
                    seen.push(a);
                    if hit {
                        return;
                    }
                }
            }
        })
        .await;
        assert!(
            found.is_ok(),
            "no {status} {name} for {gate} within {HOOK_TIMEOUT:?}; got {seen:?}"
        );
        seen
    }

    /// Everything received so far, without waiting.
    fn drain(&mut self) -> Vec<(String, String, String)> {
        let mut out = Vec::new();
        while let Ok(p) = self.rx.try_recv() {
            out.extend(alerts_of(&p));
        }
        out
    }
}

struct Daemon {
    /// The daemon's own store file lives here (never a file shared with another test).
    _dir: tempfile::TempDir,
    addr: SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    client: reqwest::Client,
}

async fn daemon(hook: SocketAddr, gate_toml: &str) -> Daemon {
    gatewatch::service::client::ensure_crypto_provider();
    // `run` opens the store: each daemon its own file (tests run in parallel, and a shared file
    // would carry one test's alert states into another)
    let dir = tempfile::tempdir().unwrap();
    let cfg = Config::from_toml(&format!(
        "[server]\nlisten = \"127.0.0.1:0\"\nworker_threads = 1\nshutdown_grace_seconds = 5.0\n\
         [storage]\npath = \"{}\"\n\
         [notify]\ninitial_backoff_ms = 50\nmax_backoff_ms = 500\n\
         [[notify.webhooks]]\nurl = \"http://{hook}/hook\"\n\
         {gate_toml}\n",
        dir.path().join("gw.db").display()
    ))
    .unwrap();
    let (addr, stop, task) = stream_common::run_daemon(cfg).await;
    Daemon {
        _dir: dir,
        addr,
        stop,
        task,
        client: reqwest::Client::new(),
    }
}

impl Daemon {
    async fn gate(&self, gate: &str) -> Value {
        self.client
            .get(format!("http://{}/api/v1/gates/{gate}", self.addr))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap_or(Value::Null)
    }

    async fn metrics(&self) -> String {
        stream_common::metrics(&self.client, &format!("http://{}", self.addr)).await
    }

    /// Sends `seconds` of samples of `sim` from sample `first` on (one request).
    async fn send(&self, gate: &str, sim: &mut GateSimulator, first: u64, seconds: f64) -> u64 {
        let n = (seconds * sim.params().rate_hz).round() as u64;
        let url = format!("http://{}", self.addr);
        stream_common::send(&url, gate, sim, START, first, n).await
    }

    async fn stop(self) {
        stream_common::stop_daemon(self.stop, self.task).await;
    }
}

/// What the daemon said about one window.
#[derive(Debug, Clone)]
struct Step {
    /// Stream time of the window's last sample, s.
    end: f64,
    /// True damping ratio at `end`.
    true_zeta: f64,
    zeta0: Option<f64>,
    trusted: bool,
    /// `GateNegativeDamping` firing after this window.
    firing: bool,
    /// Every alert firing after this window, by name.
    alerts: Vec<String>,
    /// The window's `zeta0_interval`.
    interval: Option<(f64, f64)>,
    /// The window's own interval where `zeta0_interval` reaches down to the trend
    /// (`window_interval`, absent elsewhere).
    own: Option<(f64, f64)>,
    /// The window's `zeta0_source`.
    source: Option<String>,
    state: String,
}

/// Streams `sim` for `duration` seconds of sample time in steps of `every` seconds, waiting after
/// each step until the daemon has finished the window it made due. `window` is the window length.
async fn lockstep(
    d: &Daemon,
    gate: &str,
    sim: &mut GateSimulator,
    duration: f64,
    window: f64,
    every: f64,
) -> Vec<Step> {
    let rate = sim.params().rate_hz;
    let every_n = (every * rate).round() as u64;
    let window_n =
        stream_common::first_window_samples(gate, (window * rate).round() as u64, every_n);
    let total = (duration * rate).round() as u64;
    let mut sent = 0u64;
    let mut steps = Vec::new();
    while sent < total {
        // first the whole window (and the gate's stagger), then one cadence step at a time
        let n = if sent < window_n {
            window_n - sent
        } else {
            every_n
        };
        let got = d.send(gate, sim, sent, n as f64 / rate).await;
        assert_eq!(got, n);
        sent += n;
        let end = START + (sent - 1) as f64 / rate;
        // sample times are sums of floats near 1.7e9: compare to half a sample period
        let half = 0.5 / rate;
        let url = format!("http://{}", d.addr);
        let v =
            stream_common::wait_analysed(&d.client, &url, gate, (START, end, half), WINDOW_TIMEOUT)
                .await;
        let ident = &v["identification"];
        let fresh = ident["window_end"]
            .as_f64()
            .is_some_and(|t| (t - end).abs() < half);
        let t = end - START;
        let step = Step {
            end: t,
            true_zeta: sim.true_zeta(t),
            zeta0: fresh.then(|| ident["damping"]["zeta0"].as_f64()).flatten(),
            trusted: fresh && ident["damping"]["trusted"].as_bool() == Some(true),
            firing: v["firing"].as_bool().unwrap(),
            alerts: v["alerts"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|a| a["name"].as_str().map(String::from))
                .collect(),
            interval: fresh
                .then(|| {
                    let iv = &ident["damping"]["zeta0_interval"];
                    Some((iv[0].as_f64()?, iv[1].as_f64()?))
                })
                .flatten(),
            own: fresh
                .then(|| {
                    let iv = &ident["damping"]["window_interval"];
                    Some((iv[0].as_f64()?, iv[1].as_f64()?))
                })
                .flatten(),
            source: fresh
                .then(|| ident["damping"]["zeta0_source"].as_str().map(String::from))
                .flatten(),
            state: v["alert_state"].as_str().unwrap_or("").to_string(),
        };
        eprintln!(
            "t {:7.1} s  true {:+.4}  zeta0 {:?}  trusted {}  firing {}  state {}  error {}",
            step.end,
            step.true_zeta,
            step.zeta0,
            step.trusted,
            step.firing,
            step.state,
            v["last_error"]
        );
        steps.push(step);
    }
    steps
}

fn replaced(metrics: &str) -> f64 {
    metrics
        .lines()
        .find(|l| l.starts_with("gatewatch_identification_jobs_replaced_total"))
        .and_then(|l| l.split_whitespace().last())
        .and_then(|v| v.parse().ok())
        .unwrap_or(f64::NAN)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn onset_fires_negative_damping_and_recovery_resolves_it() {
    let mut hook = hook().await;
    let (window, every) = (10.0, 5.0);
    let d = daemon(
        hook.addr,
        &format!(
            "[defaults]\nrate_hz = 200.0\nmax_past_seconds = 0.0\nwindow_seconds = {window}\nidentify_every_seconds = {every}\n\
             [defaults.alert]\nstale_after_seconds = 600.0\n"
        ),
    )
    .await;
    // onset: +2 % for 40 s, ramp to -2 % at 140 s, hold, back to +2 % at 240 s
    let table = vec![
        (0.0, 0.02),
        (40.0, 0.02),
        (140.0, -0.02),
        (200.0, -0.02),
        (240.0, 0.02),
        (360.0, 0.02),
    ];
    let mut sim = GateSimulator::new(GateParams::default(), ZetaSchedule::Table(table), 11);
    let t_minus_1 = sim
        .schedule()
        .first_time_at_or_below(-0.01, 0.0, 360.0, 0.5)
        .unwrap();
    let t_still_1 = sim
        .schedule()
        .first_time_at_or_below(0.01, 0.0, 360.0, 0.5)
        .unwrap();
    let steps = lockstep(&d, "g1", &mut sim, 360.0, window, every).await;

    // never fires while the true damping is at least +1 % over the whole window
    for s in steps.iter().filter(|s| s.end <= t_still_1) {
        assert!(!s.firing, "false alarm at {} s: {s:?}", s.end);
    }
    let fired = steps
        .iter()
        .find(|s| s.firing)
        .expect("GateNegativeDamping fired");
    eprintln!("fired at {} s, -1 % at {t_minus_1} s", fired.end);
    // KNOWN LIMIT (issue 8, open): on this ramp (0.04 % per second) the gate grows into its
    // limit cycle within a few windows of zero. With seed 11 the window ending at 105 s
    // (true -0.6 %) reads -0.06 % (-0.10, -0.02): negative, but one window does not fire
    // (`for_windows = 2`; even `fire_at_once_probability = 0.999`, off by default, would not:
    // P(zeta0 < 0) = 0.9986), and the limit-cycle windows after it
    // read "unknown" (envelope intervals across zero) until 145 s, so the alert fires 35 s
    // after -1 %, while GateDampingDeclining warned before (see `slow_drift_warns_before_zero`).
    // The bound keeps it from getting later still; issue 8's target is before -1 %.
    assert!(
        fired.end <= t_minus_1 + 40.0,
        "fired at {} s of stream time, more than 40 s after zeta reached -1 % at {t_minus_1} s",
        fired.end
    );
    let resolved = steps
        .iter()
        .find(|s| s.end > fired.end && !s.firing)
        .expect("GateNegativeDamping resolved after the damping recovered");
    assert!(
        resolved.true_zeta > 0.0,
        "resolved while still self-excited: {resolved:?}"
    );
    let seen = hook.wait_for("firing", "GateNegativeDamping", "g1").await;
    assert!(
        !seen.iter().any(|a| a.1 == "GateDataStale"),
        "no stale alert while streaming: {seen:?}"
    );
    hook.wait_for("resolved", "GateNegativeDamping", "g1").await;
    assert_eq!(
        replaced(&d.metrics().await),
        0.0,
        "lockstep: no job replaced"
    );
    d.stop().await;
    hook.task.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stable_gate_for_30_minutes_fires_nothing() {
    let mut hook = hook().await;
    let (window, every) = (10.0, 10.0);
    let d = daemon(
        hook.addr,
        &format!(
            "[defaults]\nrate_hz = 100.0\nmax_past_seconds = 0.0\nwindow_seconds = {window}\nidentify_every_seconds = {every}\n\
             [defaults.alert]\nstale_after_seconds = 600.0\n"
        ),
    )
    .await;
    let params = GateParams {
        rate_hz: 100.0,
        ..Default::default()
    };
    let mut sim = GateSimulator::scenario(params, gatewatch::simulate::Scenario::Stable, 5);
    let steps = lockstep(&d, "g1", &mut sim, 1800.0, window, every).await;
    assert!(steps.iter().all(|s| !s.firing), "fired on a stable gate");
    // the identification ran and saw positive damping (the test is not vacuous)
    let mut zetas: Vec<f64> = steps
        .iter()
        .filter(|s| s.trusted)
        .filter_map(|s| s.zeta0)
        .collect();
    assert!(
        zetas.len() * 10 >= steps.len() * 9,
        "only {} of {} windows identified and trusted",
        zetas.len(),
        steps.len()
    );
    zetas.sort_by(f64::total_cmp);
    assert!(
        zetas[zetas.len() / 2] > 0.0,
        "median zeta0 {}",
        zetas[zetas.len() / 2]
    );
    // shutdown flushes the notifier: whatever was sent has arrived
    d.stop().await;
    let got = hook.drain();
    assert!(got.is_empty(), "alerts on a stable gate: {got:?}");
    hook.task.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_stream_fires_data_stale_and_new_data_resolves_it() {
    let mut hook = hook().await;
    let d = daemon(
        hook.addr,
        "[defaults]\nrate_hz = 200.0\nmax_past_seconds = 0.0\n[defaults.alert]\nstale_after_seconds = 1.0\n",
    )
    .await;
    let mut sim = GateSimulator::scenario(
        GateParams::default(),
        gatewatch::simulate::Scenario::Stable,
        3,
    );
    // a stray sender (a typo in a gate's name): a second of samples, never a full window
    let mut stray = GateSimulator::scenario(
        GateParams::default(),
        gatewatch::simulate::Scenario::Stable,
        4,
    );
    d.send("quiet-typo", &mut stray, 0, 1.0).await;
    // a window's worth of samples: the auto-accepted gate counts as a sensor
    d.send("quiet", &mut sim, 0, 10.0).await;
    // the stream stops: the stale check (every second) fires after 1 s of silence
    let seen = hook.wait_for("firing", "GateDataStale", "quiet").await;
    assert!(!seen.iter().any(|a| a.1 == "GateNegativeDamping"));
    let v = d.gate("quiet").await;
    assert_eq!(v["alert_state"], "unknown", "stale data: state unknown");
    assert_eq!(v["alerts"][0]["name"], "GateDataStale");
    // the stray gate, silent longer, pages nothing (it expires unless it sends again)
    assert!(
        !seen.iter().any(|a| a.2 == "quiet-typo"),
        "a stray gate paged: {seen:?}"
    );
    let v = d.gate("quiet-typo").await;
    assert_eq!(v["alerts"], serde_json::json!([]), "{v}");
    // data again: resolved
    d.send("quiet", &mut sim, 2000, 1.0).await;
    hook.wait_for("resolved", "GateDataStale", "quiet").await;
    let m = d.metrics().await;
    let delivered = m
        .lines()
        .find(|l| {
            l.starts_with("gatewatch_notifications_total{outcome=\"delivered\",target=\"webhook\"}")
        })
        .and_then(|l| l.split_whitespace().last())
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0);
    assert!(delivered >= 1.0, "delivered counter exported:\n{m}");
    d.stop().await;
    hook.task.abort();
}

/// Samples of `def`'s warm-up (before `t = 0`), dropped so the stream starts at `t = 0`.
fn skip_warmup(sim: &mut GateSimulator, warmup_s: f64) {
    let mut warm = vec![0.0; (warmup_s * sim.params().rate_hz).round() as usize];
    sim.fill(&mut warm);
}

/// Issue 8, "done when": on the slow drift (+2 % to -2 % over 20 minutes) of the lab gate with a
/// load cell's noise floor, the trend warning `GateDampingDeclining` fires before the true
/// damping crosses zero (the window it fires on ends before the crossing, in sample time, as the
/// API reads it), and reaches the webhook; `GateNegativeDamping` only after it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_drift_warns_before_zero() {
    let mut hook = hook().await;
    let (window, every) = (10.0, 5.0);
    let d = daemon(
        hook.addr,
        "[defaults]\nrate_hz = 200.0\nmax_past_seconds = 0.0\n\
         [defaults.alert]\nstale_after_seconds = 600.0\n",
    )
    .await;
    let p = GatePreset::Lab.params();
    let def = ScenarioName::SlowDrift.def(&p);
    let mut sim = def.simulator(&p, NoiseLevel::Relative(0.125), 3).unwrap();
    skip_warmup(&mut sim, def.warmup_s);
    let t_zero = def
        .zeta
        .first_time_at_or_below(0.0, 0.0, def.duration_s, 0.5)
        .unwrap();
    let steps = lockstep(&d, "g1", &mut sim, t_zero + 30.0, window, every).await;
    let warned = steps
        .iter()
        .find(|s| s.alerts.iter().any(|a| a == "GateDampingDeclining"))
        .unwrap_or_else(|| panic!("GateDampingDeclining never fired up to {t_zero} s"));
    assert!(
        warned.end < t_zero,
        "warned at {} s, after the zero crossing at {t_zero} s",
        warned.end
    );
    // the warning comes from the trend, not from a negative reading: the gate was still damped
    assert!(warned.true_zeta > 0.0, "{warned:?}");
    assert!(
        steps
            .iter()
            .filter(|s| s.end <= warned.end)
            .all(|s| !s.firing),
        "GateNegativeDamping fired before the warning"
    );
    // the declining gate's intervals reach down to the trend's forecast (docs/damping.md, "A
    // declining gate's interval reaches down to its trend"): only downwards, never before the
    // trend spans trend_min_span_seconds (300 s), and not at all while the gate is steady
    let reached: Vec<&Step> = steps.iter().filter(|s| s.own.is_some()).collect();
    assert!(!reached.is_empty(), "no interval reached down to the trend");
    for s in &reached {
        let ((lo, hi), (own_lo, own_hi)) = (s.interval.unwrap(), s.own.unwrap());
        assert!(lo < own_lo && hi == own_hi, "{s:?}");
        assert!(s.end > 300.0, "{s:?}");
    }
    let drift_start = def
        .zeta
        .first_time_at_or_below(def.zeta.at(0.0) - 1e-4, 0.0, def.duration_s, 0.5)
        .unwrap();
    assert!(reached.iter().all(|s| s.end > drift_start), "{reached:?}");
    hook.wait_for("firing", "GateDampingDeclining", "g1").await;
    d.stop().await;
    hook.task.abort();
}

/// A daemon configured for a bench preset gate (its rate and stiffness, alerts kept fresh for 10
/// minutes) and the seeded scenario's simulator on it, past its warm-up, with the bench's noise.
async fn scenario_daemon(
    hook: SocketAddr,
    preset: GatePreset,
    scenario: ScenarioName,
    seed: u64,
) -> (Daemon, GateSimulator) {
    let p = preset.params();
    let d = daemon(
        hook,
        &format!(
            "[defaults]\nrate_hz = {}\nstiffness = {}\nmax_past_seconds = 0.0\n\
             [defaults.alert]\nstale_after_seconds = 600.0\n",
            p.rate_hz, p.stiffness
        ),
    )
    .await;
    let def = scenario.def(&p);
    let mut sim = def
        .simulator(&p, NoiseLevel::Relative(0.125), seed)
        .unwrap();
    skip_warmup(&mut sim, def.warmup_s);
    (d, sim)
}

/// Issue 8, "done when": a gate held on its -2 % limit cycle (lock gate, 2000 kg, 5 Hz, 100 Hz
/// sampling, sensor noise) fires `GateNegativeDamping` and never resolves it, and the reported
/// `zeta0` is right: median within 0.5 points of the truth, and the intervals cover it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn held_limit_cycle_keeps_firing_with_the_right_zeta0() {
    let mut hook = hook().await;
    let (window, every) = (10.0, 5.0);
    let (d, mut sim) =
        scenario_daemon(hook.addr, GatePreset::Lock, ScenarioName::LimitCycle, 4).await;
    let steps = lockstep(&d, "g1", &mut sim, 180.0, window, every).await;
    let fired = steps
        .iter()
        .position(|s| s.firing)
        .expect("GateNegativeDamping fired on the held limit cycle");
    assert!(
        steps[fired..].iter().all(|s| s.firing),
        "resolved on the held limit cycle: {:?}",
        steps[fired..].iter().find(|s| !s.firing)
    );
    let mut errors: Vec<f64> = steps
        .iter()
        .filter_map(|s| s.zeta0.map(|z| (z - s.true_zeta).abs()))
        .collect();
    assert!(errors.len() * 10 >= steps.len() * 9, "{steps:?}");
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    assert!(median <= 0.005, "median |zeta0 error| {median}");
    let with_interval: Vec<_> = steps
        .iter()
        .filter_map(|s| s.interval.map(|iv| (iv, s.true_zeta)))
        .collect();
    let covered = with_interval
        .iter()
        .filter(|((lo, hi), z)| lo <= z && z <= hi)
        .count();
    assert!(
        covered * 10 >= with_interval.len() * 8,
        "{covered} of {} intervals cover the truth",
        with_interval.len()
    );
    hook.wait_for("firing", "GateNegativeDamping", "g1").await;
    d.stop().await;
    let got = hook.drain();
    assert!(
        !got.iter()
            .any(|a| a.0 == "resolved" && a.1 == "GateNegativeDamping"),
        "resolved: {got:?}"
    );
    hook.task.abort();
}

/// A gate that bursts into its limit cycle again and again (the lab gate, -3 % for 15 s of every
/// 90 s): the cycle after each growth is read from its amplitude through the damping law the
/// growth identified (`zeta0_source = "amplitude"`, docs/damping.md, "The cycle's amplitude"),
/// right where the envelope alone read -3 % as about -2 %: within 0.5 points, the interval
/// covering the truth, and the alert fires on the first burst.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_cycle_is_read_from_its_amplitude() {
    let mut hook = hook().await;
    let (window, every) = (10.0, 5.0);
    let (d, mut sim) = scenario_daemon(hook.addr, GatePreset::Lab, ScenarioName::Bursting, 3).await;
    let steps = lockstep(&d, "g1", &mut sim, 170.0, window, every).await;
    let read: Vec<_> = steps
        .iter()
        .filter(|s| s.source.as_deref() == Some("amplitude"))
        .collect();
    assert!(
        !read.is_empty(),
        "no cycle read from its amplitude: {steps:?}"
    );
    for s in &read {
        // the cycle's damping: the burst's, which the window holds (it may end in the decay)
        let burst = (0..=20)
            .map(|k| sim.true_zeta(s.end - window * k as f64 / 20.0))
            .fold(f64::INFINITY, f64::min);
        let (z, (lo, hi)) = (s.zeta0.unwrap(), s.interval.unwrap());
        assert!(
            (z - burst).abs() <= 0.005 && lo <= burst && burst <= hi,
            "{s:?} against {burst}"
        );
    }
    assert!(
        steps.iter().any(|s| s.firing && s.end < 90.0),
        "GateNegativeDamping did not fire on the first burst: {steps:?}"
    );
    hook.wait_for("firing", "GateNegativeDamping", "g1").await;
    d.stop().await;
    hook.task.abort();
}
