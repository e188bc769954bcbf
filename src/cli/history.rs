//! `gatewatch history --db FILE --gate ID [--from] [--to] [--limit] [--csv]`: a gate's
//! identification history from the daemon's store, for engineers who work offline. The file is
//! opened read-only (also while the daemon writes to it: WAL).

use std::path::PathBuf;

use super::CliError;
use crate::store::{history_csv, parse_time, HistoryQuery, SqliteStore, Store, MAX_HISTORY_LIMIT};

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
    #[arg(long)]
    pub csv: bool,
}

/// Prints the history on stdout.
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
    let store =
        SqliteStore::open_read_only(&args.db).map_err(|e| CliError::Input(e.to_string()))?;
    let rows = store.history(&query).map_err(anyhow::Error::from)?;
    if args.csv {
        print!("{}", history_csv(&rows).map_err(anyhow::Error::msg)?);
    } else {
        for r in &rows {
            println!("{}", serde_json::to_string(r).map_err(anyhow::Error::from)?);
        }
    }
    Ok(())
}
