//! `gatewatch bench history`: how large a day of history is and how fast the daemon serves it.
//!
//! Writes `--hours` of identifications for `--gates` gates (one window every
//! `--every-seconds`, all gates at each step, as the daemon interleaves them) through the real
//! SQLite store ([`SqliteStore`], the daemon's schema and insert), reports the database size,
//! then starts the real daemon (`server::run`) on that file and times
//! `GET /api/v1/gates/{id}/history` for one gate's whole range, as JSON and as CSV, through a
//! real HTTP client: the store query, the serialisation and the transfer together. It also
//! times the store query alone, so a miss can be placed.
//!
//! The rows are realistic: their damping reports come from the daemon's real window analysis
//! of two simulated windows (a damped gate and one on its limit cycle, so the zeta_eq(A) curve
//! and the intervals have their real sizes), written with the daemon's own
//! `identification_record`, with zeta0 and its interval varied per row from a seeded
//! generator.
//!
//! With `--nats URL` the same rows go to a NATS server's JetStream streams through the real
//! [`NatsStore`] (under a prefix of the run's own, deleted at the end), and the daemon of the
//! route runs on that store. It also times `latest_history_rows(gate, 1)`, the read a restart
//! and a gate's first report make.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant, SystemTime};

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::Config;
use super::server::{run, Listeners};
use super::stdout::{errln, outln};
use super::storage::identification_record;
use super::worker::{AnalyzerMap, WindowAnalyzer};
use crate::analysis::{WindowAnalysis, WindowInput};
use crate::simulate::{GateParams, GateSimulator, Scenario};
use crate::store::{
    HistoryQuery, NatsOptions, NatsStore, SqliteStore, StorageBackend, Store, WriteBatch,
    MAX_HISTORY_LIMIT,
};

/// Arguments of `gatewatch bench history`.
#[derive(Debug, clap::Args)]
pub struct BenchHistoryArgs {
    /// Gates.
    #[arg(long, allow_negative_numbers = true, default_value_t = 16)]
    pub gates: usize,
    /// Hours of history per gate.
    #[arg(long, default_value_t = 24.0, allow_negative_numbers = true)]
    pub hours: f64,
    /// Seconds between two identifications of a gate (`identify_every_seconds`).
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    pub every_seconds: f64,
    /// Timed requests of each kind (the first, cold one is reported apart).
    #[arg(long, allow_negative_numbers = true, default_value_t = 10)]
    pub queries: usize,
    /// The database file to create (must not exist); default: in a temporary directory,
    /// deleted at the end.
    #[arg(long)]
    pub db: Option<PathBuf>,
    /// Seed of the per-row variation.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub seed: u64,
    /// A NATS server (`nats-server -js`) to write to and read from instead of a SQLite file,
    /// e.g. nats://127.0.0.1:4222. The streams are made under a prefix of this run's own
    /// (`GWBENCH<pid>`) and deleted at the end.
    #[arg(long, conflicts_with = "db")]
    pub nats: Option<String>,
}

/// Rows per write transaction (the daemon's writer merges up to 256 requests; larger here only
/// to write a day quickly: the file's layout does not depend on it).
const ROWS_PER_TRANSACTION: usize = 2000;

