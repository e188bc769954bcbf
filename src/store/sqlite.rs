//! [`SqliteStore`]: the embedded store, one SQLite file in WAL mode.
//!
//! Migrations are versioned in code with SQLite's own `PRAGMA user_version` (a header field of
//! the file made for this): [`MIGRATIONS`] is a list of SQL scripts, the file's version is the
//! number applied, and each script runs in the same transaction as the version bump. That is
//! what `rusqlite_migration` does too; doing it in twenty lines avoids a crate that pins our
//! rusqlite version. A file from a newer gatewatch (version above ours) is refused rather than
//! written in a schema we do not know.

use std::path::Path;
use std::sync::Mutex;

use rusqlite::{params, Connection, OpenFlags};

use super::{
    HistoryQuery, IdentificationRecord, NewOutboxRow, OutboxRow, Pruned, Store, StoreError,
    WriteBatch, MAX_HISTORY_LIMIT,
};

/// The schema scripts, in order; the file's `user_version` counts those applied.
const MIGRATIONS: &[&str] = &[
    // 1: history, alert state, outbox.
    "CREATE TABLE identifications (
        id INTEGER PRIMARY KEY,
        gate TEXT NOT NULL,
        time REAL NOT NULL,
        window_start REAL NOT NULL,
        window_end REAL NOT NULL,
        equation TEXT NOT NULL,
        coefficients TEXT NOT NULL,
        damping TEXT NOT NULL,
        verdict TEXT NOT NULL,
        fit_nmae REAL NOT NULL,
        path TEXT NOT NULL
    );
    CREATE INDEX identifications_gate_end ON identifications (gate, window_end);
    CREATE INDEX identifications_end ON identifications (window_end);
    CREATE TABLE alert_state (
        gate TEXT PRIMARY KEY,
        state TEXT NOT NULL
    );
    -- AUTOINCREMENT: ids never reused, so the id order is the order of the transitions even
    -- after deletions.
    CREATE TABLE outbox (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        target TEXT NOT NULL,
        fingerprint TEXT NOT NULL,
        status TEXT NOT NULL,
        created REAL NOT NULL,
        batch INTEGER NOT NULL,
        payload TEXT NOT NULL
    );
    CREATE INDEX outbox_target_fingerprint ON outbox (target, fingerprint);",
];

/// The schema version this build writes (the number of [`MIGRATIONS`]).
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

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
    /// "unknown gate" message). A scan of the `(gate, window_end)` index.
    pub fn gates(&self) -> Result<Vec<String>, StoreError> {
        let c = lock(&self.read);
        let mut stmt = c
            .prepare("SELECT DISTINCT gate FROM identifications ORDER BY gate")
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

/// Brings the schema to [`SCHEMA_VERSION`]; the message says why it cannot.
fn migrate(c: &mut Connection) -> Result<(), String> {
    let version: i64 = c
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .map_err(|e| e.to_string())?;
    if version > SCHEMA_VERSION {
        return Err(format!(
            "schema version {version} is newer than this gatewatch's ({SCHEMA_VERSION}): \
             written by a newer release"
        ));
    }
    for (i, script) in MIGRATIONS.iter().enumerate().skip(version.max(0) as usize) {
        let to = i + 1;
        let tx = c.transaction().map_err(|e| e.to_string())?;
        tx.execute_batch(script)
            .and_then(|()| tx.execute_batch(&format!("PRAGMA user_version = {to}")))
            .and_then(|()| tx.commit())
            .map_err(|e| format!("migration to schema version {to}: {e}"))?;
    }
    Ok(())
}

fn insert_identification(
    tx: &rusqlite::Transaction<'_>,
    r: &IdentificationRecord,
) -> rusqlite::Result<()> {
    let coefficients = serde_json::to_string(&r.coefficients).unwrap_or_else(|_| "[]".into());
    tx.prepare_cached(
        "INSERT INTO identifications (gate, time, window_start, window_end, equation,
            coefficients, damping, verdict, fit_nmae, path)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
    )?
    .execute(params![
        r.gate,
        r.time,
        r.window_start,
        r.window_end,
        r.equation,
        coefficients,
        r.damping.to_string(),
        r.verdict,
        r.fit_nmae,
        r.path,
    ])?;
    Ok(())
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

    fn history(&self, q: &HistoryQuery) -> Result<Vec<IdentificationRecord>, StoreError> {
        let c = lock(&self.read);
        let mut stmt = c
            .prepare_cached(
                "SELECT gate, time, window_start, window_end, equation, coefficients, damping,
                    verdict, fit_nmae, path
                 FROM identifications
                 WHERE gate = ?1 AND window_end >= ?2 AND window_end <= ?3
                 ORDER BY window_end, id LIMIT ?4",
            )
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
                |r| {
                    Ok((
                        r.get::<_, String>(0)?,
                        r.get::<_, f64>(1)?,
                        r.get::<_, f64>(2)?,
                        r.get::<_, f64>(3)?,
                        r.get::<_, String>(4)?,
                        r.get::<_, String>(5)?,
                        r.get::<_, String>(6)?,
                        r.get::<_, String>(7)?,
                        r.get::<_, f64>(8)?,
                        r.get::<_, String>(9)?,
                    ))
                },
            )
            .map_err(sq("history"))?;
        let mut out = Vec::new();
        for row in rows {
            let (gate, time, ws, we, equation, coef, damping, verdict, fit, path) =
                row.map_err(sq("history"))?;
            let decode = |what: &str, e: serde_json::Error| StoreError::Decode {
                operation: "history",
                message: format!("{what} of gate {gate} at {we}: {e}"),
            };
            out.push(IdentificationRecord {
                coefficients: serde_json::from_str(&coef).map_err(|e| decode("coefficients", e))?,
                damping: serde_json::from_str(&damping).map_err(|e| decode("damping", e))?,
                gate,
                time,
                window_start: ws,
                window_end: we,
                equation,
                verdict,
                fit_nmae: fit,
                path,
            });
        }
        Ok(out)
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
        let tx = c.transaction().map_err(sq("prune"))?;
        let expired = tx
            .execute(
                "DELETE FROM identifications WHERE window_end < ?1",
                params![cutoff],
            )
            .map_err(sq("prune"))? as u64;
        let count: i64 = tx
            .query_row("SELECT count(*) FROM identifications", [], |r| r.get(0))
            .map_err(sq("prune"))?;
        let excess = (count.max(0) as u64).saturating_sub(max_rows);
        // the oldest by window end, through the window_end index
        let over_size = tx
            .execute(
                "DELETE FROM identifications WHERE id IN (
                    SELECT id FROM identifications ORDER BY window_end, id LIMIT ?1)",
                params![excess.min(i64::MAX as u64) as i64],
            )
            .map_err(sq("prune"))? as u64;
        tx.commit().map_err(sq("prune"))?;
        Ok(Pruned { expired, over_size })
    }
}
