//! [`SqliteStore`]: the embedded store, one SQLite file in WAL mode. The schema and its
//! migrations are in `schema`.
//!
//! The size bound (`max_size_mb`) is kept by pruning, not by failing: SQLite's
//! `max_page_count` is set to the bound, and after each commit the writer thread calls
//! [`Store::make_room`], which deletes the oldest history when the pages in use pass
//! [`SIZE_HIGH_WATERMARK`] of the bound, until they are under [`SIZE_LOW_WATERMARK`]. The
//! pages freed are reused by the next rows, so the file stops growing there. A write refused
//! as full all the same (one transaction larger than the margin, a full disk) makes room and
//! is retried once (`writer`).

use std::path::Path;
use std::sync::Mutex;

use rusqlite::{params, Connection, OpenFlags};

use super::row::{compact_damping, HistoryRow, Summary};
use super::schema::{insert_row, migrate, NewRow, SCHEMA_VERSION};
use super::{
    HistoryQuery, IdentificationRecord, NewOutboxRow, OutboxRow, Pruned, Store, StoreError,
    WriteBatch, MAX_HISTORY_LIMIT,
};

/// Page size of a new file. 8 KiB rather than SQLite's 4 KiB: the history is a `WITHOUT ROWID`
/// table, whose rows stay on their page only up to about a quarter of it (2 030 bytes here,
/// 1 002 with 4 KiB pages), and a stored identification is about 800 bytes; an old file keeps
/// its 4 KiB pages (changing them needs a `VACUUM`, a copy of the whole file).
const PAGE_SIZE: u32 = 8192;

/// The size bound starts pruning when the pages in use pass this fraction of `max_size_mb`...
pub const SIZE_HIGH_WATERMARK: f64 = 0.9;

/// ...and prunes until they are under this fraction. The gap (10 % of the bound) is what one
/// pruning frees, so it does not run at every commit; the margin above the high mark is room
/// for the writes between two checks (one merged transaction: at most 256 requests).
pub const SIZE_LOW_WATERMARK: f64 = 0.8;

/// History rows deleted by one pruning transaction: the writer thread does not hold one
/// transaction long (the history route reads meanwhile, WAL), and each batch frees pages.
pub const PRUNE_BATCH_ROWS: u64 = 2000;

/// How long a statement waits for a lock held by another connection (the daemon's writer, a
/// `gatewatch history` reader) before failing.
const BUSY_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// The embedded store. Two connections: writes are serialised on one, reads on the other, so a
/// long history query never waits for a write to finish (WAL lets them run at once).
#[derive(Debug)]
pub struct SqliteStore {
    path: String,
    write: Mutex<Connection>,
    read: Mutex<Connection>,
    /// The size bound in bytes (`max_size_mb`); `None` read-only.
    max_bytes: Option<u64>,
}

fn lock(m: &Mutex<Connection>) -> std::sync::MutexGuard<'_, Connection> {
    // A panic under the lock cannot leave a connection half-used: rusqlite rolls back an
    // unfinished transaction when it is dropped.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn sq(operation: &'static str) -> impl FnOnce(rusqlite::Error) -> StoreError {
    move |source| StoreError::Sqlite { operation, source }
}

