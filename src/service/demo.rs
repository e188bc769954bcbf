//! `gatewatch demo`: the whole chain in one process, for a newcomer.
//!
//! 1. the daemon on the embedded default configuration, on loopback (the configured port, or an
//!    ephemeral one when it is busy);
//! 2. a webhook receiver (axum on `127.0.0.1:0`) registered as the daemon's webhook target;
//! 3. a simulated gate `g1` (the lab gate, `onset` scenario: +2 % damping, then a ramp to -2 %)
//!    streamed `--speed` times faster than real time through `POST /api/v1/samples`;
//! 4. stdout: every identification of `g1` (read from `GET /api/v1/gates/g1`) and every alert
//!    the webhook receives, as they happen; after `--duration` seconds or Ctrl-C, a summary.

use std::net::{Ipv4Addr, SocketAddr};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde_json::Value;
use tokio::net::TcpListener;
use tokio::sync::mpsc;

use super::client::{
    ensure_crypto_provider, simulate_with_source, Protocol, Scenario, SimulateArgs,
};
use super::clock::now_unix;
use super::config::Config;
use super::stdout::{errln, outln};
use crate::alert::notify::WebhookTarget;
use crate::simulate::{GateParams, GateSimulator};

/// Gate id of the simulated gate.
pub const DEMO_GATE: &str = "g1";
/// Capacity of the webhook receiver's queue (payloads); more are answered 503 (the notifier
/// retries them).
pub const WEBHOOK_QUEUE: usize = 256;

/// `gatewatch demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// Wall-clock seconds to run before the summary (Ctrl-C ends earlier).
    #[arg(long, default_value_t = 90.0, allow_negative_numbers = true)]
    pub duration: f64,
    /// Replay speed of the simulated gate (15: fifteen seconds of samples per second).
    #[arg(long, default_value_t = 15.0, allow_negative_numbers = true)]
    pub speed: f64,
    /// Seconds of sample time at +2 % damping before the ramp to -2 % (240: a steady record
    /// before the drift; the trend warning acts once its windows span
    /// `trend_min_span_seconds`, 300 s by default; the ramp reaches zero at 540 s).
    #[arg(long, default_value_t = 240.0, allow_negative_numbers = true)]
    pub onset_hold: f64,
    /// Seconds of sample time of the ramp from +2 % to -2 % (600: 0.4 points a minute, a drift
    /// the trend sees coming; on seeds 1 to 3 it warned at a true +0.49 to +0.69 % and the
    /// damping alert followed 8 to 11 s of wall time later).
    #[arg(long, default_value_t = 600.0, allow_negative_numbers = true)]
    pub onset_ramp: f64,
    /// Random seed of the simulated turbulence.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub seed: u64,
}

/// A small webhook receiver: queues every payload it is POSTed (bounded, 503 when full).
pub async fn webhook_receiver(
    capacity: usize,
) -> std::io::Result<(
    SocketAddr,
    mpsc::Receiver<Value>,
    tokio::task::JoinHandle<()>,
)> {
    let (tx, rx) = mpsc::channel::<Value>(capacity.max(1));
    async fn hook(State(tx): State<mpsc::Sender<Value>>, Json(v): Json<Value>) -> StatusCode {
        match tx.try_send(v) {
            Ok(()) => StatusCode::OK,
            Err(_) => StatusCode::SERVICE_UNAVAILABLE,
        }
    }
    let app = axum::Router::new()
        .route("/hook", axum::routing::post(hook))
        .with_state(tx);
    let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).await?;
    let addr = listener.local_addr()?;
    let task = tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, app).await {
            errln!("demo webhook receiver failed: {e}");
        }
    });
    Ok((addr, rx, task))
}

/// Binds the loopback address with the port of `listen`, or an ephemeral port when it is busy.
async fn bind_loopback(listen: &str) -> std::io::Result<TcpListener> {
    let port = listen.parse::<SocketAddr>().map(|a| a.port()).unwrap_or(0);
    match TcpListener::bind((Ipv4Addr::LOCALHOST, port)).await {
        Ok(l) => Ok(l),
        Err(e) => {
            errln!("port {port} is busy ({e}); using an ephemeral port");
            TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).await
        }
    }
}

