//! `[storage]`: where the store lives and how much it keeps.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::{nats_lease_renew_interval, NATS_LEASE_RENEWALS_PER_TTL, NATS_OPERATION_TIMEOUT};

/// Capacity of the writer thread's queue, in write requests. One identification or one alert
/// transition is one request; 4096 is minutes of 16 gates at a window a second, far more than
/// a healthy disk ever lets pile up. When it is full the write is dropped, counted
/// (`gatewatch_store_write_errors_total{reason="queue_full"}`) and logged: ingestion and alert
/// delivery go on from memory.
pub const STORE_QUEUE_CAPACITY: usize = 4096;

/// Largest `limit` of one history query (HTTP and CLI): one day of one gate at a window every
/// 5 s is 17 280 rows, so a day always fits; a longer range is paged with `from`.
pub const MAX_HISTORY_LIMIT: usize = 20_000;

/// Below this `max_size_mb`, `check-config` and `serve` warn. Why 16 MiB: the margin between
/// the pruning's high watermark and the bound (10 %) must hold the writes between two checks
/// (one merged transaction: up to 256 requests, about 0.3 MiB of history) and the WAL's
/// budget (5 % of the bound); at 16 MiB that is 1.6 MiB, five such transactions, and the store
/// keeps most of a gate-day (20 MiB at a window every 5 s). A smaller bound works (the tests
/// use 1 MiB to meet SQLite's real "full"), but a burst can fail writes and the history is
/// minutes long: a warning, not a refusal.
pub const MIN_USEFUL_SIZE_MB: u64 = 16;

/// Which store the daemon keeps its state in (`storage.backend`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StorageBackend {
    /// One SQLite file (`storage.path`), for one daemon.
    #[default]
    Sqlite,
    /// JetStream streams on a NATS server (`storage.nats_url`), one daemon per prefix
    /// (`docs/design.md`, "The NATS store").
    Nats,
}

/// `[storage]` in the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StorageConfig {
    /// `sqlite` (default): one file, `path`; `nats`: JetStream streams on the server at
    /// `nats_url`, named with `nats_prefix` (`docs/design.md`, "The NATS store").
    pub backend: StorageBackend,
    /// The NATS server of the `nats` backend (default `nats://127.0.0.1:4222`).
    pub nats_url: String,
    /// Prefix of the `nats` backend's streams and subjects (default `GATEWATCH`: streams
    /// `GATEWATCH_HISTORY`, `GATEWATCH_ALERTS`, `GATEWATCH_OUTBOX`); letters, digits, `-` and
    /// `_`. One daemon per prefix: `serve` takes the prefix's owner lease and a second daemon
    /// on it is refused at start (`docs/design.md`, "The owner lease").
    pub nats_prefix: String,
    /// How long the `nats` backend's owner lease lasts without renewal, in seconds (default
    /// 30, `store::NATS_LEASE_TTL`; renewed every third of it): how long a prefix stays refused
    /// after its daemon was killed without releasing it. At least 1.
    pub nats_lease_seconds: f64,
    /// The SQLite file (default `gatewatch.db`). A relative path is taken relative to the
    /// directory of the configuration file (the working directory without one), like
    /// Prometheus does. Its directory must exist and be writable (the WAL and shared-memory
    /// files sit next to it).
    pub path: String,
    /// History older than this is deleted (default 30 days).
    pub retention_days: f64,
    /// Bound on the history: beyond this many rows the oldest are deleted (default
    /// 10 000 000; 30 days of 16 gates at a window every 5 s are 8.3 million, so the retention
    /// binds first: docs/operations.md, "Size").
    pub max_history_rows: u64,
    /// Bound on the database file, in MiB (default 12288). Past 90 % of it the oldest history
    /// is pruned down to 80 % (`Store::make_room`, counted in
    /// `gatewatch_store_pruned_rows_total{reason="size"}`); SQLite's `max_page_count` is the
    /// hard stop, reached only when alert state and outbox alone fill it: then a write fails
    /// like a full disk, counted (`gatewatch_store_write_errors_total{reason="failed"}`) and
    /// logged, and ingestion goes on. A row is about 1 225 bytes of file (docs/benchmarks.md,
    /// "History"): 30 days of 16 gates are about 9.5 GiB.
    pub max_size_mb: u64,
    /// A notification is retried for as long as it is younger than this, then given up,
    /// counted and logged (default 86400 s = 24 h).
    pub notification_max_age_seconds: f64,
    /// At start, rebuild each gate's analysis memory (the trend of zeta0, the ambient level, the
    /// tracking model) from its latest stored windows (default true; `service::resume`,
    /// docs/operations.md, "Restarts"). False: every gate starts afresh, as without a store.
    pub resume_analysis: bool,
}

impl Default for StorageConfig {
    fn default() -> Self {
        StorageConfig {
            backend: StorageBackend::Sqlite,
            nats_url: "nats://127.0.0.1:4222".to_string(),
            nats_prefix: "GATEWATCH".to_string(),
            nats_lease_seconds: super::NATS_LEASE_TTL.as_secs_f64(),
            path: "gatewatch.db".to_string(),
            retention_days: 30.0,
            max_history_rows: 10_000_000,
            max_size_mb: 12_288,
            notification_max_age_seconds: 86_400.0,
            resume_analysis: true,
        }
    }
}

