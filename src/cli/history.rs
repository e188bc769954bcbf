//! `gatewatch history (--db FILE | --nats URL [--nats-prefix P]) --gate ID [--from] [--to]
//! [--limit] [--csv] [--plot FILE.svg]`: a gate's identification history from the daemon's
//! store, for engineers who work offline. The store is only read: the SQLite file is opened
//! read-only (also while the daemon writes to it: WAL), the NATS streams are looked up, not
//! created or changed, and the daemon's owner lease is left to it
//! ([`NatsStore::open_read_only`]). Past the opening, both go through the [`Store`] trait.

use std::io::Write;
use std::path::PathBuf;

use super::CliError;
use crate::plot::{DampingPoint, Thresholds};
use crate::store::{
    history_csv, parse_time, HistoryQuery, IdentificationRecord, NatsStore, SqliteStore,
    StorageConfig, Store, StoreError, MAX_HISTORY_LIMIT, NATS_OPERATION_TIMEOUT,
};

/// Arguments of `gatewatch history`.
///
/// The NATS store is named by `--nats URL` and `--nats-prefix`, not by the daemon's
/// configuration file: `--config` already means "the thresholds for `--plot`", reading
/// `[storage]` from it as well would make one flag do two things (and read the SQLite `path`
/// of a file meant for thresholds); and like `--db FILE` the two flags name the store itself,
/// which is what an operator on another machine (a port-forward to the server) has at hand.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("store").required(true).args(["db", "nats"])))]
pub struct HistoryArgs {
    /// The store's SQLite file (`[storage] path`).
    #[arg(long)]
    pub db: Option<PathBuf>,
    /// The NATS server of the store (`[storage] nats_url`, e.g. nats://127.0.0.1:4222), read
    /// without taking its owner lease: a running daemon keeps it.
    #[arg(long, value_name = "URL")]
    pub nats: Option<String>,
    /// The prefix of the NATS store's streams (`[storage] nats_prefix`; default GATEWATCH).
    // `conflicts_with` as well: clap lets a requirement go unmet when it conflicts with a
    // present argument (`--nats` with `--db`), which would ignore the prefix without a word
    #[arg(long, value_name = "PREFIX", requires = "nats", conflicts_with = "db")]
    pub nats_prefix: Option<String>,
    /// Gate id.
    #[arg(long)]
    pub gate: String,
    /// From this window end on: Unix seconds or RFC 3339 (`2024-05-01T12:00:00Z`).
    #[arg(long, allow_negative_numbers = true)]
    pub from: Option<String>,
    /// Up to this window end: Unix seconds or RFC 3339.
    #[arg(long, allow_negative_numbers = true)]
    pub to: Option<String>,
    /// At most this many rows (1..=20000).
    #[arg(long, allow_negative_numbers = true, default_value_t = MAX_HISTORY_LIMIT)]
    pub limit: usize,
    /// CSV instead of JSON lines.
    #[arg(long, conflicts_with = "plot")]
    pub csv: bool,
    /// Draw the damping over time (zeta0 with its 95 % interval, verdict changes) into this
    /// file (.svg or .png) instead of printing the rows.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// The daemon's configuration: the plot then shows the gate's alert thresholds
    /// (`fire_below`, `clear_above`).
    #[arg(long, requires = "plot")]
    pub config: Option<PathBuf>,
}

/// Opens the store the arguments name, read-only; the one place the backends differ. Returns
/// it with its name for the messages (the file, or the server and the prefix).
fn open(args: &HistoryArgs) -> Result<(Box<dyn Store>, String), CliError> {
    if let Some(db) = &args.db {
        let store = SqliteStore::open_read_only(db).map_err(|e| CliError::Input(e.to_string()))?;
        return Ok((Box::new(store), db.display().to_string()));
    }
    // clap's group makes one of the two present
    let url = args.nats.as_deref().unwrap_or_default();
    let prefix = args
        .nats_prefix
        .clone()
        .unwrap_or_else(|| StorageConfig::default().nats_prefix);
    let name = format!("NATS server {url}, prefix {prefix}");
    let store = NatsStore::open_read_only(url, &prefix, NATS_OPERATION_TIMEOUT).map_err(|e| {
        let why = match e {
            StoreError::Open { message, .. } => message,
            other => other.to_string(),
        };
        // one line: the client's errors may carry the server's multi-line text
        CliError::Input(format!("{name}: {}", one_line(&why)))
    })?;
    Ok((Box::new(store), name))
}

