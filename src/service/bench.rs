//! `gatewatch bench daemon`: load measurements of the daemon on this machine.
//!
//! 1. Ingest throughput (samples/s) through `POST /api/v1/samples` (JSON), `POST /api/v2/write`
//!    (line protocol over HTTP) and the raw TCP listener, with a trivial analyzer (identification
//!    costs nothing), the daemon in-process on loopback, `--senders` concurrent clients.
//! 2. Identification cost per window (the real [`crate::analysis::Analyzer`], default gate
//!    settings, 10 s windows of the simulated lab gate at 200 Hz every 5 s): CPU seconds of the
//!    analysing thread, cold (full search) and tracked (`Analyzer::analyze_tracked` with the
//!    gate's memory, as the daemon runs it), with the path each window took.
//! 3. Gates sustained: N gates at 200 Hz, 10 s windows, identified every 5 s, streamed at real-time
//!    pace for `--seconds`; sustained when no job was replaced, none dropped and none failed.
//!    Every gate arrives with a full window at once (as at a first start), so the first round of
//!    full searches is a burst; the seconds until as many windows were identified as there are
//!    gates, and the jobs replaced until then, are reported apart, and "after the first round"
//!    says whether any job was replaced later (the steady state).
//!    N doubles until neither holds (or `--max-gates`), or runs through `--gates`; each
//!    count reports the tracked share, the process CPU per identified window and the RSS.
//!    With `--restart` each count runs with a store file and then again on a second daemon
//!    started on that file (the gates' analysis memory rebuilt from it, `service::resume`); a
//!    count holds only when both runs do.

use std::net::SocketAddr;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::AsyncWriteExt;

use super::config::Config;
use super::server::{run_with_persistence, Listeners};
use super::stdout::{errln, outln};
use super::worker::{AnalyzerMap, WindowAnalyzer};
use crate::analysis::{
    AnalysisError, Analyzer, DampingReport, Path, Previous, Verdict, WindowAnalysis, WindowInput,
};
use crate::simulate::{GateParams, GateSimulator, Scenario};

/// `gatewatch bench daemon`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchDaemonArgs {
    /// Samples sent per protocol in the ingest measurement.
    #[arg(long, allow_negative_numbers = true, default_value_t = 2_000_000)]
    pub samples: u64,
    /// Samples per request (per write on TCP).
    #[arg(long, allow_negative_numbers = true, default_value_t = 2000)]
    pub batch: usize,
    /// Concurrent senders (one gate each).
    #[arg(long, allow_negative_numbers = true, default_value_t = 4)]
    pub senders: usize,
    /// Windows identified cold and warm in the latency measurement.
    #[arg(long, allow_negative_numbers = true, default_value_t = 5)]
    pub windows: usize,
    /// Wall seconds of real-time streaming per gate count in the capacity measurement.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub seconds: f64,
    /// Largest gate count tried.
    #[arg(long, allow_negative_numbers = true, default_value_t = 64)]
    pub max_gates: usize,
    /// Gate counts of the capacity sweep, e.g. `8,32,128,200,512` (every one is run); without
    /// it, powers of two up to `--max-gates` until one is not sustained.
    #[arg(long, value_delimiter = ',')]
    pub gates: Vec<usize>,
    /// Identification worker threads (0: cores - 1).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    pub worker_threads: usize,
    /// Skip measurements: any of ingest, latency, capacity.
    #[arg(long, value_delimiter = ',')]
    pub skip: Vec<String>,
    /// Capacity with a store, then a restart: each gate count runs with a store file (in a
    /// temporary directory), then a second daemon starts on that file and the same gates stream
    /// on for `--seconds` (its first round finds each gate's analysis memory rebuilt from the
    /// store, `storage.resume_analysis`).
    #[arg(long)]
    pub restart: bool,
    /// Capacity with `stagger = false`: every gate's first window as soon as it is full (all
    /// gates at once), the behaviour before the stagger, for comparison.
    #[arg(long)]
    pub no_stagger: bool,
}