impl SqliteStore {
    /// Opens (creating it if needed) the database at `path` for the daemon: WAL mode, schema
    /// migrated, writable, at most `max_size_mb` MiB. Fails with an error naming the file when
    /// it is not a database, is from a newer version, or cannot be written.
    pub fn open(path: &Path, max_size_mb: u64) -> Result<SqliteStore, StoreError> {
        let name = path.display().to_string();
        let open_err = |e: rusqlite::Error| StoreError::Open {
            path: name.clone(),
            message: e.to_string(),
        };
        if path.is_dir() {
            return Err(StoreError::Open {
                path: name,
                message: "is a directory".into(),
            });
        }
        let mut write = Connection::open(path).map_err(open_err)?;
        if write.is_readonly(rusqlite::MAIN_DB).map_err(open_err)? {
            return Err(StoreError::Open {
                path: name,
                message: "is not writable".into(),
            });
        }
        write.busy_timeout(BUSY_TIMEOUT).map_err(open_err)?;
        // before WAL: a page size can only be chosen for a new, empty file (a no-op otherwise)
        write
            .execute_batch(&format!("PRAGMA page_size = {PAGE_SIZE}"))
            .map_err(open_err)?;
        // WAL: readers (the history route, `gatewatch history` in another process) never block
        // the writer. synchronous=FULL: a committed transition survives a power cut, not only a
        // crash of the process; at a few commits a second the fsync costs nothing that matters.
        let mode: String = write
            .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))
            .map_err(open_err)?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(StoreError::Open {
                path: name,
                message: format!("cannot use WAL mode (journal mode is {mode})"),
            });
        }
        write
            .execute_batch("PRAGMA synchronous = FULL; PRAGMA foreign_keys = ON;")
            .map_err(open_err)?;
        migrate(&mut write).map_err(|message| StoreError::Open {
            path: name.clone(),
            message,
        })?;
        let page_size: u64 = write
            .query_row("PRAGMA page_size", [], |r| r.get::<_, i64>(0))
            .map_err(open_err)?
            .max(512) as u64;
        let pages = max_size_mb.saturating_mul(1024 * 1024) / page_size;
        write
            .query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))
            .map_err(open_err)?;
        let read = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(open_err)?;
        read.busy_timeout(BUSY_TIMEOUT).map_err(open_err)?;
        Ok(SqliteStore {
            path: name,
            write: Mutex::new(write),
            read: Mutex::new(read),
            max_bytes: Some(pages * page_size),
        })
    }

    /// Opens an existing database read-only (`gatewatch history`), also while the daemon
    /// writes to it. Nothing is created or migrated; a file of another schema version is
    /// refused.
    pub fn open_read_only(path: &Path) -> Result<SqliteStore, StoreError> {
        let name = path.display().to_string();
        let open_err = |e: rusqlite::Error| StoreError::Open {
            path: name.clone(),
            message: e.to_string(),
        };
        if !path.is_file() {
            return Err(StoreError::Open {
                path: name,
                message: "no such file".into(),
            });
        }
        let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let open = || -> Result<Connection, StoreError> {
            let c = Connection::open_with_flags(path, flags).map_err(open_err)?;
            c.busy_timeout(BUSY_TIMEOUT).map_err(open_err)?;
            Ok(c)
        };
        let read = open()?;
        let version: i64 = read
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(open_err)?;
        if version != SCHEMA_VERSION {
            return Err(StoreError::Open {
                path: name.clone(),
                message: format!(
                    "schema version {version}, this gatewatch reads version {SCHEMA_VERSION}"
                ),
            });
        }
        let write = open()?;
        Ok(SqliteStore {
            path: name,
            write: Mutex::new(write),
            read: Mutex::new(read),
            max_bytes: None,
        })
    }

    /// The file.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Size of the database in bytes (pages in use, free pages included; WAL not counted).
    pub fn size_bytes(&self) -> Result<u64, StoreError> {
        let c = lock(&self.read);
        let count: i64 = c
            .query_row("PRAGMA page_count", [], |r| r.get(0))
            .map_err(sq("size"))?;
        let size: i64 = c
            .query_row("PRAGMA page_size", [], |r| r.get(0))
            .map_err(sq("size"))?;
        Ok((count.max(0) as u64) * (size.max(0) as u64))
    }

    /// The gates that have at least one identification, sorted (for `gatewatch history`'s
    /// "unknown gate" message). A skip through the table's key, which starts with the gate.
    pub fn gates(&self) -> Result<Vec<String>, StoreError> {
        let c = lock(&self.read);
        let mut stmt = c
            .prepare("SELECT DISTINCT gate FROM history ORDER BY gate")
            .map_err(sq("list of the gates"))?;
        let rows = stmt
            .query_map([], |r| r.get(0))
            .map_err(sq("list of the gates"))?;
        rows.collect::<Result<_, _>>()
            .map_err(sq("list of the gates"))
    }

    /// Writes the WAL back into the database file (`PRAGMA wal_checkpoint(TRUNCATE)`), so a
    /// copy of the `.db` file alone is complete. Called at shutdown.
    pub fn checkpoint(&self) -> Result<(), StoreError> {
        lock(&self.write)
            .query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()))
            .map_err(sq("checkpoint"))
    }
}