fn pct(v: Option<f64>) -> String {
    v.map(|z| format!("{:+.2} %", 100.0 * z))
        .unwrap_or_else(|| "n/a".into())
}

/// One line per alert of a webhook payload (Alertmanager webhook format, version 4).
fn alert_lines(payload: &Value) -> Vec<String> {
    let empty = Vec::new();
    payload["alerts"]
        .as_array()
        .unwrap_or(&empty)
        .iter()
        .map(|a| {
            format!(
                "{} {} (gate {}): {}",
                a["status"].as_str().unwrap_or("?").to_uppercase(),
                a["labels"]["alertname"].as_str().unwrap_or("?"),
                a["labels"]["gate"].as_str().unwrap_or("?"),
                a["annotations"]["summary"].as_str().unwrap_or(""),
            )
        })
        .collect()
}

/// The flags' ranges, before anything starts (exit 2 naming the flag).
fn check(args: &DemoArgs) -> Result<(), String> {
    use crate::number::Num;
    use crate::service::client::SIMULATE_MAX_DURATION;
    use crate::service::config::MAX_SECONDS;
    // a year at most: the deadline is a `Duration`, which a huge float overflows
    if !(args.duration > 0.0 && args.duration <= MAX_SECONDS) {
        return Err(format!(
            "--duration must be > 0 and at most {} seconds (a year), got {}",
            Num(MAX_SECONDS),
            Num(args.duration)
        ));
    }
    // the simulated gate streams `--speed` times `--duration` seconds of samples, which
    // `simulate` bounds as its own `--duration`
    if !(args.speed > 0.0 && args.speed * args.duration <= SIMULATE_MAX_DURATION) {
        return Err(format!(
            "--speed must be > 0, and --speed times --duration at most {} seconds of samples \
             (366 days), got {} and {}",
            Num(SIMULATE_MAX_DURATION),
            Num(args.speed),
            Num(args.duration)
        ));
    }
    // as `simulate` refuses them (a negative hold ran, as a ramp begun before the stream)
    for (flag, v) in [
        ("--onset-hold", args.onset_hold),
        ("--onset-ramp", args.onset_ramp),
    ] {
        if !(0.0..=SIMULATE_MAX_DURATION).contains(&v) {
            return Err(format!(
                "{flag} must be >= 0 seconds and at most {}, got {}",
                Num(SIMULATE_MAX_DURATION),
                Num(v)
            ));
        }
    }
    Ok(())
}

