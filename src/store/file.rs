//! The store's file on disk, apart from what is in it: the lock that keeps one daemon per file,
//! the damage check at open, and the URI a read-only copy is opened by. Split from `sqlite`
//! so that file's reader meets the store's rows, not its guards.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use rusqlite::Connection;

use super::StoreError;

/// A file up to this size is checked whole at open (`PRAGMA quick_check`); a larger one only in
/// the tables the daemon restores and acts on (alert state, outbox) and the schema. Why: the
/// check reads every page, about 2.2 s per GiB with the file in the page cache on the 2-core
/// test machine (a 576 MB file: 1.25 s) and the disk's read speed cold, so the default bound
/// (12 GiB) would hold the start (and the alerting) for half a minute to minutes at every
/// restart. 1 GiB costs about two seconds. The history of a larger file is checked where it is
/// read: a damaged page fails its query with SQLite's "malformed" error, logged naming the
/// file; `sqlite3 FILE 'PRAGMA quick_check'` checks it whole offline (docs/operations.md,
/// "Start").
pub const QUICK_CHECK_MAX_BYTES: u64 = 1 << 30;

/// The lock file of the store at `db`: `<db>.lock`, next to it. The daemon passes the
/// resolved path (`real_path`), so the lock is next to the real file.
pub fn lock_path(db: &Path) -> PathBuf {
    let mut s = db.as_os_str().to_owned();
    s.push(".lock");
    PathBuf::from(s)
}

/// The path of the file `db` names, every symbolic link resolved (`std::fs::canonicalize`),
/// the lock ([`take_lock`]) is derived from. A file not yet created: its directory resolved,
/// its name kept. Why: the lock was keyed on the path's text, so `b/gw.db -> ../a/gw.db`
/// took `b/gw.db.lock` and a second daemon wrote the first's file. A symbolic link to a
/// missing file (SQLite would create the target) is refused rather than guessed at.
pub(super) fn real_path(db: &Path, name: &str) -> Result<PathBuf, StoreError> {
    let err = |message: String| StoreError::Open {
        path: name.to_string(),
        message,
    };
    match std::fs::canonicalize(db) {
        Ok(p) => return Ok(p),
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(err(format!("cannot resolve its path: {e}")))
        }
        Err(_) => {}
    }
    if std::fs::symlink_metadata(db).is_ok() {
        return Err(err(
            "is a symbolic link to a missing file: point storage.path at the real file".into(),
        ));
    }
    let (Some(dir), Some(file)) = (db.parent(), db.file_name()) else {
        return Err(err("is not the path of a file".into()));
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let dir = std::fs::canonicalize(dir).map_err(|e| {
        err(format!(
            "cannot resolve its directory {}: {e}",
            dir.display()
        ))
    })?;
    Ok(dir.join(file))
}

/// Refuses a database file with more than one hard link (`st_nlink > 1`), naming the count.
/// Why: SQLite keys its `-wal` and `-shm` files on the path, so two names of one file get two
/// WALs over one database: each daemon's commits are invisible to the other, and a checkpoint
/// of one overwrites pages the other wrote (rows silently lost, the file possibly corrupt).
/// The lock beside the file cannot see a second name either. A file not yet created passes.
pub(super) fn refuse_hard_links(db: &Path, name: &str) -> Result<(), StoreError> {
    use std::os::unix::fs::MetadataExt;
    match std::fs::metadata(db) {
        Ok(m) if m.nlink() > 1 => Err(StoreError::Open {
            path: name.to_string(),
            message: format!(
                "has {} hard links (names): a SQLite file in WAL mode opened under two names \
                 gets a -wal file per name and loses or corrupts the writes of one; remove the \
                 other names (find / -samefile {name}) or copy the file",
                m.nlink()
            ),
        }),
        _ => Ok(()),
    }
}