fn insert_identification(
    tx: &rusqlite::Transaction<'_>,
    r: &IdentificationRecord,
) -> rusqlite::Result<()> {
    let coefficients = serde_json::to_string(&r.coefficients).unwrap_or_else(|_| "[]".into());
    let damping = compact_damping(&r.damping);
    insert_row(
        tx,
        &NewRow {
            gate: &r.gate,
            window_end: r.window_end,
            time: r.time,
            window_start: r.window_start,
            summary: Summary::of(&damping),
            verdict: &r.verdict,
            fit_nmae: r.fit_nmae,
            path: &r.path,
            equation: &r.equation,
            coefficients: &coefficients,
            damping: &damping.to_string(),
        },
        None,
    )
}

/// Pages in use (the file's pages less the free ones), in bytes.
fn used_bytes(c: &Connection) -> rusqlite::Result<u64> {
    let pages: i64 = c.query_row("PRAGMA page_count", [], |r| r.get(0))?;
    let free: i64 = c.query_row("PRAGMA freelist_count", [], |r| r.get(0))?;
    let size: i64 = c.query_row("PRAGMA page_size", [], |r| r.get(0))?;
    Ok((pages - free).max(0) as u64 * size.max(0) as u64)
}

/// Deletes the oldest `n` history rows (by window end, across gates) in one transaction.
fn delete_oldest(c: &mut Connection, n: u64) -> rusqlite::Result<u64> {
    let tx = c.transaction()?;
    let deleted = tx.execute(
        "DELETE FROM history WHERE (gate, window_end, seq) IN (
            SELECT gate, window_end, seq FROM history ORDER BY window_end LIMIT ?1)",
        params![n.min(i64::MAX as u64) as i64],
    )? as u64;
    tx.commit()?;
    Ok(deleted)
}

fn insert_outbox(tx: &rusqlite::Transaction<'_>, r: &NewOutboxRow) -> rusqlite::Result<i64> {
    if r.supersedes {
        tx.prepare_cached("DELETE FROM outbox WHERE target = ?1 AND fingerprint = ?2")?
            .execute(params![r.target, r.fingerprint])?;
    }
    tx.prepare_cached(
        "INSERT INTO outbox (target, fingerprint, status, created, batch, payload)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
    )?
    .execute(params![
        r.target,
        r.fingerprint,
        r.status,
        r.created,
        r.batch as i64,
        r.payload
    ])?;
    Ok(tx.last_insert_rowid())
}

/// The columns of a [`HistoryRow`], in the order [`history_row`] reads them.
const HISTORY_COLUMNS: &str = "gate, time, window_start, window_end, equation, coefficients, \
     damping, verdict, fit_nmae, path, zeta0, zeta0_low, zeta0_high, frequency_hz, trusted";

/// A [`HistoryRow`] from a row of [`HISTORY_COLUMNS`].
fn history_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<HistoryRow> {
    let low: Option<f64> = r.get(11)?;
    let high: Option<f64> = r.get(12)?;
    Ok(HistoryRow {
        gate: r.get(0)?,
        time: r.get(1)?,
        window_start: r.get(2)?,
        window_end: r.get(3)?,
        equation: r.get(4)?,
        coefficients: r.get(5)?,
        damping: r.get(6)?,
        verdict: r.get(7)?,
        fit_nmae: r.get(8)?,
        path: r.get(9)?,
        zeta0: r.get(10)?,
        zeta0_interval: low.zip(high),
        frequency_hz: r.get(13)?,
        trusted: r.get(14)?,
    })
}