/// A directory of its own under the system's temporary directory, deleted on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> std::io::Result<TempDir> {
        let dir =
            std::env::temp_dir().join(format!("gatewatch-bench-history-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        Ok(TempDir(dir))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs the benchmark; the report goes to stdout.
pub fn bench_history(args: BenchHistoryArgs) -> ExitCode {
    if let Err(e) = check(&args) {
        errln!("gatewatch bench history: {e}");
        return ExitCode::from(2);
    }
    match bench(&args) {
        Ok(()) => ExitCode::SUCCESS,
        // a closed stdout (`| head`) ends the run quietly
        Err(e) => super::stdout::exit_code("gatewatch bench history", &e),
    }
}

/// The arguments' ranges, before anything is written: a bad one is the user's input (exit 2).
fn check(args: &BenchHistoryArgs) -> anyhow::Result<()> {
    use crate::number::Num;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if args.gates == 0 {
        anyhow::bail!("--gates must be >= 1");
    }
    // the rows' times count back from now: past a year they left the clock's range
    if !(positive(args.hours) && args.hours * 3600.0 <= crate::service::config::MAX_SECONDS) {
        anyhow::bail!(
            "--hours must be > 0 and at most {} (a year), got {}",
            Num(crate::service::config::MAX_SECONDS / 3600.0),
            Num(args.hours)
        );
    }
    if !positive(args.every_seconds) {
        anyhow::bail!(
            "--every-seconds must be > 0, got {}",
            Num(args.every_seconds)
        );
    }
    if args.queries == 0 {
        anyhow::bail!("--queries must be >= 1");
    }
    let per_gate = (args.hours * 3600.0 / args.every_seconds).floor() as usize;
    if per_gate == 0 {
        anyhow::bail!("--hours holds no window of --every-seconds");
    }
    if let Some(p) = &args.db {
        if p.exists() {
            anyhow::bail!("--db {}: exists; give a new file", p.display());
        }
        let parent = p.parent().filter(|d| !d.as_os_str().is_empty());
        if let Some(dir) = parent.filter(|d| !d.is_dir()) {
            anyhow::bail!(
                "--db {}: its directory {} does not exist",
                p.display(),
                dir.display()
            );
        }
    }
    Ok(())
}

/// Where the rows go: a SQLite file, or a NATS server's streams under a prefix.
enum Target {
    Sqlite(PathBuf),
    Nats { url: String, prefix: String },
}

impl Target {
    fn open(&self, config: &Config) -> anyhow::Result<Box<dyn Store>> {
        Ok(match self {
            Target::Sqlite(path) => Box::new(SqliteStore::open(path, config.storage.max_size_mb)?),
            Target::Nats { url, prefix } => {
                let s = &config.storage;
                let mut o = NatsOptions::new(url, s.retention(), s.max_history_rows);
                o.prefix = prefix.clone();
                Box::new(NatsStore::open(&o)?)
            }
        })
    }

    /// The daemon's configuration on this store.
    fn configure(&self, config: &mut Config) {
        match self {
            Target::Sqlite(path) => config.storage.path = path.display().to_string(),
            Target::Nats { url, prefix } => {
                config.storage.backend = StorageBackend::Nats;
                config.storage.nats_url = url.clone();
                config.storage.nats_prefix = prefix.clone();
            }
        }
    }
}

fn bench(args: &BenchHistoryArgs) -> anyhow::Result<()> {
    let per_gate = (args.hours * 3600.0 / args.every_seconds).floor() as usize;
    let mut _tmp = None;
    let target = match (&args.db, &args.nats) {
        (_, Some(url)) => Target::Nats {
            url: url.clone(),
            prefix: format!("GWBENCH{}", std::process::id()),
        },
        (Some(p), None) => {
            if p.exists() {
                anyhow::bail!("--db {}: exists; give a new file", p.display());
            }
            Target::Sqlite(p.clone())
        }
        (None, None) => {
            let dir = TempDir::new()?;
            let p = dir.0.join("history.db");
            _tmp = Some(dir);
            Target::Sqlite(p)
        }
    };
    let result = measure(args, per_gate, &target);
    if let Target::Nats { url, prefix } = &target {
        let cleaned = delete_streams(url, prefix);
        match (&result, cleaned) {
            (_, Ok(())) => outln!("streams {prefix}_* deleted from {url}")?,
            (Ok(()), Err(e)) => return Err(e.context(format!("deleting the streams {prefix}_*"))),
            // the run's own failure says more
            (Err(_), Err(_)) => {}
        }
    }
    result
}

/// Deletes the four streams of `prefix` (the store's names, docs/design.md, "The NATS store").
fn delete_streams(url: &str, prefix: &str) -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let client = async_nats::connect(url).await?;
        let js = async_nats::jetstream::new(client);
        for suffix in ["HISTORY", "OUTBOX", "ALERTS", "OWNER"] {
            // a stream the store never made (the run failed early) is no error
            let _ = js.delete_stream(format!("{prefix}_{suffix}")).await;
        }
        anyhow::Ok(())
    })
}