impl StorageConfig {
    /// Checks the values; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self.path.trim().is_empty() {
            return Err("storage.path: must not be empty".into());
        }
        let url = self.nats_url.trim();
        if url.is_empty() || url.contains(char::is_whitespace) {
            return Err(format!(
                "storage.nats_url: {:?} is not a server URL (e.g. nats://127.0.0.1:4222)",
                self.nats_url
            ));
        }
        if !super::valid_nats_prefix(&self.nats_prefix) {
            return Err(format!(
                "storage.nats_prefix: {:?}: letters, digits, '-' and '_' only, not empty",
                self.nats_prefix
            ));
        }
        if !(self.nats_lease_seconds.is_finite() && self.nats_lease_seconds >= 1.0) {
            return Err(format!(
                "storage.nats_lease_seconds: {} must be at least 1 (seconds)",
                crate::number::Num(self.nats_lease_seconds)
            ));
        }
        if !(self.retention_days.is_finite() && self.retention_days > 0.0) {
            return Err("storage.retention_days: must be > 0".into());
        }
        if self.max_history_rows == 0 {
            return Err("storage.max_history_rows: must be > 0".into());
        }
        if self.max_size_mb == 0 {
            return Err("storage.max_size_mb: must be > 0".into());
        }
        if !(self.notification_max_age_seconds.is_finite()
            && self.notification_max_age_seconds > 0.0)
        {
            return Err("storage.notification_max_age_seconds: must be > 0".into());
        }
        Ok(())
    }

    /// What is valid but probably not meant, one line each naming the key.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.max_size_mb < MIN_USEFUL_SIZE_MB {
            out.push(format!(
                "storage.max_size_mb = {} is below {MIN_USEFUL_SIZE_MB}: a burst of writes can \
                 outrun the pruning (writes fail as full) and the store keeps little history \
                 (about {} rows); docs/operations.md, \"Size\"",
                self.max_size_mb,
                self.max_size_mb * 1024 * 1024 * 8 / 10 / super::sqlite::ROW_BYTES
            ));
        }
        if let Some(w) = self.short_lease_warning() {
            out.push(w);
        }
        out
    }

    /// The NATS owner lease is renewed every TTL / [`NATS_LEASE_RENEWALS_PER_TTL`], and each
    /// renewal is given up after that interval or the store's operation timeout
    /// ([`NATS_OPERATION_TIMEOUT`], 10 s), the shorter (`store::nats` `lease::keep`). Below
    /// TTL = 3 x 10 s the interval is the shorter: a server that answers within the operation
    /// timeout, as every other store call may, but slower than TTL / 3 fails every renewal, and
    /// the lease expires after TTL (writes refused, the prefix open to another daemon). From
    /// 30 s on a renewal gets the whole operation timeout, and two in a row that each take all
    /// of it still land before the lease expires: the last one stored expires at its start plus
    /// TTL; the next starts at most 10 s + TTL / 3 later and lands at most 10 s after that,
    /// and 20 s + TTL / 3 <= TTL exactly when TTL >= 30 s. Only with `backend = "nats"`.
    fn short_lease_warning(&self) -> Option<String> {
        if self.backend != StorageBackend::Nats {
            return None;
        }
        // the condition as `lease::keep` has it: the renewal's own bound is the shorter
        if nats_lease_renew_interval(self.nats_lease()) >= NATS_OPERATION_TIMEOUT {
            return None;
        }
        let timeout = NATS_OPERATION_TIMEOUT.as_secs_f64();
        let per_ttl = f64::from(NATS_LEASE_RENEWALS_PER_TTL);
        let enough = per_ttl * timeout;
        let ttl = self.nats_lease_seconds;
        Some(format!(
                "storage.nats_lease_seconds = {ttl} is below {enough} ({NATS_LEASE_RENEWALS_PER_TTL} x \
                 the NATS operation timeout of {timeout} s): the owner lease is renewed every \
                 {every:.1} s (a third of it) and a renewal slower than that is given up, so a \
                 server that answers within the operation timeout but slower than {every:.1} s \
                 lets the lease expire: writes are refused until a renewal gets through, and \
                 another daemon may take the prefix meanwhile; from {enough} s on two renewals \
                 in a row that each take the whole timeout still land before it expires",
            every = ttl / per_ttl
        ))
    }

    /// The retention as a duration.
    pub fn retention(&self) -> Duration {
        Duration::try_from_secs_f64(self.retention_days * 86_400.0).unwrap_or(Duration::MAX)
    }

    /// The NATS owner lease's time to live as a duration.
    pub fn nats_lease(&self) -> Duration {
        Duration::try_from_secs_f64(self.nats_lease_seconds).unwrap_or(super::NATS_LEASE_TTL)
    }

    /// The notifications' maximum age as a duration.
    pub fn notification_max_age(&self) -> Duration {
        Duration::try_from_secs_f64(self.notification_max_age_seconds).unwrap_or(Duration::MAX)
    }

    /// The file, a relative `path` resolved against `base` (the configuration file's
    /// directory).
    pub fn resolve(&self, base: Option<&Path>) -> PathBuf {
        let p = PathBuf::from(&self.path);
        match base {
            Some(dir) if p.is_relative() => dir.join(p),
            _ => p,
        }
    }
}