impl Store for SqliteStore {
    fn location(&self) -> String {
        self.path.clone()
    }

    fn write(&self, batch: &WriteBatch) -> Result<Vec<i64>, StoreError> {
        let mut c = lock(&self.write);
        let tx = c.transaction().map_err(sq("write"))?;
        for r in &batch.identifications {
            insert_identification(&tx, r).map_err(sq("write of the history"))?;
        }
        for (gate, state) in &batch.alert_states {
            tx.prepare_cached(
                "INSERT INTO alert_state (gate, state) VALUES (?1, ?2)
                 ON CONFLICT (gate) DO UPDATE SET state = excluded.state",
            )
            .and_then(|mut s| s.execute(params![gate, state]))
            .map_err(sq("write of the alert state"))?;
        }
        for gate in &batch.forget_gates {
            tx.prepare_cached("DELETE FROM alert_state WHERE gate = ?1")
                .and_then(|mut s| s.execute(params![gate]))
                .map_err(sq("write of the alert state"))?;
        }
        let mut ids = Vec::with_capacity(batch.outbox.len());
        for r in &batch.outbox {
            ids.push(insert_outbox(&tx, r).map_err(sq("write of the outbox"))?);
        }
        for id in &batch.delivered {
            tx.prepare_cached("DELETE FROM outbox WHERE id = ?1")
                .and_then(|mut s| s.execute(params![id]))
                .map_err(sq("write of the outbox"))?;
        }
        tx.commit().map_err(sq("commit"))?;
        Ok(ids)
    }

    fn history_rows(&self, q: &HistoryQuery) -> Result<Vec<HistoryRow>, StoreError> {
        let c = lock(&self.read);
        // one range of the table's key (gate, window_end): the gate's rows are together
        let mut stmt = c
            .prepare_cached(&format!(
                "SELECT {HISTORY_COLUMNS} FROM history
                 WHERE gate = ?1 AND window_end >= ?2 AND window_end <= ?3
                 ORDER BY window_end, seq LIMIT ?4"
            ))
            .map_err(sq("history"))?;
        let limit = q.limit.min(MAX_HISTORY_LIMIT) as i64;
        let rows = stmt
            .query_map(
                params![
                    q.gate,
                    q.from.unwrap_or(f64::MIN),
                    q.to.unwrap_or(f64::MAX),
                    limit
                ],
                history_row,
            )
            .map_err(sq("history"))?;
        rows.collect::<Result<_, _>>().map_err(sq("history"))
    }

    fn latest_history_rows(&self, gate: &str, n: usize) -> Result<Vec<HistoryRow>, StoreError> {
        let c = lock(&self.read);
        // the same range of the key, read from its end
        let mut stmt = c
            .prepare_cached(&format!(
                "SELECT {HISTORY_COLUMNS} FROM history WHERE gate = ?1
                 ORDER BY window_end DESC, seq DESC LIMIT ?2"
            ))
            .map_err(sq("latest history"))?;
        let limit = n.min(MAX_HISTORY_LIMIT) as i64;
        let rows = stmt
            .query_map(params![gate, limit], history_row)
            .map_err(sq("latest history"))?;
        let mut rows: Vec<HistoryRow> = rows
            .collect::<Result<_, _>>()
            .map_err(sq("latest history"))?;
        rows.reverse();
        Ok(rows)
    }

