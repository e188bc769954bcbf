//! The SQLite store on real files in a temporary directory: what only SQLite does (files,
//! locks, damage, migrations, the size bound). What every store must do (history bounds,
//! alert states, the outbox, pruning) is checked once for both stores in
//! `tests/store_conformance`, run on SQLite by `tests/store_nats.rs`.

use std::sync::Arc;
use std::time::Duration;

use super::*;

#[path = "../../tests/store_conformance/fixtures.rs"]
mod fixtures;
use fixtures::{outbox_row, record};

#[path = "../../tests/store_common/brim.rs"]
mod brim;
use brim::fill_to_the_brim;

fn open(dir: &tempfile::TempDir) -> SqliteStore {
    SqliteStore::open(&dir.path().join("gw.db"), 64).expect("open")
}

#[test]
fn history_survives_reopening_and_is_filtered_by_gate_range_and_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    {
        let s = open(&dir);
        let batch = WriteBatch {
            identifications: (0..10)
                .map(|i| record("g1", 1000.0 + 5.0 * f64::from(i), 0.01))
                .chain([record("g2", 1010.0, -0.02)])
                .collect(),
            ..Default::default()
        };
        s.write(&batch).expect("write");
    }
    let s = open(&dir); // reopened: the migration is not re-run, the rows are there
    let q = |from, to, limit| HistoryQuery {
        gate: "g1".into(),
        from,
        to,
        limit,
    };
    let all = s.history(&q(None, None, 100)).expect("history");
    assert_eq!(all.len(), 10);
    assert_eq!(all[0], record("g1", 1000.0, 0.01), "round trip");
    assert!(all.windows(2).all(|w| w[0].window_end < w[1].window_end));
    let some = s
        .history(&q(Some(1010.0), Some(1020.0), 100))
        .expect("history");
    let ends: Vec<f64> = some.iter().map(|r| r.window_end).collect();
    assert_eq!(ends, [1010.0, 1015.0, 1020.0]);
    assert_eq!(s.history(&q(None, None, 3)).expect("history").len(), 3);
    let g2 = s
        .history(&HistoryQuery {
            gate: "g2".into(),
            from: None,
            to: None,
            limit: 10,
        })
        .expect("history");
    assert_eq!(g2.len(), 1);
    assert_eq!(g2[0].zeta0(), Some(-0.02));
    assert_eq!(g2[0].zeta0_interval(), Some((-0.03, -0.01)));
}

#[test]
fn a_file_that_is_not_a_database_is_refused_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("junk.db");
    std::fs::write(&path, vec![0x42u8; 8192]).expect("write junk");
    let e = SqliteStore::open(&path, 64).expect_err("not a database");
    let msg = e.to_string();
    assert!(msg.contains("junk.db"), "{msg}");
    assert!(msg.contains("not a database"), "{msg}");
    let e = SqliteStore::open(dir.path(), 64).expect_err("a directory");
    assert!(e.to_string().contains("is a directory"), "{e}");
    let e = SqliteStore::open(&dir.path().join("missing/dir/gw.db"), 64).expect_err("no dir");
    assert!(e.to_string().contains("missing/dir/gw.db"), "{e}");
}

/// One daemon per file: a second open for writing is refused naming this process (the
/// holder), read-only opens still work, and the lock goes with the first store.
#[test]
fn a_second_writer_on_the_same_file_is_refused_and_readers_are_not() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    let first = SqliteStore::open(&path, 64).expect("open");
    let e = SqliteStore::open(&path, 64).expect_err("a second writer");
    let msg = e.to_string();
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    assert!(
        msg.contains(&format!("process {}", std::process::id())),
        "{msg}"
    );
    assert!(msg.contains("gw.db.lock"), "{msg}");
    let reader = SqliteStore::open_read_only(&path).expect("a reader while the writer runs");
    assert!(reader.gates().expect("gates").is_empty());
    drop(first);
    drop(SqliteStore::open(&path, 64).expect("the lock went with the first store"));
}

