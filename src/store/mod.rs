//! The daemon's persistence: identification history, each gate's alert state and the
//! notification outbox, behind one small trait, [`Store`].
//!
//! The service talks to the trait only, so the embedded implementation ([`SqliteStore`], one
//! SQLite file in WAL mode) can be replaced by a distributed one ([`NatsStore`], NATS
//! JetStream streams shared by several daemons) without the alert engine, the notifier or the
//! worker pool knowing. Nothing in the numerical core imports this module. Why SQLite and WAL,
//! the migrations and the outbox semantics are in `docs/design.md` ("The store"), the NATS
//! mapping in its "The NATS store".
//!
//! # Layout
//! - this file: the trait, the records it keeps, its error type;
//! - `config`: [`StorageConfig`] (`[storage]`: which backend, where) and the bounds;
//! - `sqlite`: [`SqliteStore`]: the queries, the pruning and the size bound;
//! - `nats`: [`NatsStore`]: the history, the alert states and the outbox as JetStream
//!   streams, called through a small runtime of its own with a timeout, and the owner lease
//!   ([`LeaseRecord`]: one daemon per prefix);
//! - `file`: the store's file on disk: the lock (one daemon per file), the damage check at
//!   open, the read-only copy's URI;
//! - `schema`: the schema and its migrations (version 2 clusters a gate's rows and keeps the
//!   summary in columns; `docs/design.md`, "The history table");
//! - `row`: [`HistoryRow`], a stored identification as the history route serves it, and the
//!   compaction of a record before it is stored;
//! - `writer`: [`StoreWriter`], the dedicated thread that takes every write off the callers'
//!   threads through a bounded queue;
//! - `wal`: the check of the `-wal` file before SQLite opens it (a damaged frame makes SQLite
//!   drop every later frame without a word: the WAL is copied aside and the loss logged);
//! - `history`: time parsing (`RFC 3339` or Unix seconds) and the CSV form of the history,
//!   shared by the HTTP route and `gatewatch history`.

mod config;
mod file;
mod history;
mod nats;
mod row;
mod schema;
mod sqlite;
mod wal;
mod writer;

pub use config::{
    StorageBackend, StorageConfig, MAX_HISTORY_LIMIT, MIN_USEFUL_SIZE_MB, STORE_QUEUE_CAPACITY,
};
pub use file::{lock_path, QUICK_CHECK_MAX_BYTES};
pub use history::{
    history_csv, history_csv_rows, history_json_rows, parse_time, HISTORY_CSV_HEADER,
};
pub use nats::{
    decode as decode_nats_name, encode as encode_nats_name,
    reconnect_delay as nats_reconnect_delay, renew_interval as nats_lease_renew_interval,
    retry_interval as nats_lease_retry_interval, valid_prefix as valid_nats_prefix, LeaseRecord,
    NatsOptions, NatsStore, CLOCK_MARGIN as NATS_CLOCK_MARGIN, LEASE_TTL as NATS_LEASE_TTL,
    NATS_RUNTIME_THREADS, OPERATION_TIMEOUT as NATS_OPERATION_TIMEOUT,
    PRUNE_SCAN_MAX as NATS_PRUNE_SCAN_MAX, RECONNECT_DELAY_MAX as NATS_RECONNECT_DELAY_MAX,
    RENEWALS_PER_TTL as NATS_LEASE_RENEWALS_PER_TTL,
    RETRIES_PER_RENEWAL as NATS_LEASE_RETRIES_PER_RENEWAL,
};
pub use row::{HistoryRow, CURVE_STORED_DIGITS, CURVE_STORED_POINTS};
pub use schema::SCHEMA_VERSION;
pub use sqlite::{
    check_location, prune_batch_rows, wal_budget, SqliteStore, PRUNE_BATCH_ROWS,
    SIZE_HIGH_WATERMARK, SIZE_LOW_WATERMARK,
};
pub use writer::{StoreStats, StoreWriter, Then, WriteResult, LOW_SPACE_BYTES};

use serde::{Deserialize, Serialize};

