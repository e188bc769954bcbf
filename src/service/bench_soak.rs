//! `gatewatch bench soak`: the daemon under a long mixed load, watched for leaks.
//!
//! The daemon runs as a child process (`gatewatch serve` on a generated configuration, loopback
//! ports), so its resident memory and file descriptors are its own and are read from
//! `/proc/PID`. Against it, for `--minutes`:
//!
//! - steady gates stream the simulated lab gate at `--rate` Hz in half-second requests, half as
//!   JSON (`/api/v1/samples`) and half as line protocol (`/api/v2/write`); each request's latency
//!   is recorded;
//! - `--tcp-gates` stream line protocol over the raw TCP listener, reconnecting when cut;
//! - transient gates appear (a client streams under a name for 20 s, then stops) from a bounded
//!   set of `--churn-gates` names, so gates come, go stale and come back;
//! - `--slow-clients` slowloris connections send a request's headers a byte every 2 s;
//! - `--broken-per-second` broken requests: a body cut short, bad gzip, invalid JSON, a bare
//!   connect-and-close, a garbage TCP line.
//!
//! Every `--interval` seconds it records RSS, peak RSS, open descriptors, the ingest latency
//! quantiles of the steady gates, their non-2xx answers, and the identification jobs replaced
//! (from `/metrics`). The summary judges the targets of issue 12: RSS flat after `--warmup` and
//! under `--rss-bound-mib`, no descriptor growth, p99 ingest latency under 50 ms, no panic.
//! Nothing here is asserted in a test with a time limit: `tests/soak.rs` runs a short soak and
//! checks the bookkeeping and survival only.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::stdout::{errln, outln};

mod load;

use load::{broken_request, http_gate, simulator, slow_client, tcp_gate, HttpGate};

/// The p99 ingest latency target of issue 12, ms.
const P99_TARGET_MS: f64 = 50.0;
/// Seconds a transient gate streams before it stops.
const CHURN_STREAM_SECONDS: f64 = 20.0;
/// Seconds between two transient gates starting.
const CHURN_EVERY_SECONDS: f64 = 2.0;
/// Seconds between two bytes of a slowloris client's headers.
const SLOW_BYTE_SECONDS: f64 = 2.0;
/// Seconds a slowloris client keeps trying before it starts over.
const SLOW_LIFETIME_SECONDS: f64 = 60.0;
/// Seconds of samples per steady request.
const CHUNK_SECONDS: f64 = 0.5;

/// `gatewatch bench soak`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchSoakArgs {
    /// Minutes of load.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub minutes: f64,
    /// Steady gates over HTTP (half JSON, half line protocol).
    #[arg(long, allow_negative_numbers = true, default_value_t = 8)]
    pub gates: usize,
    /// Steady gates over the raw TCP listener.
    #[arg(long, allow_negative_numbers = true, default_value_t = 2)]
    pub tcp_gates: usize,
    /// Names the transient gates cycle through (bounds the gates the daemon sees).
    #[arg(long, allow_negative_numbers = true, default_value_t = 16)]
    pub churn_gates: usize,
    /// Slowloris connections held open at once.
    #[arg(long, allow_negative_numbers = true, default_value_t = 32)]
    pub slow_clients: usize,
    /// Broken requests per second.
    #[arg(long, default_value_t = 2.0, allow_negative_numbers = true)]
    pub broken_per_second: f64,
    /// Sample rate of every gate, Hz.
    #[arg(long, default_value_t = 200.0, allow_negative_numbers = true)]
    pub rate: f64,
    /// Seconds between two records.
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    pub interval: f64,
    /// Seconds of warm-up excluded from the flatness judgement.
    #[arg(long, default_value_t = 120.0, allow_negative_numbers = true)]
    pub warmup: f64,
    /// Identification worker threads of the daemon.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub worker_threads: usize,
    /// The resident-memory bound judged against, MiB (the shipped Kubernetes limit).
    #[arg(long, default_value_t = 512.0, allow_negative_numbers = true)]
    pub rss_bound_mib: f64,
    /// Extra TOML appended to the daemon's generated configuration (e.g. new limits).
    #[arg(long)]
    pub extra_config: Option<PathBuf>,
    /// Print the records and the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// One record of the soak.
