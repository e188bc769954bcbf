//! `gatewatch bench daemon`: load measurements of the daemon on this machine.
//!
//! 1. Ingest throughput (samples/s) through `POST /api/v1/samples` (JSON), `POST /api/v2/write`
//!    (line protocol over HTTP) and the raw TCP listener, with a trivial analyzer (identification
//!    costs nothing), the daemon in-process on loopback, `--senders` concurrent clients.
//! 2. Identification latency per window (the real [`crate::analysis::Analyzer`], default gate
//!    settings, 10 s windows of the simulated lab gate at 200 Hz), cold and warm-started.
//! 3. Gates sustained: N gates at 200 Hz, 10 s windows, identified every 5 s, streamed at real-time
//!    pace for `--seconds`; sustained when no job was replaced, none dropped and none failed.
//!    N doubles until it is not sustained (or `--max-gates`).

use std::net::SocketAddr;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::io::AsyncWriteExt;

use super::config::Config;
use super::server::{run_with_analyzer, Listeners};
use super::worker::{AnalyzerMap, WindowAnalyzer};
use crate::analysis::{
    AnalysisError, Analyzer, DampingReport, Verdict, WindowAnalysis, WindowInput,
};
use crate::simulate::{GateParams, GateSimulator, Scenario};

/// `gatewatch bench daemon`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchDaemonArgs {
    /// Samples sent per protocol in the ingest measurement.
    #[arg(long, default_value_t = 2_000_000)]
    pub samples: u64,
    /// Samples per request (per write on TCP).
    #[arg(long, default_value_t = 2000)]
    pub batch: usize,
    /// Concurrent senders (one gate each).
    #[arg(long, default_value_t = 4)]
    pub senders: usize,
    /// Windows identified cold and warm in the latency measurement.
    #[arg(long, default_value_t = 5)]
    pub windows: usize,
    /// Wall seconds of real-time streaming per gate count in the capacity measurement.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Largest gate count tried.
    #[arg(long, default_value_t = 64)]
    pub max_gates: usize,
    /// Identification worker threads (0: cores - 1).
    #[arg(long, default_value_t = 0)]
    pub worker_threads: usize,
    /// Skip measurements: any of ingest, latency, capacity.
    #[arg(long, value_delimiter = ',')]
    pub skip: Vec<String>,
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
                agrees: true,
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
    let cfg = Config::from_toml(config_text)?;
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let tcp = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let (h, t) = (http.local_addr()?, tcp.local_addr()?);
    let (stop, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(run_with_analyzer(
        cfg,
        Listeners {
            http,
            tcp: Some(tcp),
        },
        analyzer,
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
         [defaults]\nrate_hz = 200.0\n",
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

/// Identification latency of `windows` windows: (cold seconds, warm seconds) per window.
fn latency(windows: usize) -> anyhow::Result<Vec<(f64, f64)>> {
    let config = Config::embedded();
    let analyzer = Analyzer::new(config.defaults.analysis_settings())?;
    let n = config.defaults.window_samples();
    let every = config.defaults.every_samples();
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 1);
    let mut values = vec![0.0; n];
    sim.fill(&mut values);
    let mut warm: Option<Vec<f64>> = None;
    let mut out = Vec::new();
    for w in 0..windows {
        let input = WindowInput {
            t0: 0.0,
            rate_hz: config.defaults.rate_hz,
            values: &values,
        };
        let t = Instant::now();
        let cold = analyzer.analyze(input, None, w as u64)?;
        let cold_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let seed = warm.clone().unwrap_or_else(|| cold.warm_start.clone());
        let next = analyzer.analyze(input, Some(&seed), w as u64)?;
        let warm_s = t.elapsed().as_secs_f64();
        warm = Some(next.warm_start);
        out.push((cold_s, warm_s));
        // slide the window by the cadence
        values.drain(..every);
        let mut more = vec![0.0; every];
        sim.fill(&mut more);
        values.extend(more);
    }
    Ok(out)
}

/// One gate count: streams `gates` gates at real-time pace; returns
/// (identifications, replaced, dropped, failures).
async fn capacity_run(
    gates: usize,
    seconds: f64,
    worker_threads: usize,
) -> anyhow::Result<(f64, f64, f64, f64)> {
    let text = format!(
        "[server]\nworker_threads = {worker_threads}\nmax_gates = {}\n",
        gates.max(1)
    );
    let analyzer: Arc<dyn WindowAnalyzer> =
        Arc::new(AnalyzerMap::from_config(&Config::from_toml(&text)?)?);
    let r = start(&text, analyzer).await?;
    let client = reqwest::Client::new();
    let rate = 200.0;
    let chunk = 20usize; // 0.1 s
    let start_t = 1_700_000_000.0;
    let backfill = 2000usize; // one full window at once, so identification starts at once
    let mut sims: Vec<GateSimulator> = (0..gates)
        .map(|g| GateSimulator::scenario(GateParams::default(), Scenario::Stable, g as u64))
        .collect();
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
    while sent < total {
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
            let expected = gates as f64 * (1.0 + ((total - backfill) / 1000) as f64);
            if done >= expected {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    })
    .await;
    let m = metrics(&client, r.http).await?;
    r.stop().await;
    Ok((
        metric_sum(&m, "gatewatch_identification_duration_seconds_count"),
        metric_sum(&m, "gatewatch_identification_jobs_replaced_total"),
        metric_sum(
            &m,
            "gatewatch_identification_failures_total{reason=\"queue_full\"}",
        ),
        metric_sum(&m, "gatewatch_identification_failures_total{"),
    ))
}

async fn bench(args: BenchDaemonArgs) -> anyhow::Result<()> {
    super::client::ensure_crypto_provider();
    let skip = |what: &str| args.skip.iter().any(|s| s == what);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("gatewatch bench daemon ({cores} cores)");
    if !skip("ingest") {
        println!(
            "\n1. ingest throughput, trivial analyzer, {} senders, {} samples per request",
            args.senders, args.batch
        );
        println!("| protocol | samples | samples/s |");
        println!("|---|---:|---:|");
        for (name, p) in [
            ("JSON, POST /api/v1/samples", Proto::Json),
            ("line protocol, POST /api/v2/write", Proto::Line),
            ("line protocol, raw TCP", Proto::Tcp),
        ] {
            let r = ingest_rate(&args, p).await?;
            println!("| {name} | {} | {:.0} |", args.samples, r);
        }
    }
    if !skip("latency") {
        println!("\n2. identification latency per window (default gate settings, 10 s at 200 Hz)");
        let windows = args.windows;
        let r = tokio::task::spawn_blocking(move || {
            catch_unwind(AssertUnwindSafe(|| latency(windows)))
        })
        .await?;
        match r {
            Ok(Ok(rows)) => {
                println!("| window | cold, s | warm-started, s |");
                println!("|---:|---:|---:|");
                for (i, (c, w)) in rows.iter().enumerate() {
                    println!("| {i} | {c:.3} | {w:.3} |");
                }
                let mean = |f: fn(&(f64, f64)) -> f64| {
                    rows.iter().map(f).sum::<f64>() / rows.len().max(1) as f64
                };
                println!("| mean | {:.3} | {:.3} |", mean(|r| r.0), mean(|r| r.1));
            }
            Ok(Err(e)) => println!("analysis failed: {e}"),
            Err(_) => println!("the analyzer panicked (not implemented in this build?)"),
        }
    }
    if !skip("capacity") {
        println!(
            "\n3. gates sustained: 200 Hz, 10 s windows every 5 s, real-time pace for {} s",
            args.seconds
        );
        println!("| gates | jobs finished | replaced | queue full | failures | sustained |");
        println!("|---:|---:|---:|---:|---:|---|");
        let mut gates = 1usize;
        let mut best = 0usize;
        while gates <= args.max_gates {
            let (ids, replaced, dropped, failures) =
                capacity_run(gates, args.seconds, args.worker_threads).await?;
            let ok = replaced == 0.0 && dropped == 0.0 && failures == 0.0 && ids > 0.0;
            println!(
                "| {gates} | {ids} | {replaced} | {dropped} | {failures} | {} |",
                if ok { "yes" } else { "no" }
            );
            if !ok {
                break;
            }
            best = gates;
            gates *= 2;
        }
        println!("\nsustained: {best} gates (largest power of two tried with no job replaced)");
    }
    Ok(())
}

/// `gatewatch bench daemon`.
pub fn bench_daemon(args: BenchDaemonArgs) -> ExitCode {
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("gatewatch bench daemon: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(bench(args)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("gatewatch bench daemon: {e:#}");
            ExitCode::FAILURE
        }
    }
}