/// `s` with its line breaks folded into spaces.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Prints the history on stdout, or draws it with `--plot`.
pub fn run(args: HistoryArgs) -> Result<(), CliError> {
    let time = |name: &str, v: &Option<String>| -> Result<Option<f64>, CliError> {
        v.as_deref()
            .map(|s| parse_time(s).map_err(|e| CliError::Input(format!("--{name}: {e}"))))
            .transpose()
    };
    if args.limit == 0 || args.limit > MAX_HISTORY_LIMIT {
        return Err(CliError::Input(format!(
            "--limit must be in 1..={MAX_HISTORY_LIMIT}, got {}",
            args.limit
        )));
    }
    let query = HistoryQuery {
        gate: args.gate.clone(),
        from: time("from", &args.from)?,
        to: time("to", &args.to)?,
        limit: args.limit,
    };
    if let (Some(f), Some(t)) = (query.from, query.to) {
        if f > t {
            let (f, t) = (crate::number::Num(f), crate::number::Num(t));
            return Err(CliError::Input(format!("--from ({f}) is after --to ({t})")));
        }
    }
    // the thresholds before the database: a bad --config fails before any work
    let thresholds = match &args.config {
        Some(path) => Some(thresholds(path, &args.gate)?),
        None => None,
    };
    let (store, source) = open(&args)?;
    let rows = store.history(&query).map_err(anyhow::Error::from)?;
    if rows.is_empty() {
        // a loose scan of the key: one lookup per gate, not a read of the table
        let gates = store
            .history_gates(usize::MAX)
            .map_err(anyhow::Error::from)?;
        if !gates.contains(&args.gate) {
            return Err(CliError::Input(format!(
                "unknown gate `{}`: {} has no identification of it (gates: {})",
                args.gate,
                source,
                gate_list(&gates)
            )));
        }
        // an empty range exits 2 like a bad one (docs/operations.md, "Offline reading"): an
        // empty output with exit 0 reads as "no windows" and as "wrong range" alike
        return Err(CliError::Input(format!(
            "gate `{}` has no identification between {} and {} in {}{}",
            args.gate,
            args.from.as_deref().unwrap_or("the first"),
            args.to.as_deref().unwrap_or("the last"),
            source,
            if args.plot.is_some() {
                ": nothing to plot"
            } else {
                ""
            }
        )));
    }
    // A full page may not be the whole range: say so, and where the next page starts, rather
    // than end a day's CSV at its 20 000th row without a word.
    if rows.len() == query.limit {
        let last = rows.last().map_or(f64::NAN, |r| r.window_end);
        let next = HistoryQuery {
            from: Some(last),
            limit: 2,
            ..query.clone()
        };
        let more = store.history(&next).map_err(anyhow::Error::from)?;
        if more.iter().any(|r| r.window_end > last) {
            let _ = writeln!(
                std::io::stderr(),
                "gatewatch history: the range holds more than --limit {} windows of gate {}; \
                 these are the oldest {0}. The next page: --from {} (that window comes again \
                 first)",
                query.limit,
                args.gate,
                crate::number::Num(last)
            );
        }
    }
    if let Some(path) = &args.plot {
        let points: Vec<DampingPoint> = rows.iter().map(point).collect();
        crate::plot::damping_history(path, &args.gate, &points, thresholds)
            .map_err(|e| CliError::Input(format!("--plot: {e}")))?;
        let _ = writeln!(
            std::io::stderr(),
            "gatewatch: wrote {} ({} windows of gate {})",
            path.display(),
            rows.len(),
            args.gate
        );
    } else if args.csv {
        let csv = history_csv(&rows).map_err(anyhow::Error::msg)?;
        std::io::stdout().lock().write_all(csv.as_bytes())?;
    } else {
        let mut out = std::io::stdout().lock();
        for r in &rows {
            let line = serde_json::to_string(r).map_err(anyhow::Error::from)?;
            writeln!(out, "{line}")?;
        }
    }
    Ok(())
}

/// Gates named in the "unknown gate" message at most; the others are counted.
const LISTED_GATES: usize = 10;

/// `a, b, c`, or the first [`LISTED_GATES`] and how many more; `none` for none.
fn gate_list(gates: &[String]) -> String {
    if gates.is_empty() {
        return "none".to_string();
    }
    let mut list = gates[..gates.len().min(LISTED_GATES)].join(", ");
    if gates.len() > LISTED_GATES {
        list.push_str(&format!(" and {} more", gates.len() - LISTED_GATES));
    }
    list
}

/// What the picture needs of a stored identification.
fn point(r: &IdentificationRecord) -> DampingPoint {
    DampingPoint {
        time: r.window_end,
        zeta0: r.zeta0(),
        interval: r.zeta0_interval(),
        verdict: r.verdict.clone(),
        // An old row without the field was not known to be trusted.
        trusted: r
            .damping
            .get("trusted")
            .and_then(serde_json::Value::as_bool)
            .unwrap_or(false),
    }
}

/// The gate's alert thresholds from the daemon's configuration file (its own `[gates.ID]`
/// table, or the defaults).
fn thresholds(path: &std::path::Path, gate: &str) -> Result<Thresholds, CliError> {
    if !path.is_file() {
        let why = if path.is_dir() {
            "a directory, not a configuration file"
        } else if path.exists() {
            "not a regular file"
        } else {
            "no such file"
        };
        return Err(CliError::Input(format!(
            "--config {}: {why}",
            path.display()
        )));
    }
    let config = crate::service::config::Config::from_file(path)
        .map_err(|e| CliError::Input(format!("--config {}: {e}", path.display())))?;
    let rules = &config.gate(gate).unwrap_or(&config.defaults).alert;
    Ok(Thresholds {
        fire_below: rules.fire_below,
        clear_above: rules.clear_above,
    })
}
