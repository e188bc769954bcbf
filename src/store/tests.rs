//! The SQLite store on real files in a temporary directory.

use std::sync::Arc;
use std::time::Duration;

use super::*;

fn record(gate: &str, end: f64, zeta: f64) -> IdentificationRecord {
    IdentificationRecord {
        gate: gate.into(),
        time: end + 0.5,
        window_start: end - 10.0,
        window_end: end,
        equation: format!("ydd + {zeta}*yd + y = 0"),
        coefficients: vec![("c1".into(), zeta), ("k".into(), 1.0)],
        damping: serde_json::json!({"zeta0": zeta, "zeta0_interval": [zeta - 0.01, zeta + 0.01],
            "trusted": true, "frequency_hz": 1.5}),
        verdict: "damped".into(),
        fit_nmae: 0.02,
        path: "full".into(),
    }
}

fn outbox_row(target: &str, fp: &str, status: &str, supersedes: bool) -> NewOutboxRow {
    NewOutboxRow {
        target: target.into(),
        fingerprint: fp.into(),
        status: status.into(),
        created: 100.0,
        batch: 1,
        payload: "{}".into(),
        supersedes,
    }
}

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
fn alert_states_are_replaced_and_forgotten() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = open(&dir);
    let put = |gate: &str, state: &str| WriteBatch {
        alert_states: vec![(gate.into(), state.into())],
        ..Default::default()
    };
    s.write(&put("g1", "a")).expect("write");
    s.write(&put("g2", "b")).expect("write");
    s.write(&put("g1", "c")).expect("write");
    assert_eq!(
        s.alert_states().expect("read"),
        [("g1".into(), "c".into()), ("g2".into(), "b".into())]
    );
    s.write(&WriteBatch {
        forget_gates: vec!["g1".into()],
        ..Default::default()
    })
    .expect("write");
    assert_eq!(s.alert_states().expect("read"), [("g2".into(), "b".into())]);
}

#[test]
fn outbox_keeps_order_supersedes_per_target_and_fingerprint_and_deletes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = open(&dir);
    let ids = s
        .write(&WriteBatch {
            outbox: vec![
                outbox_row("webhook a", "f1", "firing", true),
                outbox_row("webhook b", "f1", "firing", true),
                outbox_row("webhook a", "f1", "resolved", false),
                outbox_row("webhook a", "f2", "firing", true),
            ],
            ..Default::default()
        })
        .expect("write");
    assert_eq!(ids.len(), 4);
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids in order: {ids:?}");
    // a re-fire of f1 for target a supersedes its undelivered firing and resolved
    let newer = s
        .write(&WriteBatch {
            outbox: vec![outbox_row("webhook a", "f1", "firing", true)],
            delivered: vec![ids[3]],
            ..Default::default()
        })
        .expect("write");
    let left: Vec<(i64, String, String)> = s
        .outbox()
        .expect("read")
        .into_iter()
        .map(|r| (r.id, r.row.target, r.row.fingerprint))
        .collect();
    assert_eq!(
        left,
        [
            (ids[1], "webhook b".into(), "f1".into()),
            (newer[0], "webhook a".into(), "f1".into())
        ]
    );
}

#[test]
fn prune_applies_retention_then_the_row_bound() {
    let dir = tempfile::tempdir().expect("tempdir");
    let s = open(&dir);
    s.write(&WriteBatch {
        identifications: (0..20).map(|i| record("g", f64::from(i), 0.0)).collect(),
        ..Default::default()
    })
    .expect("write");
    let p = s.prune(5.0, 10).expect("prune");
    assert_eq!((p.expired, p.over_size), (5, 5));
    let left = s
        .history(&HistoryQuery {
            gate: "g".into(),
            from: None,
            to: None,
            limit: 100,
        })
        .expect("history");
    assert_eq!(left.first().map(|r| r.window_end), Some(10.0));
    assert_eq!(left.len(), 10);
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
fn a_full_database_fails_the_write_and_the_writer_counts_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    // 1 MiB: the bound is SQLite's max_page_count, the same error as a full disk
    let store = Arc::new(SqliteStore::open(&dir.path().join("gw.db"), 1).expect("open"));
    let writer =
        StoreWriter::start(store.clone(), Duration::from_secs(86_400), 1_000_000).expect("writer");
    let (tx, rx) = std::sync::mpsc::channel();
    for i in 0..2000 {
        let tx = tx.clone();
        let mut r = record("g", f64::from(i), 0.0);
        r.equation = "x".repeat(2000);
        writer.submit(
            WriteBatch {
                identifications: vec![r],
                ..Default::default()
            },
            Some(Box::new(move |res| {
                let _ = tx.send(res.is_ok());
            })),
        );
    }
    assert!(writer.close(Duration::from_secs(30)), "flushed");
    let results: Vec<bool> = rx.try_iter().collect();
    assert_eq!(results.len(), 2000, "every callback ran");
    let stats = writer.stats();
    let failed = stats
        .write_failed
        .load(std::sync::atomic::Ordering::Relaxed);
    let lost_in_queue = stats.queue_full.load(std::sync::atomic::Ordering::Relaxed);
    assert!(failed > 0, "the full database failed some writes");
    assert_eq!(
        results.iter().filter(|ok| !**ok).count() as u64,
        failed + lost_in_queue
    );
    assert!(store.size_bytes().expect("size") <= 1024 * 1024);
}