/// A store whose directory is missing says so (SQLite alone says "unable to open").
#[test]
fn a_missing_directory_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let e = SqliteStore::open(&dir.path().join("nodir/gw.db"), 64).expect_err("no dir");
    let msg = e.to_string();
    assert!(msg.contains("nodir/gw.db"), "{msg}");
    assert!(
        msg.contains("directory") && msg.contains("does not exist"),
        "{msg}"
    );
}

/// `rm gw.db*` under the writer: the next write is refused (not written to the deleted inode),
/// counted as `file_gone`, the writer unhealthy; the shutdown checkpoint fails too; a file put
/// back at the path (another inode) is still not the store's.
#[test]
fn a_deleted_file_is_noticed_refused_and_counted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    let store = Arc::new(SqliteStore::open(&path, 64).expect("open"));
    let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1_000_000)
        .expect("writer");
    let (tx, rx) = std::sync::mpsc::channel();
    let submit = |end: f64| {
        let tx = tx.clone();
        writer.submit(
            WriteBatch {
                identifications: vec![record("g1", end, 0.01)],
                ..Default::default()
            },
            Some(Box::new(move |r| {
                let _ = tx.send(r);
            })),
        );
        assert!(writer.flush(Duration::from_secs(30)), "flushed");
        rx.recv_timeout(Duration::from_secs(30)).expect("callback")
    };
    assert!(submit(1.0).is_ok());
    assert!(writer.healthy());
    assert!(store.check().is_ok());
    for suffix in ["", "-wal", "-shm"] {
        let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
    }
    let e = submit(2.0).expect_err("refused");
    assert!(e.contains("gw.db") && e.contains("deleted"), "{e}");
    let stats = writer.stats();
    let load = |c: &std::sync::atomic::AtomicU64| c.load(std::sync::atomic::Ordering::Relaxed);
    assert_eq!(load(&stats.file_gone), 1);
    assert_eq!(load(&stats.write_failed), 0);
    assert!(!writer.healthy());
    let e = store.checkpoint().expect_err("nothing to checkpoint into");
    assert!(e.is_gone(), "{e}");
    // another file at the same path is not the store's file
    std::fs::write(&path, b"").expect("a new file");
    let e = store.check().expect_err("replaced");
    assert!(e.to_string().contains("replaced"), "{e}");
    assert!(writer.close(Duration::from_secs(30)));
}

/// The shutdown checkpoint says when a reader keeps it from writing the WAL back (SQLite
/// answers that in the pragma's row, not as an error): the `.db` alone is then incomplete.
#[test]
fn a_checkpoint_blocked_by_a_reader_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    let store = SqliteStore::open(&path, 64).expect("open");
    store
        .write(&WriteBatch {
            identifications: vec![record("g1", 1.0, 0.01)],
            ..Default::default()
        })
        .expect("write");
    let reader = rusqlite::Connection::open(&path).expect("reader");
    reader.execute_batch("BEGIN").expect("begin");
    let _: i64 = reader
        .query_row("SELECT count(*) FROM history", [], |r| r.get(0))
        .expect("read");
    store
        .write(&WriteBatch {
            identifications: vec![record("g1", 2.0, 0.01)],
            ..Default::default()
        })
        .expect("write");
    let e = store.checkpoint().expect_err("a reader holds the WAL");
    assert!(e.to_string().contains("checkpoint incomplete"), "{e}");
    reader.execute_batch("COMMIT").expect("commit");
    store
        .checkpoint()
        .expect("complete once the reader is done");
}

/// A real store with one page of its history overwritten: refused at open naming the file and
/// SQLite's finding (it used to open, and failed later in a read that did not name the file).
#[test]
fn a_damaged_page_is_refused_at_open() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    {
        let store = SqliteStore::open(&path, 64).expect("open");
        store
            .write(&WriteBatch {
                identifications: (0..400).map(|i| record("g1", f64::from(i), 0.01)).collect(),
                ..Default::default()
            })
            .expect("write");
        store.checkpoint().expect("checkpoint");
    }
    let mut bytes = std::fs::read(&path).expect("read");
    // the file's own page size (header bytes 16-17, big-endian): one whole page, mid-file
    let size = usize::from(u16::from_be_bytes([bytes[16], bytes[17]]));
    assert_eq!(size, 16384, "a new file's pages");
    let pages = bytes.len() / size;
    assert!(pages > 8, "{pages} pages");
    let page = pages / 2;
    bytes[page * size..(page + 1) * size].fill(0x5a);
    std::fs::write(&path, &bytes).expect("damage");
    let e = SqliteStore::open(&path, 64).expect_err("damaged");
    let msg = e.to_string();
    assert!(
        msg.contains("gw.db") && msg.contains("quick_check"),
        "{msg}"
    );
    assert!(!msg.contains('\n'), "one line: {msg}");
}