/// What went wrong in the store, with the file or the operation it concerns.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The database file cannot be opened, is not a database, or its schema is unusable (or
    /// the NATS server, named as such: "storage file NATS server ..." read as a file).
    #[error("storage {}{path}: {message}", if path.starts_with("NATS ") { "" } else { "file " })]
    Open {
        /// The file, or `NATS server URL`.
        path: String,
        /// What SQLite said, in words.
        message: String,
    },
    /// One operation failed (disk full, I/O error, constraint...).
    #[error("storage {operation}: {source}")]
    Sqlite {
        /// What was being done (`write`, `history`, ...).
        operation: &'static str,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// SQLite refused a write as full, with the cause named: the `max_size_mb` bound or the
    /// disk (SQLite's own message says "database or disk is full").
    #[error("storage file {path}: {operation} refused: {reason}")]
    Full {
        /// The file.
        path: String,
        /// What was being done.
        operation: &'static str,
        /// Which is full, and what to do.
        reason: String,
        /// SQLite's error (boxed: the variant carries two strings besides).
        #[source]
        source: Box<rusqlite::Error>,
    },
    /// The store's file is no longer the one it opened: deleted, moved or replaced while the
    /// daemon runs. Its writes would go to a file nobody reads again (`Store::check`).
    #[error("storage file {path}: {message}")]
    Gone {
        /// The file.
        path: String,
        /// What happened to it.
        message: String,
    },
    /// The shutdown checkpoint did not write the whole WAL back into the database file.
    #[error("storage file {path}: {message}")]
    Checkpoint {
        /// The file.
        path: String,
        /// Why, and what it means for a copy of the file.
        message: String,
    },
    /// The NATS server did not do what was asked: down, silent past the timeout, or refusing
    /// (`NatsStore`).
    #[error("storage on NATS server {url}: {operation}: {message}")]
    Nats {
        /// The server.
        url: String,
        /// What was being done (`write`, `history`, ...).
        operation: &'static str,
        /// What the client or the server said.
        message: String,
    },
    /// Another daemon owns the store's NATS prefix: its owner lease was live when this one
    /// started, or it took the prefix since (`NatsStore`: one daemon per prefix). The message
    /// names the prefix, the server, the owner's host, pid and start, and when its lease expires.
    #[error("{message}")]
    Owned {
        /// The server.
        url: String,
        /// The prefix.
        prefix: String,
        /// Who owns it, and what to do.
        message: String,
    },
    /// A stored value does not decode (a row written by a newer or broken version).
    #[error("storage {operation}: bad stored value: {message}")]
    Decode {
        /// What was being read.
        operation: &'static str,
        /// Why it does not decode.
        message: String,
    },
}

impl StoreError {
    /// Whether SQLite could not get its lock within the busy timeout (`SQLITE_BUSY`,
    /// `SQLITE_LOCKED`): another connection (another process) holds the database. Every
    /// write fails alike until it lets go, so the writer does not retry a merged write's
    /// requests one by one for it (each would wait out the busy timeout again).
    pub fn is_busy(&self) -> bool {
        match self {
            StoreError::Sqlite {
                source: rusqlite::Error::SqliteFailure(e, _),
                ..
            } => matches!(
                e.code,
                rusqlite::ErrorCode::DatabaseBusy | rusqlite::ErrorCode::DatabaseLocked
            ),
            _ => false,
        }
    }

    /// Whether the store refused the write because it is full: its size bound
    /// (`max_size_mb`) or the disk (SQLite's `SQLITE_FULL`).
    pub fn is_full(&self) -> bool {
        match self {
            StoreError::Full { .. } => true,
            StoreError::Sqlite {
                source: rusqlite::Error::SqliteFailure(e, _),
                ..
            } => e.code == rusqlite::ErrorCode::DiskFull,
            _ => false,
        }
    }
}

impl StoreError {
    /// Whether the store's file was deleted or replaced under the daemon.
    pub fn is_gone(&self) -> bool {
        matches!(self, StoreError::Gone { .. })
    }

    /// Whether another daemon owns the store's NATS prefix ([`StoreError::Owned`]).
    pub fn is_owned(&self) -> bool {
        matches!(self, StoreError::Owned { .. })
    }
}