    fn history_gates(&self, limit: usize) -> Result<Vec<String>, StoreError> {
        let c = lock(&self.read);
        // a loose scan of the key (gate, window_end, seq): one lookup per gate, where DISTINCT
        // reads the whole table
        let mut stmt = c
            .prepare_cached(
                "WITH RECURSIVE g(name) AS (
                     SELECT min(gate) FROM history
                     UNION ALL
                     SELECT (SELECT min(gate) FROM history WHERE gate > g.name)
                     FROM g WHERE g.name IS NOT NULL
                 )
                 SELECT name FROM g WHERE name IS NOT NULL LIMIT ?1",
            )
            .map_err(sq("history gates"))?;
        let rows = stmt
            .query_map(params![limit.min(i64::MAX as usize) as i64], |r| r.get(0))
            .map_err(sq("history gates"))?;
        rows.collect::<Result<_, _>>().map_err(sq("history gates"))
    }

    fn alert_states(&self) -> Result<Vec<(String, String)>, StoreError> {
        let c = lock(&self.read);
        let mut stmt = c
            .prepare("SELECT gate, state FROM alert_state ORDER BY gate")
            .map_err(sq("read of the alert states"))?;
        let rows = stmt
            .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(sq("read of the alert states"))?;
        rows.collect::<Result<_, _>>()
            .map_err(sq("read of the alert states"))
    }

    fn outbox(&self) -> Result<Vec<OutboxRow>, StoreError> {
        let c = lock(&self.read);
        let mut stmt = c
            .prepare(
                "SELECT id, target, fingerprint, status, created, batch, payload
                 FROM outbox ORDER BY id",
            )
            .map_err(sq("read of the outbox"))?;
        let rows = stmt
            .query_map([], |r| {
                Ok(OutboxRow {
                    id: r.get(0)?,
                    row: NewOutboxRow {
                        target: r.get(1)?,
                        fingerprint: r.get(2)?,
                        status: r.get(3)?,
                        created: r.get(4)?,
                        batch: r.get::<_, i64>(5)?.max(0) as u64,
                        payload: r.get(6)?,
                        supersedes: false,
                    },
                })
            })
            .map_err(sq("read of the outbox"))?;
        rows.collect::<Result<_, _>>()
            .map_err(sq("read of the outbox"))
    }

    fn prune(&self, cutoff: f64, max_rows: u64) -> Result<Pruned, StoreError> {
        let mut c = lock(&self.write);
        let expired = {
            let tx = c.transaction().map_err(sq("prune"))?;
            let n = tx
                .execute("DELETE FROM history WHERE window_end < ?1", params![cutoff])
                .map_err(sq("prune"))? as u64;
            tx.commit().map_err(sq("prune"))?;
            n
        };
        let count: i64 = c
            .query_row("SELECT count(*) FROM history", [], |r| r.get(0))
            .map_err(sq("prune"))?;
        let mut excess = (count.max(0) as u64).saturating_sub(max_rows);
        let mut over_size = 0;
        // the oldest by window end, through the window_end index, in batches
        while excess > 0 {
            let n = delete_oldest(&mut c, excess.min(PRUNE_BATCH_ROWS)).map_err(sq("prune"))?;
            if n == 0 {
                break;
            }
            over_size += n;
            excess = excess.saturating_sub(n);
        }
        Ok(Pruned { expired, over_size })
    }

    fn make_room(&self, force: bool) -> Result<u64, StoreError> {
        let Some(max) = self.max_bytes else {
            return Ok(0);
        };
        let high = (max as f64 * SIZE_HIGH_WATERMARK) as u64;
        let low = (max as f64 * SIZE_LOW_WATERMARK) as u64;
        let mut c = lock(&self.write);
        let mut used = used_bytes(&c).map_err(sq("size bound"))?;
        if used <= high && !force {
            return Ok(0);
        }
        let mut deleted = 0;
        // forced (a write was refused as full): at least one batch, even under the low mark
        let mut first = force;
        while used > low || first {
            first = false;
            let n = delete_oldest(&mut c, PRUNE_BATCH_ROWS).map_err(sq("size bound"))?;
            if n == 0 {
                break; // no history left: the rest is alert state and outbox, never pruned
            }
            deleted += n;
            used = used_bytes(&c).map_err(sq("size bound"))?;
        }
        Ok(deleted)
    }
}