/// A 3 MiB bound (the reviewer's case): the database and its WAL together stay under it while
/// history streams in, and the pruning stops near the low watermark instead of deleting the
/// whole history at once (2 000 rows a batch left 30 % of the bound used). The pruning batch
/// follows the bound.
#[test]
fn a_small_bound_counts_the_wal_and_prunes_in_proportion() {
    assert_eq!(prune_batch_rows(4 << 20), 19);
    assert_eq!(prune_batch_rows(3 << 20), 16);
    assert_eq!(prune_batch_rows(12_288 << 20), PRUNE_BATCH_ROWS);
    assert_eq!(prune_batch_rows(1 << 20), 16);
    assert_eq!(wal_budget(12_288 << 20), 64 << 20);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    let bound = 3u64 << 20;
    let store = Arc::new(SqliteStore::open(&path, 3).expect("open"));
    let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1_000_000)
        .expect("writer");
    let wal = dir.path().join("gw.db-wal");
    let on_disk = || {
        std::fs::metadata(&path).map_or(0, |m| m.len())
            + std::fs::metadata(&wal).map_or(0, |m| m.len())
    };
    let pruned = || {
        writer
            .stats()
            .over_bytes_rows
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    let (mut low_seen, mut high_seen) = (f64::MAX, 0f64);
    let mut max_on_disk = 0;
    for i in 0..2000u32 {
        let batch = fat_batch(i);
        writer.submit(batch, None);
        if i % 20 == 19 {
            assert!(writer.flush(Duration::from_secs(60)), "flushed");
            max_on_disk = max_on_disk.max(on_disk());
            if pruned() > 0 {
                let used = store.used_bytes().expect("used") as f64 / bound as f64;
                low_seen = low_seen.min(used);
                high_seen = high_seen.max(used);
            }
        }
    }
    assert!(writer.close(Duration::from_secs(60)), "flushed");
    let stats = writer.stats();
    let load = |c: &std::sync::atomic::AtomicU64| c.load(std::sync::atomic::Ordering::Relaxed);
    assert_eq!(load(&stats.write_failed), 0);
    assert!(pruned() > 2000, "pruned {}", pruned());
    assert!(
        max_on_disk <= bound,
        "database + WAL reached {max_on_disk} bytes of {bound}"
    );
    // between the watermarks, give or take one merged write and one pruning batch
    assert!(
        low_seen > 0.7,
        "the pruning went down to {low_seen:.2} of the bound"
    );
    assert!(
        high_seen < 0.95,
        "the store went up to {high_seen:.2} of the bound"
    );
}

#[test]
fn a_newer_schema_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    drop(SqliteStore::open(&path, 64).expect("open"));
    let c = rusqlite::Connection::open(&path).expect("raw open");
    c.execute_batch("PRAGMA user_version = 99").expect("bump");
    drop(c);
    let e = SqliteStore::open(&path, 64).expect_err("newer");
    assert!(e.to_string().contains("newer"), "{e}");
    let e = SqliteStore::open_read_only(&path).expect_err("newer");
    assert!(e.to_string().contains("schema version 99"), "{e}");
}