/// An analyzer that does nothing: isolates the ingestion path.
struct Trivial;

impl WindowAnalyzer for Trivial {
    fn analyze(
        &self,
        _gate: &str,
        _input: WindowInput<'_>,
        _warm: Option<&[f64]>,
        _seed: u64,
    ) -> Result<WindowAnalysis, AnalysisError> {
        Ok(WindowAnalysis {
            equation: String::new(),
            coefficients: Vec::new(),
            damping: DampingReport {
                zeta0: Some(0.01),
                agrees: Some(true),
                fit_nmae: 0.0,
                trusted: true,
                verdict: Verdict::Damped,
                ..DampingReport::unknown()
            },
            evaluations: 0,
            seconds: 0.0,
            warm_start: Vec::new(),
            path: Default::default(),
        })
    }
}

struct Running {
    http: SocketAddr,
    tcp: SocketAddr,
    stop: tokio::sync::oneshot::Sender<()>,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
}

async fn start(config_text: &str, analyzer: Arc<dyn WindowAnalyzer>) -> anyhow::Result<Running> {
    start_with(config_text, analyzer, false).await
}

/// [`start`], with the store of the configuration's `[storage]` when `store` is set.
async fn start_with(
    config_text: &str,
    analyzer: Arc<dyn WindowAnalyzer>,
    store: bool,
) -> anyhow::Result<Running> {
    let cfg = Config::from_toml(config_text)?;
    let persistence = if store {
        let (storage, lead) = (cfg.storage.clone(), cfg.sample_lead_bound());
        let path = std::path::PathBuf::from(&storage.path);
        Some(
            tokio::task::spawn_blocking(move || {
                super::storage::Persistence::open(&path, &storage, lead)
            })
            .await??,
        )
    } else {
        None
    };
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let tcp = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let (h, t) = (http.local_addr()?, tcp.local_addr()?);
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(run_with_persistence(
        cfg,
        Listeners {
            http,
            tcp: Some(tcp),
            health: None,
        },
        analyzer,
        persistence,
        async move {
            let _ = rx.await;
        },
    ));
    Ok(Running {
        http: h,
        tcp: t,
        stop,
        task,
    })
}

impl Running {
    async fn stop(self) {
        let _ = self.stop.send(());
        let _ = tokio::time::timeout(Duration::from_secs(30), self.task).await;
    }
}

/// Sum of the metric lines starting with `prefix`.
fn metric_sum(text: &str, prefix: &str) -> f64 {
    text.lines()
        .filter(|l| l.starts_with(prefix))
        .filter_map(|l| l.split_whitespace().last()?.parse::<f64>().ok())
        .fold(0.0, |a, b| a + b)
}

