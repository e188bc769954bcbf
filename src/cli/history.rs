//! `gatewatch history --db FILE --gate ID [--from] [--to] [--limit] [--csv] [--plot FILE.svg]`:
//! a gate's identification history from the daemon's store, for engineers who work offline.
//! The file is opened read-only (also while the daemon writes to it: WAL).

use std::io::Write;
use std::path::PathBuf;

use super::CliError;
use crate::plot::{DampingPoint, Thresholds};
use crate::store::{
    history_csv, parse_time, HistoryQuery, IdentificationRecord, SqliteStore, Store,
    MAX_HISTORY_LIMIT,
};

/// Arguments of `gatewatch history`.
#[derive(Debug, clap::Args)]
pub struct HistoryArgs {
    /// The store's SQLite file (`[storage] path`).
    #[arg(long)]
    pub db: PathBuf,
    /// Gate id.
    #[arg(long)]
    pub gate: String,
    /// From this window end on: Unix seconds or RFC 3339 (`2024-05-01T12:00:00Z`).
    #[arg(long)]
    pub from: Option<String>,
    /// Up to this window end: Unix seconds or RFC 3339.
    #[arg(long)]
    pub to: Option<String>,
    /// At most this many rows (1..=20000).
    #[arg(long, default_value_t = MAX_HISTORY_LIMIT)]
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
            return Err(CliError::Input(format!("--from ({f}) is after --to ({t})")));
        }
    }
    // the thresholds before the database: a bad --config fails before any work
    let thresholds = match &args.config {
        Some(path) => Some(thresholds(path, &args.gate)?),
        None => None,
    };
    let store =
        SqliteStore::open_read_only(&args.db).map_err(|e| CliError::Input(e.to_string()))?;
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
                args.db.display(),
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
            args.db.display(),
            if args.plot.is_some() {
                ": nothing to plot"
            } else {
                ""
            }
        )));
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
        return Err(CliError::Input(format!(
            "--config {}: no such file",
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