/// Takes the exclusive advisory lock (`flock`, non-blocking) on `<db>.lock` and writes this process's id
/// into it, or fails naming the process that holds it.
///
/// Why: SQLite itself lets two processes write one file, so a second daemon started on the
/// same `storage.path` (a copy of the unit, a forgotten container) would restore the first's
/// alert states, fire false `GateDataStale` for its gates, write them back and prune the same
/// history. A lock beside the file rather than on it: the lock file also carries the holder's
/// pid for the message, and SQLite's own (POSIX) locks on the database are left alone. The lock
/// file is never deleted: deleting it would let a third process lock a new file while the
/// second still holds the old one. The kernel releases the lock when the process dies, even
/// on `kill -9`. `gatewatch history` opens read-only and takes no lock.
pub(super) fn take_lock(db: &Path, name: &str) -> Result<File, StoreError> {
    let path = lock_path(db);
    let open_err = |message: String| StoreError::Open {
        path: name.to_string(),
        message,
    };
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| {
            open_err(match e.kind() {
                std::io::ErrorKind::PermissionDenied => format!(
                    "its directory is not writable (cannot create the lock file {}: {e})",
                    path.display()
                ),
                _ => format!("cannot create the lock file {}: {e}", path.display()),
            })
        })?;
    match rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => {}
        Err(e) if e == rustix::io::Errno::WOULDBLOCK => {
            let mut pid = String::new();
            let _ = file.read_to_string(&mut pid);
            let holder = match pid.trim().parse::<u32>() {
                Ok(pid) => format!("process {pid}"),
                Err(_) => "another process".to_string(),
            };
            // the same file under another name (a symbolic link, a directory link): say which
            let named = std::path::absolute(name).unwrap_or_else(|_| PathBuf::from(name));
            let same = if named != db {
                format!(", the same file as {}", db.display())
            } else {
                String::new()
            };
            return Err(open_err(format!(
                "in use: {holder} holds its lock {} (one daemon per store file{same})",
                path.display()
            )));
        }
        Err(e) => {
            let e = std::io::Error::from(e);
            return Err(open_err(format!("cannot lock {}: {e}", path.display())));
        }
    }
    // the pid is only for the message of a second daemon: a failure here is not fatal
    let _ = file
        .set_len(0)
        .and_then(|()| file.write_all(format!("{}\n", std::process::id()).as_bytes()));
    Ok(file)
}

/// `file:PATH?immutable=1`, the path percent-encoded where a URI needs it (`?`, `#`, `%` and
/// every byte outside ASCII; SQLite decodes them).
pub(super) fn immutable_uri(path: &Path) -> String {
    let mut uri = String::from("file:");
    for &b in path.as_os_str().as_encoded_bytes() {
        if matches!(b, b'?' | b'#' | b'%') || !b.is_ascii() {
            uri.push_str(&format!("%{b:02X}"));
        } else {
            uri.push(char::from(b));
        }
    }
    uri.push_str("?immutable=1");
    uri
}

/// Refuses a damaged file before anything in it is trusted or written: `PRAGMA quick_check`
/// (the b-tree pages and their order, not the index contents: `integrity_check` is several
/// times slower), whole up to [`QUICK_CHECK_MAX_BYTES`], else the small tables only. The error
/// carries SQLite's first finding.
pub(super) fn quick_check(c: &Connection, path: &Path, name: &str) -> Result<(), StoreError> {
    let corrupt = |finding: String| StoreError::Open {
        path: name.to_string(),
        message: format!(
            "damaged (SQLite's quick_check: {finding}); restore it from a backup or move it \
             aside to start with an empty store"
        ),
    };
    let run = |sql: &str| -> Result<(), StoreError> {
        let first: String =
            c.query_row(sql, [], |r| r.get(0))
                .map_err(|e| match e.sqlite_error_code() {
                    Some(rusqlite::ErrorCode::DatabaseCorrupt) => corrupt(e.to_string()),
                    _ => StoreError::Open {
                        path: name.to_string(),
                        message: e.to_string(),
                    },
                })?;
        if first.eq_ignore_ascii_case("ok") {
            return Ok(());
        }
        let finding: Vec<&str> = first
            .lines()
            .filter(|l| !l.starts_with("***"))
            .take(3)
            .collect();
        Err(corrupt(finding.join("; ")))
    };
    let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    if size <= QUICK_CHECK_MAX_BYTES {
        return run("PRAGMA quick_check(1)");
    }
    tracing::info!(
        store = name,
        bytes = size,
        "store larger than {} MiB: quick_check of the alert state and the outbox only \
         (check it whole offline with sqlite3 FILE 'PRAGMA quick_check')",
        QUICK_CHECK_MAX_BYTES >> 20
    );
    for table in ["sqlite_schema", "alert_state", "outbox"] {
        let exists: bool = c
            .query_row(
                "SELECT count(*) > 0 FROM sqlite_schema WHERE name = ?1",
                [table],
                |r| r.get(0),
            )
            .unwrap_or(table == "sqlite_schema");
        if exists {
            run(&format!("PRAGMA quick_check({table})"))?;
        }
    }
    Ok(())
}