#[test]
fn the_size_bound_prunes_the_oldest_history_and_no_write_fails() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("gw.db");
    // 1 MiB: SQLite's max_page_count, the same error as a full disk if it were reached
    let store = Arc::new(SqliteStore::open(&path, 1).expect("open"));
    let writer = StoreWriter::start(store.clone(), Duration::from_secs(u64::MAX / 4), 1_000_000)
        .expect("writer");
    // alert state and an undelivered notification, before the history fills the file
    writer.submit(
        WriteBatch {
            alert_states: vec![("g0".into(), "{\"state\":\"firing\"}".into())],
            outbox: vec![outbox_row("webhook a", "f1", "firing", false)],
            ..Default::default()
        },
        None,
    );
    let (tx, rx) = std::sync::mpsc::channel();
    const STEPS: u32 = 1500;
    for i in 0..STEPS {
        // 4 gates interleaved, about 1.3 kB a row: 6 000 rows are 8 MiB, 8 times the bound
        let tx = tx.clone();
        let batch = fat_batch(i);
        writer.submit(
            batch,
            Some(Box::new(move |res| {
                let _ = tx.send(res.is_ok());
            })),
        );
        if i % 20 == 19 {
            // at most 20 requests merged into one transaction (80 rows, 100 kB): the margin
            // between the high watermark and the bound (10 %, 100 kB of this 1 MiB) must hold
            // one transaction; the daemon's bound is gigabytes, its transactions 256 requests
            assert!(writer.flush(Duration::from_secs(60)), "flushed");
        }
    }
    assert!(writer.close(Duration::from_secs(60)), "flushed");
    let results: Vec<bool> = rx.try_iter().collect();
    assert_eq!(results.len(), STEPS as usize, "every callback ran");
    assert!(results.iter().all(|ok| *ok), "no write failed");
    let stats = writer.stats();
    let load = |c: &std::sync::atomic::AtomicU64| c.load(std::sync::atomic::Ordering::Relaxed);
    assert_eq!(load(&stats.write_failed), 0);
    assert_eq!(load(&stats.queue_full), 0);
    let pruned = load(&stats.over_bytes_rows);
    assert!(pruned > 4000, "the size bound pruned {pruned} rows");
    store.checkpoint().expect("checkpoint");
    let size = std::fs::metadata(&path).expect("file").len();
    assert!(size <= 1024 * 1024, "file {size} bytes");
    let q = |gate: &str| HistoryQuery {
        gate: gate.into(),
        from: None,
        to: None,
        limit: 10_000,
    };
    for g in 0..4 {
        let rows = store.history(&q(&format!("g{g}"))).expect("history");
        // the newest kept, the oldest gone, the same span for every gate (fair)
        assert_eq!(
            rows.last().map(|r| r.window_end),
            Some(f64::from(STEPS - 1))
        );
        assert!(rows[0].window_end > 1000.0, "{}", rows[0].window_end);
        assert!(rows
            .windows(2)
            .all(|w| w[1].window_end - w[0].window_end == 1.0));
        let first = store.history(&q("g0")).expect("history")[0].window_end;
        assert!(
            (rows[0].window_end - first).abs() <= 1.0,
            "fair across gates"
        );
    }
    assert_eq!(
        store.alert_states().expect("states"),
        [("g0".to_string(), "{\"state\":\"firing\"}".to_string())]
    );
    assert_eq!(
        store.outbox().expect("outbox").len(),
        1,
        "the outbox is never pruned"
    );
}

