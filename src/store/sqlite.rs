//! [`SqliteStore`]: the embedded store, one SQLite file in WAL mode. The schema and its
//! migrations are in `schema`.
//!
//! The size bound (`max_size_mb`) is kept by pruning, not by failing: SQLite's
//! `max_page_count` is set to the bound, and after each commit the writer thread calls
//! [`Store::make_room`], which deletes the oldest history when the pages in use plus the WAL
//! file pass [`SIZE_HIGH_WATERMARK`] of the bound, until they are under [`SIZE_LOW_WATERMARK`],
//! [`prune_batch_rows`] rows (about 1 % of the bound) at a time. The pages freed are reused by
//! the next rows, so the file stops growing there. A write refused as full all the same (one
//! transaction larger than the margin, a full disk) makes room and is retried once (`writer`).
//!
//! The WAL is bounded too ([`wal_budget`]): SQLite's default checkpoints it every 1 000 pages
//! (8 MiB here) and never shrinks the file, which alone was three times a 3 MiB bound; the
//! store checkpoints it at a twentieth of the bound (at most SQLite's 1 000 pages) and
//! truncates it back to its budget (`journal_size_limit`).

use std::fs::File;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rusqlite::{params, Connection, OpenFlags};

use super::file::{immutable_uri, quick_check, real_path, refuse_hard_links, take_lock};
use super::row::{compact_damping, HistoryRow, Summary};
use super::schema::{insert_row, migrate, NewRow, SCHEMA_VERSION};
use super::{
    HistoryQuery, IdentificationRecord, NewOutboxRow, OutboxRow, Pruned, Store, StoreError,
    WriteBatch, MAX_HISTORY_LIMIT,
};

/// Page size of a new file. 16 KiB rather than SQLite's 4 KiB: the history is a `WITHOUT ROWID`
/// table, whose rows stay on their page only up to about a quarter of it (4 086 bytes here,
/// 2 030 with 8 KiB pages, 1 002 with 4 KiB); a row that does not fits its first part there and
/// the rest on an overflow page of its own. A stored identification was about 800 bytes when
/// 8 KiB was chosen; it is now 1 700 to 2 100 (the damping report grew), and with 8 KiB pages
/// half of `bench history`'s rows overflowed: 5 736 bytes of file per row, 3.3 times the rows'
/// own size (docs/benchmarks.md, "Stop 98: the store's rows outgrew their page"). An old file
/// keeps its page size (changing it needs a `VACUUM`, a copy of the whole file).
const PAGE_SIZE: u32 = 16384;

/// The size bound starts pruning when the pages in use pass this fraction of `max_size_mb`...
pub const SIZE_HIGH_WATERMARK: f64 = 0.9;

/// ...and prunes until they are under this fraction. The gap (10 % of the bound) is what one
/// pruning frees, so it does not run at every commit; the margin above the high mark is room
/// for the writes between two checks (one merged transaction: at most 256 requests).
pub const SIZE_LOW_WATERMARK: f64 = 0.8;

/// History rows deleted by one pruning transaction at most: the writer thread does not hold one
/// transaction long (the history route reads meanwhile, WAL), and each batch frees pages.
pub const PRUNE_BATCH_ROWS: u64 = 2000;

/// Bytes of file per stored identification (docs/benchmarks.md, "Stop 98: the store's rows
/// outgrew their page": 2 115 with 16 KiB pages and today's reports; 1 735 at stop 58, 1 225
/// when schema 2 was made), to turn a size into rows.
pub(crate) const ROW_BYTES: u64 = 2115;

/// History rows deleted by one pruning transaction for a bound of `max_bytes`: about 1 % of the
/// bound, between 16 and [`PRUNE_BATCH_ROWS`]. Why proportional: the pruning stops at the first
/// batch that brings the store under [`SIZE_LOW_WATERMARK`], so it overshoots by up to one batch;
/// 2 000 rows (3.5 MB) deleted every row of a 3 MiB store at once, leaving 30 % of it used
/// instead of 80 %. For the default 12 GiB bound it is the 2 000.
pub fn prune_batch_rows(max_bytes: u64) -> u64 {
    (max_bytes / 100 / ROW_BYTES).clamp(16, PRUNE_BATCH_ROWS)
}