fn measure(args: &BenchHistoryArgs, per_gate: usize, target: &Target) -> anyhow::Result<()> {
    let config = Config::embedded();
    let templates = templates(&config)?;
    outln!(
        "templates: {} real window analyses ({} and {} bytes of damping report)",
        templates.len(),
        serde_json::to_string(&templates[0].damping)?.len(),
        serde_json::to_string(&templates[1].damping)?.len()
    )?;

    // write: every gate at each step, oldest first, ending now
    let store = target.open(&config)?;
    let now = crate::service::clock::unix_seconds(SystemTime::now());
    let start = now - per_gate as f64 * args.every_seconds;
    let gates: Vec<String> = (0..args.gates).map(|g| format!("g{g:02}")).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let began = Instant::now();
    let mut batch = WriteBatch::default();
    let mut rows = 0usize;
    for step in 0..per_gate {
        let end = start + (step + 1) as f64 * args.every_seconds;
        for gate in &gates {
            let mut a = templates[rng.random_range(0..templates.len())].clone();
            let zeta: f64 = rng.random_range(-0.02..0.03);
            let half: f64 = rng.random_range(0.002..0.01);
            a.damping.zeta0 = Some(zeta);
            a.damping.zeta0_interval = Some((zeta - half, zeta + half));
            a.damping.fit_nmae = rng.random_range(0.01..0.2);
            let window = (end - config.defaults.window_seconds, end);
            let time = SystemTime::UNIX_EPOCH + Duration::from_secs_f64(end + 0.8);
            batch
                .identifications
                .push(identification_record(gate, time, window, &a));
            rows += 1;
            if batch.identifications.len() == ROWS_PER_TRANSACTION {
                store.write(&std::mem::take(&mut batch))?;
            }
        }
    }
    store.write(&batch)?;
    let write_s = began.elapsed().as_secs_f64();
    outln!(
        "wrote {rows} rows ({} gates x {per_gate}) in {write_s:.1} s ({:.0} rows/s), \
         {} rows per write",
        args.gates,
        rows as f64 / write_s,
        ROWS_PER_TRANSACTION
    )?;
    if let Target::Sqlite(path) = target {
        drop(store);
        // the file's size once its WAL is merged
        SqliteStore::open(path, config.storage.max_size_mb)?.checkpoint()?;
        let size = std::fs::metadata(path)?.len();
        outln!(
            "database file: {size} bytes ({:.1} MiB), {:.0} bytes per row",
            size as f64 / 1048576.0,
            size as f64 / rows as f64
        )?;
    } else {
        drop(store);
    }
    let store = target.open(&config)?;

    // the store queries alone (what the route and a restart run in spawn_blocking)
    let expected = per_gate.min(MAX_HISTORY_LIMIT);
    let query = HistoryQuery {
        gate: gates[0].clone(),
        from: Some(start),
        to: Some(now + 1.0),
        limit: MAX_HISTORY_LIMIT,
    };
    let (mut store_ms, mut latest_ms) = (Vec::new(), Vec::new());
    for _ in 0..args.queries {
        let t = Instant::now();
        let got = store.history_rows(&query)?;
        store_ms.push(t.elapsed().as_secs_f64() * 1e3);
        anyhow::ensure!(
            got.len() == expected,
            "{} rows, expected {expected}",
            got.len()
        );
        let t = Instant::now();
        let last = store.latest_history_rows(&gates[0], 1)?;
        latest_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let newest = start + per_gate as f64 * args.every_seconds;
        anyhow::ensure!(
            last.len() == 1 && last[0].window_end == newest,
            "the newest row is not the last written: {:?}",
            last.first().map(|r| r.window_end)
        );
    }
    drop(store);

    // the real route on the real daemon
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let (json_ms, csv_ms, bytes) = runtime.block_on(route(target, &gates[0], start, now, args))?;
    let line = |what: &str, ms: &[f64]| {
        let mut warm = ms[1..].to_vec();
        warm.sort_by(f64::total_cmp);
        if warm.is_empty() {
            outln!("{what:<44} first {:8.1} ms", ms[0])?;
        } else {
            outln!(
                "{what:<44} first {:8.1} ms  median {:8.1} ms  max {:8.1} ms",
                ms[0],
                warm[warm.len() / 2],
                warm[warm.len() - 1]
            )?;
        }
        std::io::Result::Ok(())
    };
    outln!(
        "one gate's {per_gate} rows ({:.1} h; a request returns at most {MAX_HISTORY_LIMIT}), \
         {} requests each:",
        per_gate as f64 * args.every_seconds / 3600.0,
        args.queries
    )?;
    let kind = match target {
        Target::Sqlite(_) => "SqliteStore",
        Target::Nats { .. } => "NatsStore",
    };
    line(&format!("store query ({kind}::history_rows)"), &store_ms)?;
    line("store: the newest row (latest_history_rows)", &latest_ms)?;
    line(
        &format!("GET .../history JSON ({:.1} MB)", bytes.0 as f64 / 1e6),
        &json_ms,
    )?;
    line(
        &format!("GET .../history CSV ({:.1} MB)", bytes.1 as f64 / 1e6),
        &csv_ms,
    )?;
    Ok(())
}