/// One identified window of a gate, as the history keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IdentificationRecord {
    /// Gate id.
    pub gate: String,
    /// Wall-clock time of the identification, Unix seconds.
    pub time: f64,
    /// Sample time of the window's first sample, Unix seconds.
    pub window_start: f64,
    /// Sample time of the window's last sample, Unix seconds.
    pub window_end: f64,
    /// The identified equation with numbers.
    pub equation: String,
    /// Coefficients by name.
    pub coefficients: Vec<(String, f64)>,
    /// The damping report (`analysis::DampingReport`) as JSON, intervals included.
    pub damping: serde_json::Value,
    /// `damped`, `self_excited`, ... (the report's verdict).
    pub verdict: String,
    /// Fit error (normalised mean absolute error).
    pub fit_nmae: f64,
    /// Which identification path produced it: `full` (issue 9 adds `tracked`).
    pub path: String,
}

impl IdentificationRecord {
    /// The damping ratio at rest, when the report has one.
    pub fn zeta0(&self) -> Option<f64> {
        self.damping
            .get("zeta0")
            .and_then(serde_json::Value::as_f64)
    }

    /// The interval of the damping ratio at rest, when the report has one.
    pub fn zeta0_interval(&self) -> Option<(f64, f64)> {
        let v = self.damping.get("zeta0_interval")?.as_array()?;
        Some((v.first()?.as_f64()?, v.get(1)?.as_f64()?))
    }
}

/// A history query: one gate, a time range on the window end, at most `limit` rows, oldest
/// first.
#[derive(Debug, Clone, PartialEq)]
pub struct HistoryQuery {
    /// Gate id.
    pub gate: String,
    /// Inclusive lower bound on `window_end`, Unix seconds.
    pub from: Option<f64>,
    /// Inclusive upper bound on `window_end`, Unix seconds.
    pub to: Option<f64>,
    /// At most this many rows (capped at [`MAX_HISTORY_LIMIT`]).
    pub limit: usize,
}

/// A notification to persist before it is sent: one alert transition for one target.
#[derive(Debug, Clone, PartialEq)]
pub struct NewOutboxRow {
    /// The target's key (`webhook <url>` or `alertmanager <url>`).
    pub target: String,
    /// Alertmanager's fingerprint of the alert.
    pub fingerprint: String,
    /// `firing` or `resolved`.
    pub status: String,
    /// Wall-clock time of the transition, Unix seconds (the age counts from it).
    pub created: f64,
    /// Number of the batch the transition came in (delivered together when possible).
    pub batch: u64,
    /// The alert, as JSON (see `alert::notify::outbox`).
    pub payload: String,
    /// Whether this row removes the older undelivered rows of the same target and fingerprint.
    pub supersedes: bool,
}

/// A persisted, undelivered notification.
#[derive(Debug, Clone, PartialEq)]
pub struct OutboxRow {
    /// Row id: the order of the outbox, and the key to delete it by.
    pub id: i64,
    /// The row as it was written.
    pub row: NewOutboxRow,
}

/// Everything one write does, in one transaction: it all lands or none of it does.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WriteBatch {
    /// Identified windows to append to the history.
    pub identifications: Vec<IdentificationRecord>,
    /// `(gate, state as JSON)`: each gate's alert state, replacing the stored one.
    pub alert_states: Vec<(String, String)>,
    /// Gates whose alert state is deleted (removed from the configuration).
    pub forget_gates: Vec<String>,
    /// Notifications to persist (in this order; each may supersede older ones).
    pub outbox: Vec<NewOutboxRow>,
    /// Delivered (or given up) notifications to delete.
    pub delivered: Vec<i64>,
}

impl WriteBatch {
    /// Whether the batch does nothing.
    pub fn is_empty(&self) -> bool {
        self.identifications.is_empty()
            && self.alert_states.is_empty()
            && self.forget_gates.is_empty()
            && self.outbox.is_empty()
            && self.delivered.is_empty()
    }

    /// Appends `other` (order kept).
    pub fn append(&mut self, mut other: WriteBatch) {
        self.identifications.append(&mut other.identifications);
        self.alert_states.append(&mut other.alert_states);
        self.forget_gates.append(&mut other.forget_gates);
        self.outbox.append(&mut other.outbox);
        self.delivered.append(&mut other.delivered);
    }
}