/// The WAL file's budget for a bound of `max_bytes`: 5 % of it, at most 64 MiB. The WAL is
/// checkpointed when it holds half of that (at most SQLite's default 1 000 pages) and truncated
/// back to it after a checkpoint (`journal_size_limit`). It outgrows the budget only while a
/// reader keeps a checkpoint from finishing (a long `gatewatch history`, a backup), and that is
/// not answered by deleting history: the pruning counts the WAL up to its budget.
pub fn wal_budget(max_bytes: u64) -> u64 {
    (max_bytes / 20).min(64 << 20)
}

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
    /// The daemon's exclusive lock on `<file>.lock`, held while the store is open (dropping
    /// the file releases it); `None` read-only. See [`take_lock`].
    _lock: Option<File>,
    /// The file as opened, and its `(device, inode)` then: [`Store::check`] compares them with
    /// what the path names now. `None` read-only.
    file: PathBuf,
    identity: Option<(u64, u64)>,
    /// Frames of a damaged `-wal` SQLite dropped at open (`wal::keep_damaged`); 0 read-only.
    wal_frames_dropped: u64,
}

fn lock(m: &Mutex<Connection>) -> std::sync::MutexGuard<'_, Connection> {
    // A panic under the lock cannot leave a connection half-used: rusqlite rolls back an
    // unfinished transaction when it is dropped.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn sq(operation: &'static str) -> impl FnOnce(rusqlite::Error) -> StoreError {
    move |source| StoreError::Sqlite { operation, source }
}