/// Two real window analyses: a damped gate and one on its limit cycle.
fn templates(config: &Config) -> anyhow::Result<Vec<WindowAnalysis>> {
    let analyzer = AnalyzerMap::from_config(config)?;
    let rate = config.defaults.rate_hz;
    let n = (config.defaults.window_seconds * rate).round() as usize;
    let mut out = Vec::new();
    for (scenario, seed) in [(Scenario::Stable, 3), (Scenario::LimitCycle, 4)] {
        let params = GateParams {
            rate_hz: rate,
            ..Default::default()
        };
        let mut sim = GateSimulator::scenario(params, scenario, seed);
        let mut values = vec![0.0; n];
        sim.fill(&mut values);
        let input = WindowInput {
            t0: 0.0,
            rate_hz: rate,
            values: &values,
            history: &[],
        };
        out.push(analyzer.analyze("g00", input, None, seed)?);
    }
    Ok(out)
}

/// Times the route: `(JSON ms, CSV ms, (JSON bytes, CSV bytes))`.
async fn route(
    target: &Target,
    gate: &str,
    start: f64,
    now: f64,
    args: &BenchHistoryArgs,
) -> anyhow::Result<(Vec<f64>, Vec<f64>, (usize, usize))> {
    super::client::ensure_crypto_provider();
    let mut config = Config::embedded();
    config.server.listen = "127.0.0.1:0".into();
    config.server.tcp_listen = String::new();
    config.server.worker_threads = 1;
    target.configure(&mut config);
    let http = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let url = format!(
        "http://{}/api/v1/gates/{gate}/history?from={start}&to={}",
        http.local_addr()?,
        now + 1.0
    );
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let daemon = tokio::spawn(run(config, Listeners::http_only(http), async move {
        let _ = stopped.await;
    }));
    let client = reqwest::Client::new();
    // the daemon opens the store off the executor: wait until it answers
    let deadline = Instant::now() + Duration::from_secs(60);
    while client.get(format!("{url}&limit=1")).send().await.is_err() {
        anyhow::ensure!(Instant::now() < deadline, "the daemon did not start");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut times = (Vec::new(), Vec::new());
    let mut bytes = (0, 0);
    for csv in [false, true] {
        for _ in 0..args.queries {
            let mut req = client.get(&url);
            if csv {
                req = req.header("accept", "text/csv");
            }
            let t = Instant::now();
            let resp = req.send().await?;
            anyhow::ensure!(resp.status().is_success(), "HTTP {}", resp.status());
            let body = resp.bytes().await?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            if csv {
                times.1.push(ms);
                bytes.1 = body.len();
            } else {
                times.0.push(ms);
                bytes.0 = body.len();
            }
        }
    }
    let _ = stop.send(());
    let _ = tokio::time::timeout(Duration::from_secs(30), daemon).await;
    Ok((times.0, times.1, bytes))
}