/// `gatewatch demo`: exit 0 after `--duration` or Ctrl-C, 1 when something cannot start.
pub fn demo(args: DemoArgs) -> ExitCode {
    if let Err(e) = check(&args) {
        errln!("gatewatch demo: {e}");
        return ExitCode::from(2);
    }
    // Daemon logs (warnings only, unless RUST_LOG says otherwise) go to stderr; stdout is the
    // demo's narrative.
    // An invalid RUST_LOG is named, and `warn` used (src/service/rust_log.rs).
    let (filter, invalid) = match super::rust_log::read() {
        Ok(Some(f)) => (f, None),
        Ok(None) => (tracing_subscriber::EnvFilter::new("warn"), None),
        Err(bad) => (tracing_subscriber::EnvFilter::new("warn"), Some(bad)),
    };
    // colour codes only on a terminal, as `serve`'s logs (cli::init_tracing)
    use std::io::IsTerminal;
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
    if let Some(bad) = invalid {
        tracing::warn!(
            rust_log = %bad.value,
            error = %bad.reason,
            "RUST_LOG is invalid and ignored; using warn"
        );
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            errln!("gatewatch demo: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    // the signals are taken over inside the runtime (`shutdown::signal` needs its reactor)
    match rt.block_on(async { run_demo(args, super::shutdown::signal()).await }) {
        Ok(_) => ExitCode::SUCCESS,
        // `gatewatch demo | head -1`: the daemon is stopped as after Ctrl-C, then a quiet exit
        Err(e) => super::stdout::exit_code("gatewatch demo", &e),
    }
}

/// The demo's stdout: once a write fails (the reader went away), nothing more is written and
/// the demo ends as after Ctrl-C, stopping its daemon; the error is the demo's result.
#[derive(Debug, Default)]
struct Narrative {
    failed: Option<std::io::Error>,
}

impl Narrative {
    /// Writes one line, unless an earlier write failed.
    fn line(&mut self, line: std::fmt::Arguments<'_>) {
        if self.failed.is_none() {
            if let Err(e) = outln!("{line}") {
                self.failed = Some(e);
            }
        }
    }

    /// Whether stdout has failed (the demo should end).
    fn ended(&self) -> bool {
        self.failed.is_some()
    }
}

/// Counts of a finished demo.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DemoSummary {
    /// Identifications of the gate seen.
    pub identifications: u64,
    /// Alerts received by the webhook (firing and resolved).
    pub alerts: u64,
    /// `GateNegativeDamping` firing alerts received.
    pub negative_damping_fired: u64,
    /// `GateDampingDeclining` (the early warning) firing alerts received.
    pub declining_fired: u64,
    /// `gatewatch_damping_ratio` lines of the final metrics.
    pub damping_metric_lines: Vec<String>,
}

impl DemoSummary {
    /// Counts one line of [`alert_lines`].
    fn count(&mut self, line: &str) {
        self.alerts += 1;
        if line.starts_with("FIRING GateNegativeDamping ") {
            self.negative_damping_fired += 1;
        } else if line.starts_with("FIRING GateDampingDeclining ") {
            self.declining_fired += 1;
        }
    }
}

/// The demo, until `--duration` has passed or `interrupt` resolves; a failed write to stdout
/// ends it the same way (its daemon stopped) and is its error.
pub async fn run_demo(
    args: DemoArgs,
    interrupt: impl std::future::Future<Output = ()>,
) -> anyhow::Result<DemoSummary> {
    ensure_crypto_provider();
    let began = Instant::now();
    let mut config = Config::embedded();
    let http = bind_loopback(&config.server.listen).await?;
    let daemon_addr = http.local_addr()?;
    let (hook_addr, mut hooks, hook_task) = webhook_receiver(WEBHOOK_QUEUE).await?;
    config.server.listen = daemon_addr.to_string();
    config.notify.webhooks.push(WebhookTarget {
        url: format!("http://{hook_addr}/hook"),
        bearer_token: None,
        receiver: "gatewatch-demo".into(),
    });
    config.notify.external_url = format!("http://{daemon_addr}");
    config.notify.initial_backoff_ms = 100;
    // A fresh temporary store: the demo must not resume an earlier demo's alerts. It lives in
    // a directory of its own, removed with everything in it (the database, its `-wal`, `-shm`
    // and `.lock` files) when `store_dir` drops: at the end, on Ctrl-C, or on an error. Until
    // stop 67 the files were left in the temporary directory, four more with every run.
    let store_dir = tempfile::Builder::new()
        .prefix("gatewatch-demo-")
        .tempdir()
        .context("creating the demo's temporary store directory")?;
    config.storage.path = store_dir.path().join("demo.db").display().to_string();
    // The demo streams `--speed` times faster than real time: its sample times run ahead of the
    // daemon's clock by design, so the bounds on sample times (issue 12) do not apply to it.
    config.defaults.max_future_seconds = 0.0;
    config.defaults.max_past_seconds = 0.0;
    let rules = config.defaults.alert.clone();
    let base = format!("http://{daemon_addr}");

    let mut out = Narrative::default();
    out.line(format_args!(
        "gatewatch demo: daemon on {base} (embedded default configuration)"
    ));
    out.line(format_args!(
        "  metrics:  {base}/metrics      gate: {base}/api/v1/gates/{DEMO_GATE}"
    ));
    out.line(format_args!("  webhook receiver: http://{hook_addr}/hook"));
    out.line(format_args!(
        "  simulated gate `{DEMO_GATE}`: lab gate (10.4 Hz), damping +2 % for {} s, then a ramp to \
         -2 % over {} s (sample time), streamed at {}x through POST /api/v1/samples",
        args.onset_hold, args.onset_ramp, args.speed
    ));
    for line in rule_lines(&rules) {
        out.line(format_args!("  {line}"));
    }
    out.line(format_args!(
        "  running for {} s (Ctrl-C ends earlier)",
        args.duration
    ));
    out.line(format_args!(""));

    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let daemon = tokio::spawn(super::server::run(
        config,
        super::server::Listeners::http_only(http),
        async move {
            let _ = stop_rx.await;
        },
    ));

    // the simulated gate, through the real ingestion path
    let start = now_unix();
    let rate = 200.0;
    let sim_args = SimulateArgs {
        url: base.clone(),
        tcp_addr: String::new(),
        gate: DEMO_GATE.into(),
        scenario: Scenario::Onset,
        speed: args.speed,
        duration: Some(args.speed * args.duration + 60.0),
        seed: args.seed,
        protocol: Protocol::Json,
        rate,
        token: None,
        chunk_seconds: 0.1,
        start: Some(start),
        onset_hold: Some(args.onset_hold),
        onset_ramp: Some(args.onset_ramp),
        sensor: Default::default(),
    };
    let truth = GateSimulator::scenario(
        GateParams::default(),
        Scenario::Onset.to_simulation(args.onset_hold, args.onset_ramp),
        args.seed,
    );
    let streamer = tokio::spawn(async move {
        let mut sim = GateSimulator::scenario(
            GateParams {
                rate_hz: sim_args.rate,
                ..Default::default()
            },
            Scenario::Onset.to_simulation(args.onset_hold, args.onset_ramp),
            sim_args.seed,
        );
        simulate_with_source(&sim_args, |b: &mut [f64]| sim.fill(b)).await
    });

    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .build()?;
    let gate_url = format!("{base}/api/v1/gates/{DEMO_GATE}");
    let mut summary = DemoSummary::default();
    let mut last_seen: Option<f64> = None;
    let mut poll = tokio::time::interval(Duration::from_millis(200));
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let deadline = tokio::time::sleep(Duration::from_secs_f64(args.duration));
    tokio::pin!(deadline);
    tokio::pin!(interrupt);
    let mut streamer = Some(streamer);
    // until the duration, Ctrl-C, or stdout's reader going away
    while !out.ended() {
        tokio::select! {
            _ = &mut deadline => break,
            _ = &mut interrupt => {
                out.line(format_args!("\ninterrupted"));
                break;
            }
            Some(payload) = hooks.recv() => {
                for line in alert_lines(&payload) {
                    summary.count(&line);
                    out.line(format_args!("[{:6.1} s] webhook: {line}", began.elapsed().as_secs_f64()));
                }
            }
            r = async { streamer.as_mut().expect("checked by the guard").await }, if streamer.is_some() => {
                streamer = None;
                match r {
                    Ok(Ok(n)) => out.line(format_args!("[{:6.1} s] simulated stream ended after {n} samples", began.elapsed().as_secs_f64())),
                    Ok(Err(e)) => errln!("simulated stream failed: {e:#}"),
                    Err(e) => errln!("simulated stream task failed: {e}"),
                }
            }
            _ = poll.tick() => {
                let Ok(resp) = client.get(&gate_url).send().await else { continue };
                let Ok(v) = resp.json::<Value>().await else { continue };
                let ident = &v["identification"];
                let Some(t) = ident["time"].as_f64() else { continue };
                if last_seen == Some(t) {
                    continue;
                }
                last_seen = Some(t);
                summary.identifications += 1;
                let d = &ident["damping"];
                let end = ident["window_end"].as_f64().unwrap_or(start) - start;
                let state = if v["firing"].as_bool() == Some(true) {
                    "firing".to_string()
                } else {
                    v["alert_state"].as_str().unwrap_or("?").to_string()
                };
                out.line(format_args!(
                    "[{:6.1} s] identification of {DEMO_GATE} (window ending at t = {:6.1} s): \
                     zeta0 {}{} from {} (true {}), f {} Hz, fit NMAE {}, trusted {}, state {}",
                    began.elapsed().as_secs_f64(),
                    end,
                    pct(d["zeta0"].as_f64()),
                    // The 95 % interval says how much the number can be trusted (issue 8).
                    match (d["zeta0_interval"][0].as_f64(), d["zeta0_interval"][1].as_f64()) {
                        (Some(lo), Some(hi)) => format!(" [{}, {}]", pct(Some(lo)), pct(Some(hi))),
                        _ => String::new(),
                    },
                    d["zeta0_source"].as_str().unwrap_or("n/a"),
                    pct(Some(truth.true_zeta(end))),
                    d["frequency_hz"].as_f64().map(|f| format!("{f:.2}")).unwrap_or_else(|| "n/a".into()),
                    d["fit_nmae"].as_f64().map(|f| format!("{f:.3}")).unwrap_or_else(|| "n/a".into()),
                    d["trusted"].as_bool().unwrap_or(false),
                    state,
                ));
            }
        }
    }

    if let Some(s) = streamer.take() {
        s.abort();
    }
    let metrics = match client.get(format!("{base}/metrics")).send().await {
        Ok(r) => r.text().await.unwrap_or_default(),
        Err(_) => String::new(),
    };
    summary.damping_metric_lines = metrics
        .lines()
        .filter(|l| l.starts_with("gatewatch_damping_ratio"))
        .map(String::from)
        .collect();
    let _ = stop_tx.send(());
    match tokio::time::timeout(Duration::from_secs(15), daemon).await {
        Ok(Ok(Ok(()))) => {}
        Ok(Ok(Err(e))) => errln!("daemon: {e:#}"),
        Ok(Err(e)) => errln!("daemon task: {e}"),
        Err(_) => errln!("daemon did not stop within 15 s"),
    }
    // alerts flushed by the daemon's shutdown
    while let Ok(payload) = hooks.try_recv() {
        for line in alert_lines(&payload) {
            summary.count(&line);
            out.line(format_args!(
                "[{:6.1} s] webhook: {line}",
                began.elapsed().as_secs_f64()
            ));
        }
    }
    hook_task.abort();
    // the daemon has stopped (or was given up on): its store goes
    let store_path = store_dir.path().display().to_string();
    if let Err(e) = store_dir.close() {
        errln!("gatewatch demo: cannot remove its temporary store {store_path}: {e}");
    }

    out.line(format_args!(""));
    out.line(format_args!(
        "summary after {:.0} s: {} identifications, {} alerts received by the webhook (firing: \
         {} GateDampingDeclining, {} GateNegativeDamping)",
        began.elapsed().as_secs_f64(),
        summary.identifications,
        summary.alerts,
        summary.declining_fired,
        summary.negative_damping_fired
    ));
    if summary.damping_metric_lines.is_empty() {
        out.line(format_args!(
            "no gatewatch_damping_ratio yet (no successful identification)"
        ));
    }
    for l in &summary.damping_metric_lines {
        out.line(format_args!("  {l}"));
    }
    match out.failed {
        Some(e) => Err(anyhow::Error::new(e).context("writing to stdout")),
        None => Ok(summary),
    }
}

/// The alert rules as the demo states them: what `AlertEngine` decides on (the interval, the
/// streak, the at-once rule and the trend warning), not a simplification an operator would
/// then see contradicted by the first alert that fires on one window.
fn rule_lines(rules: &crate::alert::AlertRules) -> [String; 2] {
    let below = format!("{:.1} %", 100.0 * rules.fire_below);
    let evidence = match rules.fire_probability {
        Some(p) => format!("P(zeta0 < {below}) >= {p}"),
        None => format!("zeta0's whole 95 % interval lies below {below}"),
    };
    let bar = rules
        .fire_at_once_min_ratio
        .unwrap_or(crate::alert::at_once_ratio(None));
    let at_once = if rules.fire_at_once_probability < 1.0 {
        format!(
            ", or at once on one window {bar}x above the gate's ambient level with P(zeta0 < \
             {below}) >= {}",
            rules.fire_at_once_probability
        )
    } else {
        String::new()
    };
    let regimes = match (rules.fire_on_limit_cycle, rules.fire_on_growth) {
        (true, true) => "a limit-cycle or growing window",
        (true, false) => "a limit-cycle window",
        (false, true) => "a growing window",
        (false, false) => "",
    };
    let cycle = if regimes.is_empty() {
        String::new()
    } else {
        format!(
            " ({regimes} {bar}x above the gate's ambient level counts, whatever its interval \
             and trust)"
        )
    };
    [
        format!(
            "alert rule: GateNegativeDamping fires when {evidence} in {} consecutive trusted \
             windows{cycle}{at_once}",
            rules.for_windows.max(1)
        ),
        format!(
            "warning:    GateDampingDeclining fires when the trend of zeta0 predicts the crossing \
             of {below} within {:.0} min and within the span of its windows (95 % confidence), \
             once they span {:.0} s",
            rules.warn_lead_seconds / 60.0,
            rules.trend_min_span_seconds
        ),
    ]
}

#[cfg(test)]
mod rule_tests {
    use super::{alert_lines, check, rule_lines, DemoArgs, DemoSummary};
    use crate::alert::AlertRules;

    /// Every flag out of range is refused by name before anything starts; a duration of 1e300
    /// panicked converting to the deadline's `Duration`.
    #[test]
    fn the_demo_refuses_flags_out_of_range_naming_them() {
        let args = DemoArgs {
            duration: 90.0,
            speed: 15.0,
            onset_hold: 240.0,
            onset_ramp: 600.0,
            seed: 1,
        };
        assert_eq!(check(&args), Ok(()));
        let bad = |f: &dyn Fn(&mut DemoArgs)| {
            let mut a = args.clone();
            f(&mut a);
            check(&a).unwrap_err()
        };
        for d in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e300, 4e7] {
            assert!(bad(&|a| a.duration = d).starts_with("--duration"), "{d}");
        }
        for s in [0.0, -2.0, f64::NAN, 1e300] {
            assert!(bad(&|a| a.speed = s).starts_with("--speed"), "{s}");
        }
        // each within its own range, together past what `simulate` streams
        let both = bad(&|a| {
            a.duration = 3e7;
            a.speed = 10.0
        });
        assert!(both.contains("--speed times --duration"), "{both}");
        assert!(bad(&|a| a.onset_hold = -1.0).starts_with("--onset-hold"));
        assert!(bad(&|a| a.onset_ramp = 1e300).starts_with("--onset-ramp"));
    }

    #[test]
    fn the_demo_states_the_rules_the_engine_applies() {
        let [negative, declining] = rule_lines(&AlertRules::default());
        assert_eq!(
            negative,
            "alert rule: GateNegativeDamping fires when zeta0's whole 95 % interval lies below \
             0.0 % in 2 consecutive trusted windows (a limit-cycle or growing window 3.5x above \
             the gate's ambient level counts, whatever its interval and trust), or at once on one window 3.5x above \
             the gate's ambient level with P(zeta0 < 0.0 %) >= 0.975"
        );
        assert_eq!(
            declining,
            "warning:    GateDampingDeclining fires when the trend of zeta0 predicts the \
             crossing of 0.0 % within 10 min and within the span of its windows (95 % \
             confidence), once they span 300 s"
        );
        let other = AlertRules {
            fire_probability: Some(0.9),
            fire_at_once_probability: 1.0,
            fire_on_limit_cycle: false,
            fire_on_growth: false,
            for_windows: 3,
            ..AlertRules::default()
        };
        let [negative, _] = rule_lines(&other);
        assert_eq!(
            negative,
            "alert rule: GateNegativeDamping fires when P(zeta0 < 0.0 %) >= 0.9 in 3 \
             consecutive trusted windows"
        );
    }

    #[test]
    fn the_summary_counts_each_alert_that_fired() {
        let payload = serde_json::json!({"alerts": [
            {"status": "firing", "labels": {"alertname": "GateDampingDeclining", "gate": "g"},
             "annotations": {"summary": "declining"}},
            {"status": "firing", "labels": {"alertname": "GateNegativeDamping", "gate": "g"},
             "annotations": {"summary": "negative"}},
            {"status": "resolved", "labels": {"alertname": "GateDampingDeclining", "gate": "g"},
             "annotations": {"summary": "calm"}},
        ]});
        let mut summary = DemoSummary::default();
        for line in alert_lines(&payload) {
            summary.count(&line);
        }
        assert_eq!(
            (
                summary.alerts,
                summary.declining_fired,
                summary.negative_damping_fired
            ),
            (3, 1, 1)
        );
    }
}