#[derive(Debug, Clone, Serialize)]
pub struct Tick {
    /// Seconds since the load started.
    pub t: f64,
    /// Resident memory of the daemon, MiB.
    pub rss_mib: f64,
    /// Peak resident memory so far, MiB.
    pub hwm_mib: f64,
    /// Open file descriptors of the daemon.
    pub fds: usize,
    /// Steady ingest requests answered in the interval.
    pub requests: usize,
    /// Median ingest latency in the interval, ms.
    pub p50_ms: f64,
    /// 99th percentile ingest latency in the interval, ms.
    pub p99_ms: f64,
    /// Steady requests answered other than 2xx in the interval (503 included).
    pub non_2xx: u64,
    /// Steady requests that failed at the transport level in the interval.
    pub transport_errors: u64,
    /// Identification jobs replaced so far (`gatewatch_identification_jobs_replaced_total`).
    pub jobs_replaced: f64,
}

/// The verdict of a soak.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Minutes of load.
    pub minutes: f64,
    /// RSS at the first record after the warm-up, MiB.
    pub rss_after_warmup_mib: f64,
    /// RSS at the last record, MiB.
    pub rss_last_mib: f64,
    /// Least-squares slope of RSS after the warm-up, MiB per hour.
    pub rss_slope_mib_per_hour: f64,
    /// Peak RSS over the run, MiB.
    pub rss_peak_mib: f64,
    /// Descriptors at the first record after the warm-up and at the last.
    pub fds_after_warmup: usize,
    /// Descriptors at the last record.
    pub fds_last: usize,
    /// 99th percentile of every steady ingest request after the warm-up, ms.
    pub p99_ms: f64,
    /// Worst interval p99 after the warm-up, ms.
    pub worst_interval_p99_ms: f64,
    /// Steady ingest requests answered in all.
    pub requests: usize,
    /// Non-2xx answers to steady requests in all.
    pub non_2xx: u64,
    /// The same, by status code.
    pub non_2xx_by_status: std::collections::BTreeMap<u16, u64>,
    /// Identification jobs replaced in all.
    pub jobs_replaced: f64,
    /// Lines of the daemon's stderr containing "panicked".
    pub panics: usize,
    /// Whether the daemon was still running at the end.
    pub survived: bool,
    /// The daemon's exit after SIGTERM (`None`: killed after the grace).
    pub exit_code: Option<i32>,
    /// Per target: its name and whether it held.
    pub targets: Vec<(String, bool)>,
}

/// Counters shared by the load tasks.
#[derive(Default)]
struct Shared {
    latencies_ms: Mutex<Vec<f64>>,
    non_2xx: AtomicU64,
    /// Every non-2xx answer to a steady request after the warm-up, by status code (the 30-minute
    /// soak saw 77 without saying which).
    statuses: Mutex<std::collections::BTreeMap<u16, u64>>,
    transport_errors: AtomicU64,
    stop: AtomicBool,
}

/// The running daemon under test.
struct Daemon {
    child: Child,
    http: String,
    tcp: String,
    stderr_path: PathBuf,
    dir: PathBuf,
}