/// Whether the daemon can open a store at `path`, as far as the file system tells before
/// SQLite is asked: `path` is not a directory, its directory exists, and the directory (where
/// SQLite creates the WAL, shared-memory and lock files) and an existing file are writable by
/// this process. The reason, when not, says which (SQLite's own "unable to open database file"
/// does not).
///
/// [`SqliteStore::open`] runs it first; `gatewatch check-config` runs it too, so that a
/// configuration it passes does not make `serve` fail at start on its store (the systemd unit
/// runs it as `ExecStartPre`, as the same user, after systemd created `StateDirectory`). The
/// daemon never creates the directory: a missing one is more often a typo or an unmounted
/// volume than a wish, and a store silently created elsewhere would lose the history.
pub fn check_location(path: &Path) -> Result<(), String> {
    use rustix::fs::{access, Access};
    if path.is_dir() {
        return Err("is a directory".into());
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // named absolutely: "its directory . is not writable" said little
    let shown = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    if !dir.is_dir() {
        return Err(format!(
            "its directory {} does not exist or is not a directory",
            shown.display()
        ));
    }
    if let Err(e) = access(dir, Access::WRITE_OK | Access::EXEC_OK) {
        return Err(format!(
            "its directory {} is not writable ({}): SQLite creates and writes the -wal, -shm \
             and lock files there, and a store opened read-only would fail every write",
            shown.display(),
            std::io::Error::from(e)
        ));
    }
    // the file, and SQLite's files beside it: one it cannot write makes the store read-only
    for (suffix, what) in [
        ("", "it"),
        ("-wal", "its WAL file"),
        ("-shm", "its shared-memory file"),
    ] {
        let mut file = path.as_os_str().to_owned();
        file.push(suffix);
        let file = PathBuf::from(file);
        let Ok(meta) = std::fs::metadata(&file) else {
            continue;
        };
        let denied = |a: Access| access(&file, a).err().map(std::io::Error::from);
        let missing: Vec<(&str, std::io::Error)> =
            [("read", Access::READ_OK), ("write", Access::WRITE_OK)]
                .into_iter()
                .filter_map(|(name, a)| denied(a).map(|e| (name, e)))
                .collect();
        let Some((_, first)) = missing.first() else {
            continue;
        };
        let cause = match first.kind() {
            std::io::ErrorKind::PermissionDenied => "permission denied".to_string(),
            _ => first.to_string(),
        };
        let verbs: Vec<&str> = missing.iter().map(|(v, _)| *v).collect();
        let named = if suffix.is_empty() {
            String::new()
        } else {
            format!(" {}", file.display())
        };
        return Err(format!(
            "{cause}: this process cannot {} {what}{named} (mode {:03o}, owner uid {} gid {})",
            verbs.join(" or "),
            meta.mode() & 0o7777,
            meta.uid(),
            meta.gid()
        ));
    }
    Ok(())
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
        check_location(path).map_err(|message| StoreError::Open {
            path: name.clone(),
            message,
        })?;
        // the lock next to the real file, whatever name (symbolic link) leads to it; a second
        // name of the same file (hard link) is refused outright
        refuse_hard_links(path, &name)?;
        let real = real_path(path, &name)?;
        let lock_file = take_lock(&real, &name)?;
        // before SQLite's recovery silently drops what follows a damaged frame
        let wal_frames_dropped = super::wal::keep_damaged(path, &name)?;
        // SQLite opens an empty file as a new database without a word: a file truncated by a
        // failed copy or a full disk would silently cost the history, the alert states and
        // the undelivered notifications
        if std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() == 0) {
            tracing::warn!(
                store = %name,
                "store {name} is empty: starting without history or alert state (a new store, \
                 or a file truncated by a failed copy or a full disk)"
            );
        }
        let mut write = Connection::open(path).map_err(open_err)?;
        if write.is_readonly(rusqlite::MAIN_DB).map_err(open_err)? {
            return Err(StoreError::Open {
                path: name,
                message: "is not writable".into(),
            });
        }
        write.busy_timeout(BUSY_TIMEOUT).map_err(open_err)?;
        quick_check(&write, path, &name)?;
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
        if page_size < u64::from(PAGE_SIZE) {
            tracing::warn!(
                store = %name,
                page_size,
                "store {name} has pages of {page_size} bytes (made by an earlier gatewatch): many \
                 history rows overflow such a page, and the file holds about 2.7 times what a \
                 new store's would for the same rows; with the daemon stopped, `sqlite3 FILE 'PRAGMA \
                 journal_mode=DELETE; PRAGMA page_size={PAGE_SIZE}; VACUUM; PRAGMA \
                 journal_mode=WAL'` rewrites it (docs/operations.md, \"Size\")"
            );
        }
        let pages = max_size_mb.saturating_mul(1024 * 1024) / page_size;
        write
            .query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))
            .map_err(open_err)?;
        let budget = wal_budget(pages * page_size);
        let checkpoint_pages = (budget / 2 / page_size).clamp(1, 1000);
        write
            .query_row(&format!("PRAGMA journal_size_limit = {budget}"), [], |_| {
                Ok(())
            })
            .map_err(open_err)?;
        write
            .query_row(
                &format!("PRAGMA wal_autocheckpoint = {checkpoint_pages}"),
                [],
                |_| Ok(()),
            )
            .map_err(open_err)?;
        let read = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(open_err)?;
        read.busy_timeout(BUSY_TIMEOUT).map_err(open_err)?;
        let meta = std::fs::metadata(path).map_err(|e| StoreError::Open {
            path: name.clone(),
            message: format!("cannot stat it after opening it: {e}"),
        })?;
        Ok(SqliteStore {
            file: path.to_path_buf(),
            identity: Some((meta.dev(), meta.ino())),
            path: name,
            write: Mutex::new(write),
            read: Mutex::new(read),
            max_bytes: Some(pages * page_size),
            _lock: Some(lock_file),
            wal_frames_dropped,
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
        if path.is_dir() {
            return Err(StoreError::Open {
                path: name,
                message: "is a directory, not a database file".into(),
            });
        }
        if !path.is_file() {
            let message = if path.exists() {
                "not a regular file (a device or a pipe), not a database file"
            } else {
                "no such file"
            };
            return Err(StoreError::Open {
                path: name,
                message: message.into(),
            });
        }
        let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let open = |immutable: bool| -> Result<(Connection, i64), rusqlite::Error> {
            let c = if immutable {
                Connection::open_with_flags(
                    immutable_uri(path),
                    flags | OpenFlags::SQLITE_OPEN_URI,
                )?
            } else {
                Connection::open_with_flags(path, flags)?
            };
            c.busy_timeout(BUSY_TIMEOUT)?;
            // the first read: where a WAL file's missing shared memory shows
            let version = c.query_row("PRAGMA user_version", [], |r| r.get(0))?;
            Ok((c, version))
        };
        // A WAL-mode file needs its `-shm` file, which SQLite creates next to it even to read:
        // a copy in a directory the user cannot write (a backup, a read-only mount) fails with
        // SQLITE_READONLY. Then it is opened `immutable=1`: read as a plain file, no locks, no
        // shared memory, which is right for a copy nobody writes. An immutable open ignores
        // the WAL, so a non-empty `-wal` beside it (writes not yet in the .db) is refused
        // rather than silently left out.
        let (read, version, immutable) = match open(false) {
            Ok((c, v)) => (c, v, false),
            // READONLY without a -wal file, CANTOPEN with one
            Err(e)
                if matches!(
                    e.sqlite_error_code(),
                    Some(rusqlite::ErrorCode::ReadOnly | rusqlite::ErrorCode::CannotOpen)
                ) =>
            {
                let mut wal = path.as_os_str().to_owned();
                wal.push("-wal");
                let wal = PathBuf::from(wal);
                if std::fs::metadata(&wal).is_ok_and(|m| m.len() > 0) {
                    return Err(StoreError::Open {
                        path: name,
                        message: format!(
                            "cannot be read (SQLite: {e}) and {} beside it holds writes not yet \
                             in it: if the directory is not writable (SQLite creates a -shm \
                             file there even to read), copy both files into one that is",
                            wal.display()
                        ),
                    });
                }
                // the first error is the one to report when the immutable open fails too
                let (c, v) = open(true).map_err(|_| open_err(e))?;
                (c, v, true)
            }
            Err(e) => return Err(open_err(e)),
        };
        if version != SCHEMA_VERSION {
            // version 0: an empty file or another program's database, not an old gatewatch's
            let message = if version == 0 {
                "is not a gatewatch store (no gatewatch schema in it): give the file that \
                 `serve` writes, its storage.path"
                    .to_string()
            } else {
                format!("schema version {version}, this gatewatch reads version {SCHEMA_VERSION}")
            };
            return Err(StoreError::Open {
                path: name.clone(),
                message,
            });
        }
        let (write, _) = open(immutable).map_err(open_err)?;
        Ok(SqliteStore {
            file: path.to_path_buf(),
            identity: None,
            path: name,
            write: Mutex::new(write),
            read: Mutex::new(read),
            max_bytes: None,
            _lock: None,
            wal_frames_dropped: 0,
        })
    }

    /// SQLite's "database or disk is full" says neither which, and an operator acts on one or
    /// the other (free the disk, or raise `max_size_mb`): the error names the cause. The bound
    /// when what the file could still take without growing past `max_page_count` (its free
    /// pages and the pages left under the bound) is under 2 MiB or 5 % of the bound, so one
    /// transaction can have met it; the disk otherwise. Other errors are returned as they are.
    fn explain_full(&self, c: &Connection, e: StoreError) -> StoreError {
        let StoreError::Sqlite { operation, source } = e else {
            return e;
        };
        if source.sqlite_error_code() != Some(rusqlite::ErrorCode::DiskFull) {
            return StoreError::Sqlite { operation, source };
        }
        let pragma = |name: &str| -> u64 {
            c.query_row(&format!("PRAGMA {name}"), [], |r| r.get::<_, i64>(0))
                .map_or(0, |v| v.max(0) as u64)
        };
        let (pages, free, max_pages, page) = (
            pragma("page_count"),
            pragma("freelist_count"),
            pragma("max_page_count"),
            pragma("page_size"),
        );
        let mib = |pages: u64| (pages * page) as f64 / 1_048_576.0;
        let room = (max_pages.saturating_sub(pages) + free) * page;
        let bound = self.max_bytes.unwrap_or(u64::MAX);
        let reason = if room < (2 << 20).max(bound / 20) {
            format!(
                "the database is full at its storage.max_size_mb bound ({:.1} MiB) after \
                 pruning history: what is left is alert state and outbox, or a transaction \
                 larger than the margin",
                mib(max_pages)
            )
        } else {
            format!(
                "the disk holding it is full ({source}; the database uses {:.1} MiB of its \
                 {:.1} MiB bound): free space on that disk",
                mib(pages - free.min(pages)),
                mib(max_pages)
            )
        };
        StoreError::Full {
            path: self.path.clone(),
            operation,
            reason,
            source: Box::new(source),
        }
    }

    /// Frames of the last writes SQLite dropped at open because the `-wal` file was damaged
    /// before them (a copy of the WAL was kept and a warning logged); 0 when none.
    pub fn wal_frames_dropped(&self) -> u64 {
        self.wal_frames_dropped
    }

    /// The file.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// What the size bound counts, in bytes: the database's pages in use (free pages not
    /// counted: they are reused) plus the WAL file.
    pub fn used_bytes(&self) -> Result<u64, StoreError> {
        let used = used_bytes(&lock(&self.write)).map_err(sq("size"))?;
        Ok(used + wal_bytes(&self.file))
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
    /// copy of the `.db` file alone is complete. Called at shutdown. An error when it is not
    /// complete: the file is gone ([`Store::check`]), SQLite failed (a full disk), or another
    /// connection (a `gatewatch history`, a backup) still reads the WAL after the busy
    /// timeout: SQLite reports that last one in the pragma's answer, not as an error.
    pub fn checkpoint(&self) -> Result<(), StoreError> {
        self.checkpoint_within(BUSY_TIMEOUT)
    }

    /// [`SqliteStore::checkpoint`], waiting at most `within` (not the 5 s busy timeout) for a
    /// lock another connection holds: at shutdown, what is left of the deadline.
    pub fn checkpoint_within(&self, within: std::time::Duration) -> Result<(), StoreError> {
        self.check()?;
        let c = lock(&self.write);
        c.busy_timeout(within.min(BUSY_TIMEOUT))
            .map_err(sq("checkpoint"))?;
        let result = c.query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, i64>(2)?,
            ))
        });
        // the connection's usual patience back (a no-op error: the same call succeeded above)
        let _ = c.busy_timeout(BUSY_TIMEOUT);
        drop(c);
        let (busy, log, done) = result.map_err(sq("checkpoint"))?;
        if busy != 0 || log != done {
            return Err(StoreError::Checkpoint {
                path: self.path.clone(),
                message: format!(
                    "checkpoint incomplete: another connection holds a lock on the \
                     database or still reads the WAL ({done} of {log} pages written back); the \
                     .db file alone is not complete, keep its -wal file with it"
                ),
            });
        }
        Ok(())
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