async fn metrics(client: &reqwest::Client, addr: SocketAddr) -> anyhow::Result<String> {
    Ok(client
        .get(format!("http://{addr}/metrics"))
        .send()
        .await?
        .text()
        .await?)
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Proto {
    Json,
    Line,
    Tcp,
}

fn line_body(gate: &str, t0: f64, rate: f64, values: &[f64]) -> String {
    let mut body = String::with_capacity(values.len() * 48);
    for (i, v) in values.iter().enumerate() {
        let ns = ((t0 + i as f64 / rate) * 1e9).round() as i64;
        body.push_str(&format!("gate,gate={gate} force={v} {ns}\n"));
    }
    body
}

/// Sends `total` samples split over `senders` gates; returns samples/s measured until the
/// daemon has accepted all of them.
async fn ingest_rate(args: &BenchDaemonArgs, proto: Proto) -> anyhow::Result<f64> {
    let rate = 200.0;
    let r = start(
        "[server]\nworker_threads = 1\nmax_concurrent_ingest = 64\n\
         [defaults]\nrate_hz = 200.0\n\
         # synthetic times run ahead of the clock at full speed: no time bounds\n\
         max_future_seconds = 0.0\nmax_past_seconds = 0.0\n",
        Arc::new(Trivial),
    )
    .await?;
    let client = reqwest::Client::new();
    let per = args.samples / args.senders.max(1) as u64;
    let began = Instant::now();
    let mut tasks = Vec::new();
    for s in 0..args.senders.max(1) {
        let (client, http, tcp, batch) = (client.clone(), r.http, r.tcp, args.batch.max(1));
        tasks.push(tokio::spawn(async move {
            let gate = format!("{proto:?}-{s}").to_lowercase();
            let mut stream = match proto {
                Proto::Tcp => Some(tokio::net::TcpStream::connect(tcp).await?),
                _ => None,
            };
            let mut sim =
                GateSimulator::scenario(GateParams::default(), Scenario::Stable, s as u64);
            let mut buf = vec![0.0; batch];
            let mut sent = 0u64;
            while sent < per {
                let n = batch.min((per - sent) as usize);
                sim.fill(&mut buf[..n]);
                let t0 = 1_700_000_000.0 + sent as f64 / rate;
                match proto {
                    Proto::Json => {
                        let body = serde_json::json!({
                            "gate": gate, "start": t0, "rate_hz": rate, "values": &buf[..n],
                        });
                        let resp = client
                            .post(format!("http://{http}/api/v1/samples"))
                            .header("content-type", "application/json")
                            .body(body.to_string())
                            .send()
                            .await?;
                        anyhow::ensure!(resp.status().is_success(), "{}", resp.status());
                    }
                    Proto::Line => {
                        let resp = client
                            .post(format!("http://{http}/api/v2/write?precision=ns"))
                            .body(line_body(&gate, t0, rate, &buf[..n]))
                            .send()
                            .await?;
                        anyhow::ensure!(resp.status().is_success(), "{}", resp.status());
                    }
                    Proto::Tcp => {
                        let s = stream.as_mut().expect("connected above");
                        s.write_all(line_body(&gate, t0, rate, &buf[..n]).as_bytes())
                            .await?;
                    }
                }
                sent += n as u64;
            }
            if let Some(mut s) = stream {
                s.shutdown().await?;
            }
            anyhow::Ok(())
        }));
    }
    for t in tasks {
        t.await??;
    }
    // wait until the daemon has applied everything (TCP is asynchronous)
    let expected = (per * args.senders.max(1) as u64) as f64;
    let waited = tokio::time::timeout(Duration::from_secs(120), async {
        loop {
            let m = metrics(&client, r.http).await.unwrap_or_default();
            if metric_sum(&m, "gatewatch_samples_ingested_total{") >= expected {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await;
    let secs = began.elapsed().as_secs_f64();
    r.stop().await;
    anyhow::ensure!(waited.is_ok(), "{proto:?}: not every sample was accepted");
    Ok(expected / secs)
}

/// CPU seconds of the calling thread (Linux `schedstat`, nanoseconds), `None` elsewhere. CPU
/// rather than wall time: the machine is shared with other builds.
fn thread_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

/// CPU seconds of this process (user + system, clock ticks of 10 ms), `None` off Linux.
fn process_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/self/stat").ok()?;
    // fields after the command (which may contain spaces) start after the last ')'
    let rest = text.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let (utime, stime): (f64, f64) = (f.get(11)?.parse().ok()?, f.get(12)?.parse().ok()?);
    Some((utime + stime) / 100.0)
}

/// `VmRSS` and `VmHWM` (peak) of this process, MiB, `None` off Linux.
fn rss_mib() -> Option<(f64, f64)> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| -> Option<f64> {
        let line = text.lines().find(|l| l.starts_with(name))?;
        let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb / 1024.0)
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

/// Seconds spent by `f` on this thread: CPU when known, else wall.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let (c0, t0) = (thread_cpu_seconds(), Instant::now());
    let out = f();
    let secs = match (c0, thread_cpu_seconds()) {
        (Some(a), Some(b)) => b - a,
        _ => t0.elapsed().as_secs_f64(),
    };
    (out, secs)
}

/// One row of the latency table.
struct LatencyRow {
    cold: f64,
    tracked: f64,
    path: Path,
}

/// Identification cost of `windows` consecutive windows (5 s apart): each analysed cold (full
/// search, no warm start) and as the daemon does (tracked when the rule allows).
fn latency(windows: usize) -> anyhow::Result<Vec<LatencyRow>> {
    let config = Config::embedded();
    let analyzer = Analyzer::new(config.defaults.analysis_settings())?
        .with_tracking(config.defaults.tracking.clone())?;
    let n = config.defaults.window_samples();
    let every = config.defaults.every_samples();
    let rate = config.defaults.rate_hz;
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 1);
    let mut values = vec![0.0; n];
    sim.fill(&mut values);
    let mut previous: Option<Previous> = None;
    let mut out = Vec::new();
    for w in 0..windows {
        let t0 = (w * every) as f64 / rate;
        let input = WindowInput {
            t0,
            rate_hz: rate,
            values: &values,
            history: &[],
        };
        let seed = (w * every + n) as u64;
        let (cold, cold_s) = timed(|| analyzer.analyze(input, None, seed));
        cold?;
        let (next, tracked_s) = timed(|| analyzer.analyze_tracked(input, previous.as_ref(), seed));
        let next = next?;
        let t_end = t0 + (n - 1) as f64 / rate;
        previous = Some(Previous::after(previous.as_ref(), &next, t0, t_end));
        out.push(LatencyRow {
            cold: cold_s,
            tracked: tracked_s,
            path: next.path,
        });
        // slide the window by the cadence
        values.drain(..every);
        let mut more = vec![0.0; every];
        sim.fill(&mut more);
        values.extend(more);
    }
    Ok(out)
}

fn median(mut v: Vec<f64>) -> f64 {
    crate::identify::median(&mut v).unwrap_or(f64::NAN)
}

/// What one gate count of the capacity measurement gave.
struct Capacity {
    identifications: f64,
    replaced: f64,
    /// Seconds of streaming until every gate had its first window identified (the first round
    /// of full searches), and the jobs replaced until then; `None` when that never happened.
    warm_up: Option<(f64, f64)>,
    dropped: f64,
    failures: f64,
    tracked: f64,
    /// Process CPU seconds (ingestion included) per identified window.
    cpu_per_window: Option<f64>,
    /// RSS and peak RSS at the end of the run, MiB.
    rss: Option<(f64, f64)>,
    workers: usize,
}

/// The simulated gates of a capacity run and the samples each has streamed, so that a
/// restarted daemon can be fed what comes next.
struct Streams {
    sims: Vec<GateSimulator>,
    sent: usize,
}

/// One gate count: streams `gates` gates at real-time pace. With `store`, the daemon keeps its
/// store in that file; with `resume`, the gates go on from where that run left them (a restart:
/// every gate's buffer is empty again, so each starts with a full window at once, identified
/// when its stagger offset has passed).
async fn capacity_run(
    gates: usize,
    seconds: f64,
    (worker_threads, stagger): (usize, bool),
    store: Option<&std::path::Path>,
    resume: Option<Streams>,
) -> anyhow::Result<(Capacity, Streams)> {
    let storage = match store {
        // the replayed sample times are of 2023: a retention that keeps them
        Some(p) => format!(
            "[storage]\npath = {:?}\nretention_days = 36500.0\n",
            p.display().to_string()
        ),
        None => String::new(),
    };
    let text = format!(
        "[server]\nworker_threads = {worker_threads}\nmax_gates = {}\n\
         [defaults]\n# replayed synthetic times: no time bounds\nmax_past_seconds = 0.0\n\
         max_future_seconds = 0.0\nstagger = {stagger}\n{storage}",
        gates.max(1)
    );
    let config = Config::from_toml(&text)?;
    let workers = config.server.effective_worker_threads();
    let analyzer: Arc<dyn WindowAnalyzer> = Arc::new(AnalyzerMap::from_config(&config)?);
    let r = start_with(&text, analyzer, store.is_some()).await?;
    let client = reqwest::Client::new();
    let rate = 200.0;
    let cpu0 = process_cpu_seconds();
    // 0.1 s per request up to 32 gates; 1 s beyond, so that the sender (one request at a time)
    // keeps real-time pace with hundreds of gates (the cadence is 5 s either way).
    let chunk = if gates <= 32 { 20usize } else { 200 };
    let start_t = 1_700_000_000.0;
    let backfill = 2000usize; // one full window at once, so identification starts at once
    let (mut sims, base) = match resume {
        Some(s) => (s.sims, s.sent),
        None => (
            (0..gates)
                .map(|g| GateSimulator::scenario(GateParams::default(), Scenario::Stable, g as u64))
                .collect(),
            0,
        ),
    };
    // sample time of the run's first sample
    let start_t = start_t + base as f64 / rate;
    let post = |gate: usize, t0: f64, values: Vec<f64>| {
        let client = client.clone();
        let url = format!("http://{}/api/v1/samples", r.http);
        async move {
            let body = serde_json::json!({
                "gate": format!("g{gate}"), "start": t0, "rate_hz": rate, "values": values,
            });
            let resp = client.post(url).body(body.to_string()).send().await?;
            anyhow::ensure!(resp.status().is_success(), "{}", resp.status());
            anyhow::Ok(())
        }
    };
    for (g, sim) in sims.iter_mut().enumerate() {
        let mut v = vec![0.0; backfill];
        sim.fill(&mut v);
        post(g, start_t, v).await?;
    }
    let began = tokio::time::Instant::now();
    let mut sent = backfill;
    let total = backfill + (seconds * rate) as usize;
    // The first round: every gate arrives with a full window at once and needs a full search
    // once its stagger offset (0 to 5 s of stream) has passed
    // (after a restart with the store's memory, a refinement); what a worker sustains
    // afterwards is the steady state, so the replaced jobs are counted apart before and after.
    let mut warm_up = None;
    let mut next_check = backfill;
    while sent < total {
        if warm_up.is_none() && sent >= next_check {
            next_check = sent + rate as usize; // once a second of stream
            let m = metrics(&client, r.http).await.unwrap_or_default();
            let done = metric_sum(&m, "gatewatch_identification_duration_seconds_count");
            if done >= gates as f64 {
                let replaced = metric_sum(&m, "gatewatch_identification_jobs_replaced_total");
                warm_up = Some((began.elapsed().as_secs_f64(), replaced));
            }
        }
        for (g, sim) in sims.iter_mut().enumerate() {
            let mut v = vec![0.0; chunk];
            sim.fill(&mut v);
            post(g, start_t + sent as f64 / rate, v).await?;
        }
        sent += chunk;
        let due = Duration::from_secs_f64((sent - backfill) as f64 / rate);
        tokio::time::sleep_until(began + due).await;
    }
    // let the last jobs finish (bounded)
    let _ = tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            let m = metrics(&client, r.http).await.unwrap_or_default();
            let done = metric_sum(&m, "gatewatch_identification_duration_seconds_count");
            // each gate's windows: the first a full window and its stagger offset after the
            // start, then one every 1000 samples
            let expected: usize = (0..gates)
                .map(|g| {
                    let first = backfill + config.defaults.stagger_samples(&format!("g{g}"));
                    if total >= first {
                        1 + (total - first) / 1000
                    } else {
                        0
                    }
                })
                .sum();
            let expected = expected as f64;
            if done >= expected {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await;
    let m = metrics(&client, r.http).await?;
    let cpu = process_cpu_seconds();
    let rss = rss_mib();
    r.stop().await;
    let streams = Streams {
        sims,
        sent: base + sent,
    };
    let identifications = metric_sum(&m, "gatewatch_identification_duration_seconds_count");
    let tracked: f64 = m
        .lines()
        .filter(|l| {
            l.starts_with("gatewatch_identifications_total{") && l.contains("path=\"tracked\"")
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        // not `sum()`: it starts at -0.0 and printed "-0" for no tracked window
        .fold(0.0, |a, b| a + b);
    let capacity = Capacity {
        identifications,
        replaced: metric_sum(&m, "gatewatch_identification_jobs_replaced_total"),
        warm_up,
        dropped: metric_sum(
            &m,
            "gatewatch_identification_failures_total{reason=\"queue_full\"}",
        ),
        failures: metric_sum(&m, "gatewatch_identification_failures_total{"),
        tracked,
        cpu_per_window: match (cpu0, cpu) {
            (Some(a), Some(b)) if identifications > 0.0 => Some((b - a) / identifications),
            _ => None,
        },
        rss,
        workers,
    };
    Ok((capacity, streams))
}

/// The arguments' ranges, before any daemon starts: a bad one is the user's input (exit 2).
fn check(args: &BenchDaemonArgs) -> Result<(), String> {
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        return Err(format!(
            "--seconds must be > 0, got {}",
            crate::number::Num(args.seconds)
        ));
    }
    for (flag, v) in [
        ("--samples", args.samples as usize),
        ("--batch", args.batch),
        ("--senders", args.senders),
        ("--windows", args.windows),
        ("--max-gates", args.max_gates),
    ] {
        if v == 0 {
            return Err(format!("{flag} must be >= 1"));
        }
    }
    if args.gates.contains(&0) {
        return Err("--gates: every gate count must be >= 1".into());
    }
    if let Some(s) = args
        .skip
        .iter()
        .find(|s| !["ingest", "latency", "capacity"].contains(&s.as_str()))
    {
        return Err(format!(
            "--skip {s}: unknown measurement (ingest, latency, capacity)"
        ));
    }
    Ok(())
}

async fn bench(args: BenchDaemonArgs) -> anyhow::Result<()> {
    super::client::ensure_crypto_provider();
    let skip = |what: &str| args.skip.iter().any(|s| s == what);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    outln!("gatewatch bench daemon ({cores} cores)")?;
    if !skip("ingest") {
        outln!(
            "\n1. ingest throughput, trivial analyzer, {} senders, {} samples per request",
            args.senders,
            args.batch
        )?;
        outln!("| protocol | samples | samples/s |")?;
        outln!("|---|---:|---:|")?;
        for (name, p) in [
            ("JSON, POST /api/v1/samples", Proto::Json),
            ("line protocol, POST /api/v2/write", Proto::Line),
            ("line protocol, raw TCP", Proto::Tcp),
        ] {
            let r = ingest_rate(&args, p).await?;
            outln!("| {name} | {} | {:.0} |", args.samples, r)?;
        }
    }
    if !skip("latency") {
        outln!(
            "\n2. identification CPU per window (default gate settings, 10 s at 200 Hz every 5 s)"
        )?;
        let windows = args.windows;
        let r = tokio::task::spawn_blocking(move || {
            catch_unwind(AssertUnwindSafe(|| latency(windows)))
        })
        .await?;
        match r {
            Ok(Ok(rows)) => {
                outln!("| window | cold (full search), s | as the daemon runs it, s | path |")?;
                outln!("|---:|---:|---:|---|")?;
                for (i, r) in rows.iter().enumerate() {
                    outln!(
                        "| {i} | {:.4} | {:.4} | {} |",
                        r.cold,
                        r.tracked,
                        r.path.as_str()
                    )?;
                }
                let cold = median(rows.iter().map(|r| r.cold).collect());
                let tracked: Vec<f64> = rows
                    .iter()
                    .filter(|r| r.path == Path::Tracked)
                    .map(|r| r.tracked)
                    .collect();
                outln!(
                    "median cold {cold:.4} s; median tracked {:.4} s ({} of {} windows tracked)",
                    median(tracked.clone()),
                    tracked.len(),
                    rows.len()
                )?;
            }
            Ok(Err(e)) => outln!("analysis failed: {e}")?,
            Err(_) => outln!("the analyzer panicked (not implemented in this build?)")?,
        }
    }
    if !skip("capacity") {
        outln!(
            "\n3. gates sustained: 200 Hz, 10 s windows every 5 s, real-time pace for {} s",
            args.seconds
        )?;
        outln!(
            "| gates | workers | gates/worker | jobs finished | tracked | replaced | first round s \
             (replaced in it) | queue full | failures | process CPU s/window | RSS MiB (peak) \
             | sustained | after the first round |"
        )?;
        outln!("|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|---|")?;
        let sweep = !args.gates.is_empty();
        let counts: Vec<usize> = if sweep {
            args.gates.clone()
        } else {
            std::iter::successors(Some(1usize), |g| g.checked_mul(2))
                .take_while(|g| *g <= args.max_gates)
                .collect()
        };
        let mut best = 0usize;
        let mut best_steady = 0usize;
        let mut best_restarted = 0usize;
        let settings = (args.worker_threads, !args.no_stagger);
        for gates in counts {
            // a directory of this process for the store file (removed after the count)
            let dir = std::env::temp_dir()
                .join(format!("gatewatch-bench-{}-{gates}", std::process::id()));
            if args.restart {
                std::fs::create_dir_all(&dir)?;
            }
            let db = dir.join("gatewatch.db");
            let store = args.restart.then_some(db.as_path());
            let (c, streams) = capacity_run(gates, args.seconds, settings, store, None).await?;
            let mut runs = vec![(gates.to_string(), c)];
            if args.restart {
                let (again, _) =
                    capacity_run(gates, args.seconds, settings, store, Some(streams)).await?;
                runs.push((format!("{gates}, restarted"), again));
                let _ = std::fs::remove_dir_all(&dir);
            }
            let (mut ok, mut steady) = (true, true);
            for (k, (label, c)) in runs.iter().enumerate() {
                let (o, s) = capacity_row(label, gates, c)?;
                ok &= o;
                steady &= s;
                // The restarted daemon's row on its own: its first round is tracked.
                if k == 1 && o {
                    best_restarted = best_restarted.max(gates);
                }
            }
            if steady {
                best_steady = best_steady.max(gates);
            }
            if ok {
                best = best.max(gates);
            } else if !sweep && !steady {
                break;
            }
        }
        outln!(
            "\nsustained: {best} gates (largest count tried with no job replaced); \
             after the first round: {best_steady} gates"
        )?;
        if args.restart {
            outln!(
                "restarted from the store: {best_restarted} gates (largest count whose restarted \
                 daemon replaced no job)"
            )?;
        }
    }
    Ok(())
}

/// Prints one row of the capacity table; returns (sustained, sustained after the first round).
fn capacity_row(label: &str, gates: usize, c: &Capacity) -> std::io::Result<(bool, bool)> {
    {
        {
            let clean = c.dropped == 0.0 && c.failures == 0.0 && c.identifications > 0.0;
            let ok = clean && c.replaced == 0.0;
            // Steady: no job replaced once every gate had its first window (the first round
            // must end within the run for this to say anything).
            let steady = clean && c.warm_up.is_some_and(|(_, before)| c.replaced == before);
            outln!(
                "| {label} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                c.workers,
                gates as f64 / c.workers.max(1) as f64,
                c.identifications,
                c.tracked,
                c.replaced,
                c.warm_up
                    .map_or("never".into(), |(s, n)| format!("{s:.0} ({n})")),
                c.dropped,
                c.failures,
                c.cpu_per_window.map_or("-".into(), |v| format!("{v:.4}")),
                c.rss
                    .map_or("-".into(), |(r, p)| format!("{r:.0} ({p:.0})")),
                if ok { "yes" } else { "no" },
                if steady { "sustained" } else { "no" }
            )?;
            Ok((ok, steady))
        }
    }
}

/// `gatewatch bench daemon`.
pub fn bench_daemon(args: BenchDaemonArgs) -> ExitCode {
    if let Err(e) = check(&args) {
        errln!("gatewatch bench daemon: {e}");
        return ExitCode::from(2);
    }
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            errln!("gatewatch bench daemon: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(bench(args)) {
        Ok(()) => ExitCode::SUCCESS,
        // a closed stdout (`| head`) ends the run quietly
        Err(e) => super::stdout::exit_code("gatewatch bench daemon", &e),
    }
}