impl Drop for Daemon {
    /// The daemon dies with the bench, whatever ended it (an error, a panic): an orphan kept
    /// its ports and its log in a directory that no longer existed.
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn free_port() -> std::io::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

fn start_daemon(args: &BenchSoakArgs) -> anyhow::Result<Daemon> {
    use anyhow::Context;
    // A directory of its own for the configuration and the daemon's log (removed on drop).
    let dir = std::env::temp_dir().join(format!("gatewatch-soak-{}", std::process::id()));
    std::fs::create_dir_all(&dir)
        .with_context(|| format!("creating the soak's directory {}", dir.display()))?;
    let (http_port, tcp_port) = (free_port()?, free_port()?);
    let max_gates = args.gates + args.tcp_gates + args.churn_gates + 8;
    let mut config = format!(
        "[server]\nlisten = \"127.0.0.1:{http_port}\"\ntcp_listen = \"127.0.0.1:{tcp_port}\"\n\
         worker_threads = {}\nmax_gates = {max_gates}\n\n[log]\nlevel = \"warn\"\n",
        args.worker_threads
    );
    if let Some(extra) = &args.extra_config {
        let text = std::fs::read_to_string(extra)
            .with_context(|| format!("reading --extra-config {}", extra.display()))?;
        config.push('\n');
        config.push_str(&text);
    }
    let config_path = dir.join("gatewatch.toml");
    std::fs::write(&config_path, config).context("writing the soak's configuration")?;
    let stderr_path = dir.join("daemon.stderr");
    let stderr = std::fs::File::create(&stderr_path).context("creating the daemon's log")?;
    let exe = std::env::current_exe().context("locating the gatewatch binary")?;
    let child = Command::new(exe)
        .arg("serve")
        .arg("--config")
        .arg(&config_path)
        .current_dir(&dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .context("starting `gatewatch serve`")?;
    Ok(Daemon {
        child,
        http: format!("http://127.0.0.1:{http_port}"),
        tcp: format!("127.0.0.1:{tcp_port}"),
        stderr_path,
        dir,
    })
}

/// `VmRSS` and `VmHWM` of `pid` in MiB.
fn memory_mib(pid: u32) -> Option<(f64, f64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| -> Option<f64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib / 1024.0)
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

fn open_fds(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// The `q` quantile of `sorted` (nearest rank), NaN when empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// Least-squares slope of `ys` over `xs`.
fn slope(xs: &[f64], ys: &[f64]) -> f64 {
    let n = xs.len() as f64;
    if xs.len() < 2 {
        return 0.0;
    }
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    if sxx > 0.0 {
        sxy / sxx
    } else {
        0.0
    }
}

/// Sum of a counter family's samples in a Prometheus text exposition.
fn metric_sum(text: &str, name: &str) -> f64 {
    text.lines()
        .filter(|l| {
            l.starts_with(name) && matches!(l.as_bytes().get(name.len()), Some(b' ' | b'{'))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

async fn soak(args: &BenchSoakArgs, daemon: &mut Daemon) -> anyhow::Result<Vec<Tick>> {
    crate::alert::notify::ensure_crypto_provider();
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(30))
        .build()?;
    // Wait for the daemon to answer.
    let ready_by = Instant::now() + Duration::from_secs(30);
    loop {
        if let Ok(r) = client.get(format!("{}/readyz", daemon.http)).send().await {
            if r.status().is_success() {
                break;
            }
        }
        if let Some(status) = daemon.child.try_wait()? {
            anyhow::bail!("the daemon exited before it was ready: {status}");
        }
        anyhow::ensure!(
            Instant::now() < ready_by,
            "the daemon was not ready in 30 s"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let shared = Arc::new(Shared::default());
    let mut tasks = Vec::new();
    for g in 0..args.gates {
        let gate = HttpGate {
            client: client.clone(),
            base: daemon.http.clone(),
            name: format!("soak-{g}"),
            sim: simulator(g, args.rate),
            line: g % 2 == 1,
            until: None,
            record: true,
        };
        tasks.push(tokio::spawn(http_gate(gate, shared.clone())));
    }
    for g in 0..args.tcp_gates {
        tasks.push(tokio::spawn(tcp_gate(
            daemon.tcp.clone(),
            format!("soak-tcp-{g}"),
            simulator(args.gates + g, args.rate),
            shared.clone(),
        )));
    }
    let addr = daemon.http.trim_start_matches("http://").to_string();
    for _ in 0..args.slow_clients {
        tasks.push(tokio::spawn(slow_client(addr.clone(), shared.clone())));
    }
    // Transient gates and broken requests.
    {
        let (client, http, tcp, shared) = (
            client.clone(),
            daemon.http.clone(),
            daemon.tcp.clone(),
            shared.clone(),
        );
        let (churn, rate, per_s) = (args.churn_gates.max(1), args.rate, args.broken_per_second);
        tasks.push(tokio::spawn(async move {
            let started = Instant::now();
            let (mut k_churn, mut k_broken) = (0u64, 0u64);
            let mut tick = tokio::time::interval(Duration::from_millis(100));
            while !shared.stop.load(Ordering::Relaxed) {
                tick.tick().await;
                let t = started.elapsed().as_secs_f64();
                if t >= k_churn as f64 * CHURN_EVERY_SECONDS {
                    let name = format!("soak-churn-{}", k_churn as usize % churn);
                    let until = Instant::now() + Duration::from_secs_f64(CHURN_STREAM_SECONDS);
                    let gate = HttpGate {
                        client: client.clone(),
                        base: http.clone(),
                        name,
                        sim: simulator(10_000 + k_churn as usize, rate),
                        line: k_churn % 2 == 0,
                        until: Some(until),
                        record: false,
                    };
                    tokio::spawn(http_gate(gate, shared.clone()));
                    k_churn += 1;
                }
                while per_s > 0.0 && t >= k_broken as f64 / per_s {
                    let (client, http, tcp) = (client.clone(), http.clone(), tcp.clone());
                    let k = k_broken;
                    tokio::spawn(async move { broken_request(k, &http, &tcp, &client).await });
                    k_broken += 1;
                }
            }
        }));
    }

    let pid = daemon.child.id();
    let started = Instant::now();
    let end = started + Duration::from_secs_f64(args.minutes * 60.0);
    let mut ticks = Vec::new();
    let mut next = tokio::time::Instant::now();
    while Instant::now() < end {
        next += Duration::from_secs_f64(args.interval);
        tokio::time::sleep_until(next).await;
        if daemon.child.try_wait()?.is_some() {
            break;
        }
        let mut lat = std::mem::take(&mut *crate::service::sync::lock(&shared.latencies_ms));
        lat.sort_by(f64::total_cmp);
        let metrics = match client.get(format!("{}/metrics", daemon.http)).send().await {
            Ok(r) => r.text().await.unwrap_or_default(),
            Err(_) => String::new(),
        };
        let (rss_mib, hwm_mib) = memory_mib(pid).unwrap_or((f64::NAN, f64::NAN));
        let tick = Tick {
            t: started.elapsed().as_secs_f64(),
            rss_mib,
            hwm_mib,
            fds: open_fds(pid),
            requests: lat.len(),
            p50_ms: quantile(&lat, 0.5),
            p99_ms: quantile(&lat, 0.99),
            non_2xx: shared.non_2xx.swap(0, Ordering::Relaxed),
            transport_errors: shared.transport_errors.swap(0, Ordering::Relaxed),
            jobs_replaced: metric_sum(&metrics, "gatewatch_identification_jobs_replaced_total"),
        };
        if !args.json {
            errln!(
                "{:7.0} s  rss {:7.1} MiB  peak {:7.1} MiB  fds {:5}  req {:5}  p50 {:6.1} ms  p99 {:6.1} ms  non-2xx {:3}  replaced {:6.0}",
                tick.t, tick.rss_mib, tick.hwm_mib, tick.fds, tick.requests, tick.p50_ms,
                tick.p99_ms, tick.non_2xx, tick.jobs_replaced
            );
        }
        // Keep the whole run's latencies for the overall quantile, in the tick's own vector.
        crate::service::sync::lock(&ALL_LATENCIES).push((tick.t, lat));
        ticks.push(tick);
    }
    shared.stop.store(true, Ordering::Relaxed);
    for t in tasks {
        t.abort();
    }
    *crate::service::sync::lock(&ALL_STATUSES) =
        std::mem::take(&mut *crate::service::sync::lock(&shared.statuses));
    Ok(ticks)
}

/// Every record's latencies, kept for the overall p99 after the warm-up.
static ALL_LATENCIES: Mutex<Vec<(f64, Vec<f64>)>> = Mutex::new(Vec::new());

/// The steady requests' non-2xx answers by status, handed from the load to the summary.
static ALL_STATUSES: Mutex<std::collections::BTreeMap<u16, u64>> =
    Mutex::new(std::collections::BTreeMap::new());

fn stop_daemon(daemon: &mut Daemon) -> Option<i32> {
    // SIGTERM through kill(1): the daemon's graceful path, as systemd stops it.
    let _ = Command::new("kill")
        .arg("-TERM")
        .arg(daemon.child.id().to_string())
        .status();
    let by = Instant::now() + Duration::from_secs(30);
    while Instant::now() < by {
        if let Ok(Some(status)) = daemon.child.try_wait() {
            return status.code();
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = daemon.child.kill();
    let _ = daemon.child.wait();
    None
}

fn count_panics(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .map(|s| s.lines().filter(|l| l.contains("panicked")).count())
        .unwrap_or(0)
}

/// Judges `ticks` against the targets.
pub fn summarise(
    args: &BenchSoakArgs,
    ticks: &[Tick],
    latencies: &[(f64, Vec<f64>)],
    panics: usize,
    survived: bool,
    exit_code: Option<i32>,
) -> Summary {
    let after: Vec<&Tick> = ticks.iter().filter(|t| t.t >= args.warmup).collect();
    let after = if after.is_empty() {
        ticks.iter().collect()
    } else {
        after
    };
    let xs: Vec<f64> = after.iter().map(|t| t.t / 3600.0).collect();
    let ys: Vec<f64> = after.iter().map(|t| t.rss_mib).collect();
    let mut all: Vec<f64> = latencies
        .iter()
        .filter(|(t, _)| *t >= args.warmup)
        .flat_map(|(_, l)| l.iter().copied())
        .collect();
    all.sort_by(f64::total_cmp);
    let first = after.first();
    let last = after.last();
    let rss_after_warmup_mib = first.map_or(f64::NAN, |t| t.rss_mib);
    let rss_last_mib = last.map_or(f64::NAN, |t| t.rss_mib);
    let rss_peak_mib = ticks.iter().map(|t| t.hwm_mib).fold(0.0, f64::max);
    let rss_slope = slope(&xs, &ys);
    let fds_after_warmup = first.map_or(0, |t| t.fds);
    let fds_last = last.map_or(0, |t| t.fds);
    let p99_ms = quantile(&all, 0.99);
    let worst = after
        .iter()
        .map(|t| t.p99_ms)
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let minutes_after = after.last().map_or(0.0, |l| l.t) / 60.0 - args.warmup / 60.0;
    // Flat: the fitted growth over the measured stretch stays within 5 % of the level (and
    // 8 MiB), so the allocator's noise is not called a leak.
    let growth = rss_slope * minutes_after.max(0.0) / 60.0;
    let flat = growth <= (0.05 * rss_after_warmup_mib).max(8.0);
    // Descriptors: the slowloris and broken clients hold some at any moment; growth beyond
    // the clients' own count is a leak.
    let fd_slack = args.slow_clients + args.gates + args.tcp_gates + 16;
    let targets = vec![
        ("rss flat after warm-up".to_string(), flat),
        (
            format!("rss peak under {:.0} MiB", args.rss_bound_mib),
            rss_peak_mib <= args.rss_bound_mib,
        ),
        (
            "no descriptor growth".to_string(),
            fds_last <= fds_after_warmup + fd_slack,
        ),
        (
            format!("p99 ingest latency under {P99_TARGET_MS} ms"),
            p99_ms < P99_TARGET_MS,
        ),
        ("no panic".to_string(), panics == 0),
        ("daemon survived".to_string(), survived),
    ];
    Summary {
        minutes: ticks.last().map_or(0.0, |t| t.t / 60.0),
        rss_after_warmup_mib,
        rss_last_mib,
        rss_slope_mib_per_hour: rss_slope,
        rss_peak_mib,
        fds_after_warmup,
        fds_last,
        p99_ms,
        worst_interval_p99_ms: worst,
        requests: ticks.iter().map(|t| t.requests).sum(),
        non_2xx: ticks.iter().map(|t| t.non_2xx).sum(),
        non_2xx_by_status: Default::default(),
        jobs_replaced: ticks.last().map_or(0.0, |t| t.jobs_replaced),
        panics,
        survived,
        exit_code,
        targets,
    }
}

/// `gatewatch bench soak`.
pub fn bench_soak(args: BenchSoakArgs) -> ExitCode {
    let positive = |v: f64| v > 0.0 && v.is_finite();
    // a year at most (`config::MAX_SECONDS`): the run's end and its ticks are `Duration`s,
    // which a huge float overflows
    let seconds = |v: f64| v > 0.0 && v <= crate::service::config::MAX_SECONDS;
    if !seconds(args.minutes * 60.0)
        || !seconds(args.interval)
        || !positive(args.rate)
        || !positive(args.rss_bound_mib)
        || !(args.broken_per_second == 0.0 || positive(args.broken_per_second))
        || !(args.warmup == 0.0 || positive(args.warmup))
    {
        errln!(
            "gatewatch bench soak: --minutes, --interval, --rate and --rss-bound-mib must be \
             > 0 (--minutes and --interval at most a year), --broken-per-second and --warmup \
             >= 0"
        );
        return ExitCode::from(2);
    }
    let mut daemon = match start_daemon(&args) {
        Ok(d) => d,
        Err(e) => {
            errln!("gatewatch bench soak: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            errln!("gatewatch bench soak: starting the load's runtime: {e}");
            let _ = daemon.child.kill();
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(soak(&args, &mut daemon));
    drop(runtime);
    let survived = matches!(daemon.child.try_wait(), Ok(None));
    let exit_code = if survived {
        stop_daemon(&mut daemon)
    } else {
        daemon
            .child
            .try_wait()
            .ok()
            .flatten()
            .and_then(|s| s.code())
    };
    let ticks = match result {
        Ok(t) => t,
        Err(e) => {
            errln!("gatewatch bench soak: {e:#}");
            let _ = daemon.child.kill();
            return ExitCode::FAILURE;
        }
    };
    let panics = count_panics(&daemon.stderr_path);
    let latencies = std::mem::take(&mut *crate::service::sync::lock(&ALL_LATENCIES));
    let mut summary = summarise(&args, &ticks, &latencies, panics, survived, exit_code);
    summary.non_2xx_by_status = std::mem::take(&mut *crate::service::sync::lock(&ALL_STATUSES));
    // `| head`: the reader has what it wanted; the verdict below is still the exit code
    if let Err(e) = print_summary(args.json, &ticks, &summary) {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            errln!("gatewatch bench soak: writing to stdout: {e}");
            return ExitCode::FAILURE;
        }
    }
    if summary.targets.iter().all(|(_, ok)| *ok) {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// Prints the records and the summary (JSON), or the summary's line and the targets.
fn print_summary(json: bool, ticks: &[Tick], summary: &Summary) -> std::io::Result<()> {
    if json {
        let out = serde_json::json!({"ticks": ticks, "summary": summary});
        outln!("{out}")?;
    } else {
        outln!(
            "soak {:.1} min: rss {:.1} -> {:.1} MiB after warm-up ({:+.1} MiB/h), peak {:.1} MiB; \
             fds {} -> {}; p99 {:.1} ms (worst interval {:.1} ms) over {} requests, {} non-2xx; \
             jobs replaced {:.0}; panics {}; exit {:?}",
            summary.minutes,
            summary.rss_after_warmup_mib,
            summary.rss_last_mib,
            summary.rss_slope_mib_per_hour,
            summary.rss_peak_mib,
            summary.fds_after_warmup,
            summary.fds_last,
            summary.p99_ms,
            summary.worst_interval_p99_ms,
            summary.requests,
            summary.non_2xx,
            summary.jobs_replaced,
            summary.panics,
            summary.exit_code
        )?;
        if !summary.non_2xx_by_status.is_empty() {
            outln!("  non-2xx by status: {:?}", summary.non_2xx_by_status)?;
        }
        for (name, ok) in &summary.targets {
            outln!("  {} {name}", if *ok { "PASS" } else { "FAIL" })?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