#[test]
fn a_file_of_schema_1_is_migrated_in_place_keeping_every_row() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("old.db");
    // a real file in the old schema, written as version 1 wrote it (4 KiB pages, WAL)
    let curve: Vec<serde_json::Value> = (0..17)
        .map(|i| serde_json::json!([0.001 * f64::from(i), 0.0123456789 - 0.001 * f64::from(i)]))
        .collect();
    {
        let mut c = rusqlite::Connection::open(&path).expect("raw open");
        c.execute_batch("PRAGMA journal_mode = WAL").expect("wal");
        super::schema::migrate_to(&mut c, 1).expect("schema 1");
        for (i, gate) in ["b", "a", "b", "a", "b"].iter().enumerate() {
            let mut r = record(gate, 100.0 + i as f64, [0.0, 0.01, 0.02, 0.03, 0.04][i]);
            r.damping["zeta_eq_curve"] = serde_json::Value::Array(curve.clone());
            c.execute(
                "INSERT INTO identifications (gate, time, window_start, window_end, equation,
                    coefficients, damping, verdict, fit_nmae, path)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                rusqlite::params![
                    r.gate,
                    r.time,
                    r.window_start,
                    r.window_end,
                    r.equation,
                    serde_json::to_string(&r.coefficients).expect("json"),
                    r.damping.to_string(),
                    r.verdict,
                    r.fit_nmae,
                    r.path
                ],
            )
            .expect("insert v1");
        }
        c.execute(
            "INSERT INTO alert_state (gate, state) VALUES ('a', 'firing')",
            [],
        )
        .expect("state");
        c.execute_batch("PRAGMA wal_checkpoint(TRUNCATE)")
            .expect("checkpoint");
    }
    // version 1 is refused read-only (not migrated behind the daemon's back)
    let e = SqliteStore::open_read_only(&path).expect_err("old schema");
    assert!(e.to_string().contains("schema version 1"), "{e}");
    let s = SqliteStore::open(&path, 64).expect("migrated");
    let c = rusqlite::Connection::open(&path).expect("raw open");
    let version: i64 = c
        .query_row("PRAGMA user_version", [], |r| r.get(0))
        .expect("version");
    assert_eq!(version, SCHEMA_VERSION);
    assert_eq!(SCHEMA_VERSION, 2);
    let old: i64 = c
        .query_row(
            "SELECT count(*) FROM sqlite_master WHERE name = 'identifications'",
            [],
            |r| r.get(0),
        )
        .expect("tables");
    assert_eq!(old, 0, "the old table is dropped");
    let q = |gate: &str| HistoryQuery {
        gate: gate.into(),
        from: None,
        to: None,
        limit: 100,
    };
    let b = s.history(&q("b")).expect("history");
    assert_eq!(
        b.iter().map(|r| r.window_end).collect::<Vec<_>>(),
        [100.0, 102.0, 104.0]
    );
    let a = s.history_rows(&q("a")).expect("rows");
    assert_eq!(a.len(), 2);
    // the summary columns are filled from the old reports
    assert_eq!(a[1].zeta0, Some(0.03));
    assert_eq!(a[1].zeta0_interval, Some((0.03 - 0.01, 0.03 + 0.01)));
    assert_eq!(a[1].frequency_hz, Some(1.5));
    assert!(a[1].trusted);
    // the figures exact, the curve thinned
    let r = s.history(&q("a")).expect("history").remove(1);
    let mut expected = record("a", 103.0, 0.03);
    expected.damping["zeta_eq_curve"] = r.damping["zeta_eq_curve"].clone();
    assert_eq!(r, expected);
    assert_eq!(r.damping["zeta_eq_curve"].as_array().map(Vec::len), Some(9));
    assert_eq!(
        s.alert_states().expect("states").len(),
        1,
        "alert state kept"
    );
    // the migrated file takes new rows after the old ones
    s.write(&WriteBatch {
        identifications: vec![record("a", 103.0, 0.5)],
        ..Default::default()
    })
    .expect("write");
    let a = s.history(&q("a")).expect("history");
    assert_eq!(
        a.iter().map(|r| r.zeta0()).collect::<Vec<_>>(),
        [Some(0.01), Some(0.03), Some(0.5)]
    );
}

/// Times are Unix seconds or RFC 3339; an RFC 3339 time before 1970 is refused by name (the
/// parser's range), never read as 0, and negative Unix seconds stay what they say.
#[test]
fn times_parse_as_unix_seconds_and_rfc3339() {
    use super::parse_time;
    assert_eq!(parse_time("2024-05-01T12:00:00Z"), Ok(1_714_564_800.0));
    assert_eq!(parse_time(" 1714564800.5 "), Ok(1_714_564_800.5));
    assert_eq!(parse_time("1970-01-01T00:00:00Z"), Ok(0.0));
    assert_eq!(parse_time("-1"), Ok(-1.0));
    let e = parse_time("1969-12-31T23:59:59Z").unwrap_err();
    assert!(e.contains("1969-12-31T23:59:59Z"), "{e}");
    let e = parse_time("yesterday").unwrap_err();
    assert!(
        e.contains("neither Unix seconds nor an RFC 3339 time"),
        "{e}"
    );
    assert!(parse_time("NaN").is_err());
}