/// [`Store::write`] on the write connection: one transaction.
fn write_batch(c: &mut Connection, batch: &WriteBatch) -> Result<Vec<i64>, StoreError> {
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

/// Pages in use (the file's pages less the free ones), in bytes.
fn used_bytes(c: &Connection) -> rusqlite::Result<u64> {
    let pages: i64 = c.query_row("PRAGMA page_count", [], |r| r.get(0))?;
    let free: i64 = c.query_row("PRAGMA freelist_count", [], |r| r.get(0))?;
    let size: i64 = c.query_row("PRAGMA page_size", [], |r| r.get(0))?;
    Ok((pages - free).max(0) as u64 * size.max(0) as u64)
}

/// The size of the WAL file next to `db` (0 when there is none).
fn wal_bytes(db: &Path) -> u64 {
    let mut wal = db.as_os_str().to_owned();
    wal.push("-wal");
    std::fs::metadata(PathBuf::from(wal))
        .map(|m| m.len())
        .unwrap_or(0)
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

    fn check(&self) -> Result<(), StoreError> {
        let Some(identity) = self.identity else {
            return Ok(());
        };
        let what = match std::fs::metadata(&self.file) {
            Ok(m) if (m.dev(), m.ino()) == identity => return Ok(()),
            Ok(_) => "replaced by another file".to_string(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "deleted".to_string(),
            Err(e) => format!("no longer visible ({e})"),
        };
        Err(StoreError::Gone {
            path: self.path.clone(),
            message: format!(
                "{what} while the daemon runs: writes would go to a file that disappears at \
                 exit, so they are refused; restore the file or restart the daemon"
            ),
        })
    }

    fn probe(&self) -> Option<Result<(), StoreError>> {
        self.identity?;
        let c = lock(&self.write);
        // the schema version written back unchanged: one page (the header) through the WAL
        let probe = || -> rusqlite::Result<()> {
            let v: i64 = c.query_row("PRAGMA user_version", [], |r| r.get(0))?;
            c.execute_batch(&format!("PRAGMA user_version = {v}"))?;
            // The header is rewritten in place, so that succeeds at the size bound too, where
            // every real write (a new page) fails: the probe cleared the failure and /readyz
            // said 200 while no identification could be written (a CI rehearsal at stop 60).
            // So no page left under `max_page_count` is a full store, as a real write finds.
            let pragma =
                |name: &str| c.query_row(&format!("PRAGMA {name}"), [], |r| r.get::<_, i64>(0));
            if pragma("freelist_count")? == 0 && pragma("page_count")? >= pragma("max_page_count")?
            {
                return Err(rusqlite::Error::SqliteFailure(
                    rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_FULL),
                    Some("no free page under max_page_count".into()),
                ));
            }
            Ok(())
        };
        Some(
            probe()
                .map_err(sq("write probe"))
                .map_err(|e| self.explain_full(&c, e)),
        )
    }

    fn space_left(&self) -> Option<u64> {
        self.identity?;
        let dir = match self.file.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let v = rustix::fs::statvfs(dir).ok()?;
        Some(v.f_bavail.saturating_mul(v.f_frsize))
    }

    fn write(&self, batch: &WriteBatch) -> Result<Vec<i64>, StoreError> {
        let mut c = lock(&self.write);
        write_batch(&mut c, batch).map_err(|e| self.explain_full(&c, e))
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
        let mut c = lock(&self.write);
        let result = self.prune_to_bound(&mut c, force, max);
        result.map_err(|e| self.explain_full(&c, e))
    }
}

impl SqliteStore {
    /// [`Store::make_room`] on the write connection.
    fn prune_to_bound(&self, c: &mut Connection, force: bool, max: u64) -> Result<u64, StoreError> {
        let high = (max as f64 * SIZE_HIGH_WATERMARK) as u64;
        let low = (max as f64 * SIZE_LOW_WATERMARK) as u64;
        let budget = wal_budget(max);
        let mut used = used_bytes(c).map_err(sq("size bound"))?;
        let mut wal = wal_bytes(&self.file);
        if used + wal <= high && !force {
            return Ok(0);
        }
        if wal > budget {
            // a reader held the last checkpoints back: try now (a reader still there leaves
            // the WAL as it is, reported in the pragma's row, not as an error)
            let _ = c.query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()));
            wal = wal_bytes(&self.file);
        }
        // The database's share of the low mark. Deleting history writes to the WAL rather
        // than shrinking it, so the WAL is counted as it was before the deletions, and up to
        // its budget only: a WAL held back by a reader is not answered by deleting history.
        let target = low.saturating_sub(wal.min(budget));
        let batch = prune_batch_rows(max);
        let mut deleted = 0;
        // forced (a write was refused as full): at least one batch, even under the low mark
        let mut first = force;
        while used > target || first {
            first = false;
            let n = delete_oldest(c, batch).map_err(sq("size bound"))?;
            if n == 0 {
                break; // no history left: the rest is alert state and outbox, never pruned
            }
            deleted += n;
            used = used_bytes(c).map_err(sq("size bound"))?;
        }
        Ok(deleted)
    }
}