/// What pruning removed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pruned {
    /// History rows older than the retention.
    pub expired: u64,
    /// Oldest history rows beyond `max_history_rows`.
    pub over_size: u64,
}

/// The seam between the daemon and its persistence. Every method is blocking: callers on the
/// async runtime go through [`StoreWriter`] (writes) or `spawn_blocking` (reads).
pub trait Store: Send + Sync + 'static {
    /// Where the store keeps its data (the file, the server), for the logs: a failed write
    /// names it.
    fn location(&self) -> String {
        "the store".to_string()
    }

    /// Whether the store is still the one that was opened: an error when its file was deleted
    /// or replaced under the daemon (an `rm gatewatch.db*` leaves SQLite writing, without an
    /// error, to a file that disappears at exit). The writer calls it before each commit and
    /// every `CHECK_INTERVAL` when idle. A store without a file has nothing to check.
    fn check(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// Bytes free to this process on the file system holding the store, when it has one
    /// (`statvfs`): the writer warns when it is nearly full ([`StoreWriter`]). `None`: no file,
    /// or the file system does not say.
    fn space_left(&self) -> Option<u64> {
        None
    }

    /// A write that changes nothing (`None`: the store has none), which the writer runs every
    /// `CHECK_INTERVAL` while writes fail: `/readyz` fails meanwhile, so the ingestion whose
    /// writes would show the store is back may stop arriving (a load balancer takes the
    /// instance out); the probe brings it back without them. It must fail wherever a real write
    /// would: the SQLite store's probe rewrites its header in place, which fits at the size
    /// bound too, so it also fails as full when no page is left under `max_page_count`.
    fn probe(&self) -> Option<Result<(), StoreError>> {
        None
    }

    /// Applies a batch in one transaction. Returns the ids given to `batch.outbox`, in order.
    fn write(&self, batch: &WriteBatch) -> Result<Vec<i64>, StoreError>;

    /// One gate's history, oldest first, as stored: the summary columns and the stored JSON
    /// (damping report, coefficients) as text, not parsed. What the HTTP route serves.
    fn history_rows(&self, query: &HistoryQuery) -> Result<Vec<HistoryRow>, StoreError>;

    /// The newest `n` rows of one gate's history (at most [`MAX_HISTORY_LIMIT`]), oldest first:
    /// what a restart rebuilds the gate's analysis memory from. SQLite takes the largest window
    /// ends; NATS the last `n` stored, read from its stream's end, which are the same for the
    /// rows a daemon writes (a gate's windows in their order).
    fn latest_history_rows(&self, gate: &str, n: usize) -> Result<Vec<HistoryRow>, StoreError>;

    /// The gates that have history, by name, at most `limit`.
    fn history_gates(&self, limit: usize) -> Result<Vec<String>, StoreError>;

    /// One gate's history, oldest first, each record's JSON parsed.
    fn history(&self, query: &HistoryQuery) -> Result<Vec<IdentificationRecord>, StoreError> {
        self.history_rows(query)?
            .into_iter()
            .map(HistoryRow::into_record)
            .collect()
    }

    /// Every gate's persisted alert state, `(gate, JSON)`.
    fn alert_states(&self) -> Result<Vec<(String, String)>, StoreError>;

    /// Every undelivered notification, oldest first.
    fn outbox(&self) -> Result<Vec<OutboxRow>, StoreError>;

    /// Deletes history rows whose window ended before `cutoff` (Unix seconds), then the oldest
    /// rows beyond `max_rows`.
    fn prune(&self, cutoff: f64, max_rows: u64) -> Result<Pruned, StoreError>;

    /// The size bound: when the store is above its high watermark (or `force`, after a write
    /// refused as full), deletes the oldest history, in batches, until it is below its low
    /// watermark. Alert state and outbox are never deleted. Returns the rows deleted. A store
    /// without a size bound does nothing.
    fn make_room(&self, force: bool) -> Result<u64, StoreError> {
        let _ = force;
        Ok(0)
    }
}

#[cfg(test)]
mod tests;