/// An RFC 3339 offset is applied (it used to be refused as "not an RFC 3339 time").
#[test]
fn rfc3339_offsets_are_the_same_instant() {
    use super::parse_time;
    assert_eq!(parse_time("2024-05-01T14:00:00+02:00"), Ok(1_714_564_800.0));
    assert_eq!(parse_time("2024-05-01T08:30:00-03:30"), Ok(1_714_564_800.0));
    assert_eq!(
        parse_time("2024-05-01T12:00:00.5+00:00"),
        Ok(1_714_564_800.5)
    );
    for bad in ["2024-05-01T14:00:00+25:00", "2024-05-01T14:00:00+02-00"] {
        let e = parse_time(bad).unwrap_err();
        assert!(e.contains("+02:00"), "says offsets are accepted: {e}");
    }
    // a time without an offset is local time somewhere: refused, as ingest refuses it (it
    // was read as UTC, the range shifted by the reader's offset without a word)
    for bad in [
        "2024-05-01T12:00:00",
        "2024-05-01 12:00:00",
        "2024-05-01T12:00:00.5",
    ] {
        let e = parse_time(bad).unwrap_err();
        assert!(e.contains("has no offset"), "{bad}: {e}");
    }
    assert_eq!(parse_time("2024-05-01t12:00:00z"), Ok(1_714_564_800.0));
}

/// A bound below `MIN_USEFUL_SIZE_MB` is valid but warned about, naming the key.
#[test]
fn a_tiny_size_bound_is_warned_about() {
    let tiny = StorageConfig {
        max_size_mb: 3,
        ..Default::default()
    };
    assert!(tiny.validate().is_ok());
    let w = tiny.warnings();
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].starts_with("storage.max_size_mb = 3"), "{w:?}");
    assert!(StorageConfig::default().warnings().is_empty());
    let enough = StorageConfig {
        max_size_mb: MIN_USEFUL_SIZE_MB,
        ..Default::default()
    };
    assert!(enough.warnings().is_empty());
}

/// A write refused by the `max_size_mb` bound says so (SQLite's own words, "database or disk
/// is full", name neither; an operator frees a disk or raises the bound).
#[test]
fn a_full_bound_is_named_as_the_bound_not_the_disk() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store = SqliteStore::open(&dir.path().join("gw.db"), 1).expect("open");
    let mut n = 0;
    let e = loop {
        n += 1;
        let batch = WriteBatch {
            alert_states: vec![(format!("g{n}"), "x".repeat(50_000))],
            ..Default::default()
        };
        if let Err(e) = store.write(&batch) {
            break e;
        }
        assert!(n < 1000, "never full");
    };
    assert!(e.is_full(), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("gw.db") && msg.contains("full"), "{msg}");
    assert!(msg.contains("storage.max_size_mb"), "{msg}");
    assert!(!msg.contains("disk holding"), "{msg}");
}

/// The write probe (run while writes fail and none comes) finds a store full at its size bound
/// full, as a real write does: it rewrote the header page in place, which fits at the bound,
/// so it cleared the failure and `/readyz` said 200 while every identification's write failed
/// (`store_restart`'s full-database test, in a CI rehearsal). Once a page is free again it
/// succeeds.
#[test]
fn the_write_probe_of_a_store_full_at_its_bound_fails_as_full() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store = SqliteStore::open(&dir.path().join("gw.db"), 1).expect("open");
    assert!(matches!(store.probe(), Some(Ok(()))), "an empty store");
    fill_to_the_brim(&store, "g");
    let e = store.probe().expect("a probe").expect_err("a full store");
    assert!(e.is_full(), "{e}");
    assert!(e.to_string().contains("storage.max_size_mb"), "{e}");
    // a gate forgotten frees its pages: the probe passes again
    let forget = WriteBatch {
        forget_gates: vec!["g1".into()],
        ..Default::default()
    };
    store.write(&forget).expect("a forget deletes");
    assert!(matches!(store.probe(), Some(Ok(()))), "{:?}", store.probe());
}

/// Four gates' rows at time `i`, about 1.3 kB each (a 1000-character equation): a few thousand
/// fill a small size bound.
fn fat_batch(i: u32) -> WriteBatch {
    WriteBatch {
        identifications: (0..4)
            .map(|g| {
                let mut r = record(&format!("g{g}"), f64::from(i), 0.01);
                r.equation = "x".repeat(1000);
                r
            })
            .collect(),
        ..Default::default()
    }
}
