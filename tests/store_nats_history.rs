//! `gatewatch history --nats URL [--nats-prefix P]` (the real binary) against a REAL
//! `nats-server` on loopback (skipped when it is not installed, failed under CI): the same rows
//! written to a SQLite file and to the NATS store print the same, byte for byte (JSON lines and
//! CSV, with and without a range and a limit); the reader leaves the running owner's lease and
//! the history stream's limits as they were; a server that is down, a prefix with no streams
//! and a bad prefix exit 2 with one line naming the server and the prefix, creating nothing.

use std::path::{Path, PathBuf};
use std::time::Duration;

use gatewatch::store::{
    IdentificationRecord, NatsOptions, NatsStore, SqliteStore, Store, WriteBatch,
};

use crate::history_common;
use crate::nats_common;
use history_common::history;
use nats_common::{free_port, nats_installed, NatsServer};

/// 2024-05-01T12:00:00Z.
const T0: f64 = 1_714_564_800.0;
/// Windows of gate g1.
const N: usize = 60;
/// The "daemon's" history stream limits: not the reader's defaults, so that a reader that
/// declared the stream with its own would be seen.
const RETENTION: Duration = Duration::from_secs(7 * 86_400);
const MAX_ROWS: u64 = 123_456;
/// A gate name no subject token may hold as it is (`.`, space, `*`, `>`).
const ODD_GATE: &str = "dam 7/a.b*>";

/// Window `i` of `gate`: zeta0 falling through zero, numbers with long decimal expansions (the
/// two stores keep them as they are, or the outputs differ).
fn record(gate: &str, i: usize) -> IdentificationRecord {
    let z = 0.02 - 0.000_7 * i as f64 + 0.1 / 3.0 * 1e-6;
    let end = T0 + 30.0 * i as f64;
    IdentificationRecord {
        gate: gate.into(),
        time: end + 1.25,
        window_start: end - 10.0,
        window_end: end,
        equation: format!("ydd + {:.5}*yd + 88.8*y = 0", 2.0 * z * 9.42),
        coefficients: vec![
            ("c1".into(), 2.0 * z * 9.42),
            ("c3".into(), 88.8 + 0.1 + 0.2),
        ],
        damping: serde_json::json!({"zeta0": z, "zeta0_interval": [z - 0.004, z + 0.004],
            "trusted": i % 7 != 3, "frequency_hz": 1.5 + i as f64 / 1e3}),
        verdict: if z < 0.0 { "self_excited" } else { "damped" }.into(),
        fit_nmae: 0.03 + i as f64 * 1e-4,
        path: if i % 2 == 0 { "full" } else { "tracked" }.into(),
    }
}

fn batch() -> WriteBatch {
    WriteBatch {
        identifications: (0..N)
            .map(|i| record("g1", i))
            .chain((0..3).map(|i| record(ODD_GATE, i)))
            .collect(),
        ..Default::default()
    }
}

/// The SQLite file with the batch, written through the store and checkpointed.
fn database(dir: &Path) -> PathBuf {
    let path = dir.join("gw.db");
    let store = SqliteStore::open(&path, 64).expect("open the SQLite store");
    store.write(&batch()).expect("write the SQLite history");
    store.checkpoint().expect("checkpoint");
    path
}

/// The store a running daemon holds: prefix `prefix`, the owner lease taken, the history
/// stream with [`RETENTION`] and [`MAX_ROWS`].
fn daemon_store(url: &str, prefix: &str) -> NatsStore {
    NatsStore::open(&NatsOptions {
        prefix: prefix.into(),
        owner_lease: Some(gatewatch::store::NATS_LEASE_TTL),
        ..NatsOptions::new(url, RETENTION, MAX_ROWS)
    })
    .expect("open the NATS store with the owner lease")
}

/// A stream's `(max_age, max_messages)` as the server has it, `None` when it does not exist.
fn stream_limits(url: &str, name: &str) -> Option<(Duration, i64)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let client = async_nats::connect(url).await.expect("connect");
        let js = async_nats::jetstream::new(client);
        match js.get_stream(name).await {
            Ok(mut s) => {
                let info = s.info().await.expect("stream info");
                Some((info.config.max_age, info.config.max_messages))
            }
            Err(_) => None,
        }
    })
}

#[test]
fn history_from_nats_prints_what_the_sqlite_file_prints_and_leaves_the_owner_alone() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let url = server.url();
    let db = database(dir.path());
    let db = db.to_str().expect("UTF-8 path");
    // the daemon: it holds the prefix's lease for the whole test
    let daemon = daemon_store(&url, "PLANT");
    daemon.write(&batch()).expect("write the NATS history");
    let (_, lease) = daemon
        .owner_lease()
        .expect("read the lease")
        .expect("a lease record");
    assert_eq!(lease.pid, std::process::id());
    let limits = Some((RETENTION, i64::try_from(MAX_ROWS).unwrap()));
    assert_eq!(stream_limits(&url, "PLANT_HISTORY"), limits);

    let nats = ["--nats", url.as_str(), "--nats-prefix", "PLANT"];
    let cases: [&[&str]; 7] = [
        &["--gate", "g1"],
        &["--gate", "g1", "--csv"],
        &[
            "--gate",
            "g1",
            "--csv",
            "--from",
            "2024-05-01T12:10:00Z",
            "--to",
            "2024-05-01T12:20:00Z",
        ],
        &["--gate", "g1", "--from", "1714565400", "--limit", "4"],
        &["--gate", "g1", "--csv", "--limit", "1"],
        &["--gate", ODD_GATE, "--csv"],
        &["--gate", ODD_GATE],
    ];
    for args in cases {
        let (code, from_file, err) = history(&[&["--db", db][..], args].concat());
        assert_eq!(code, 0, "--db {args:?}: {err}");
        let (code, from_nats, err) = history(&[&nats[..], args].concat());
        assert_eq!(code, 0, "--nats {args:?}: {err}");
        assert!(!from_file.is_empty(), "{args:?}");
        // line by line first, so that a failure shows the row that differs
        for (i, (n, f)) in from_nats.lines().zip(from_file.lines()).enumerate() {
            assert_eq!(n, f, "{args:?}, line {}", i + 1);
        }
        assert_eq!(from_nats, from_file, "{args:?}");
    }
    // the comparison compares something: the whole history, in order, in both
    let (_, csv, _) = history(&[&nats[..], &["--gate", "g1", "--csv"]].concat());
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), N + 1, "{csv}");
    assert!(
        lines[0].starts_with("gate,time,window_start,window_end,zeta0"),
        "{csv}"
    );
    assert!(lines[1].starts_with(&format!("g1,{},", T0 + 1.25)), "{csv}");
    assert!(lines[N].contains("self_excited"), "{csv}");
    let (_, ranged, _) = history(
        &[
            &nats[..],
            &["--gate", "g1", "--from", "1714565400", "--limit", "4"],
        ]
        .concat(),
    );
    let ends: Vec<f64> = ranged
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("JSON line");
            v["window_end"].as_f64().expect("window_end")
        })
        .collect();
    assert_eq!(
        ends,
        [
            1_714_565_400.0,
            1_714_565_430.0,
            1_714_565_460.0,
            1_714_565_490.0
        ]
    );

    // an unknown gate and an empty range say where they looked: the server and the prefix
    let (code, out, err) = history(&[&nats[..], &["--gate", "nope"]].concat());
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(err.contains("unknown gate `nope`"), "{err}");
    assert!(
        err.contains(&format!(
            "NATS server {url}, prefix PLANT has no identification"
        )),
        "{err}"
    );
    assert!(err.contains(&format!("gates: {ODD_GATE}, g1")), "{err}");
    let (code, _, err) = history(
        &[
            &nats[..],
            &["--gate", "g1", "--from", "2099-01-01T00:00:00Z"],
        ]
        .concat(),
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("no identification between"), "{err}");
    assert!(err.contains("prefix PLANT"), "{err}");

    // the reader left the daemon alone: its lease is the same instance, still live and
    // renewable, its writes go on, and the history stream kept the daemon's limits (a reader
    // that declared the streams would have set its own)
    let (_, after) = daemon
        .owner_lease()
        .expect("read the lease")
        .expect("a lease record");
    assert_eq!(after.instance, lease.instance);
    assert_eq!(
        (after.host.as_str(), after.pid),
        (lease.host.as_str(), lease.pid)
    );
    daemon.check().expect("the daemon still owns the prefix");
    daemon
        .write(&WriteBatch {
            identifications: vec![record("g1", N)],
            ..Default::default()
        })
        .expect("the daemon still writes");
    assert_eq!(stream_limits(&url, "PLANT_HISTORY"), limits);
    let (_, csv, _) = history(&[&nats[..], &["--gate", "g1", "--csv"]].concat());
    assert_eq!(
        csv.lines().count(),
        N + 2,
        "the daemon's new row is read: {csv}"
    );
}

#[test]
fn history_from_nats_refuses_a_down_server_a_missing_prefix_and_bad_flags_with_exit_2() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let one_line = |err: &str| {
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.starts_with("gatewatch: "), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    };

    // nobody listens: the server and the (default) prefix are named
    let down = format!("nats://127.0.0.1:{}", free_port());
    let (code, out, err) = history(&["--nats", &down, "--gate", "g1"]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    one_line(&err);
    assert!(
        err.starts_with(&format!(
            "gatewatch: NATS server {down}, prefix GATEWATCH: cannot connect"
        )),
        "{err}"
    );

    // a server with nothing under the prefix: named, and nothing is created
    let server = NatsServer::start(dir.path());
    let url = server.url();
    for prefix in [None, Some("NOBODY")] {
        let mut args = vec!["--nats", url.as_str(), "--gate", "g1", "--csv"];
        if let Some(p) = prefix {
            args.extend(["--nats-prefix", p]);
        }
        let prefix = prefix.unwrap_or("GATEWATCH");
        let (code, out, err) = history(&args);
        assert_eq!((code, out.as_str()), (2, ""), "{err}");
        one_line(&err);
        assert!(
            err.starts_with(&format!(
                "gatewatch: NATS server {url}, prefix {prefix}: stream {prefix}_HISTORY does not \
                 exist"
            )),
            "{err}"
        );
        for stream in ["HISTORY", "OUTBOX", "ALERTS", "OWNER"] {
            let name = format!("{prefix}_{stream}");
            assert_eq!(stream_limits(&url, &name), None, "{name} was created");
        }
    }

    // a prefix no stream can be named by
    let (code, _, err) = history(&["--nats", &url, "--nats-prefix", "a.b", "--gate", "g1"]);
    assert_eq!(code, 2, "{err}");
    one_line(&err);
    assert!(err.contains("prefix \"a.b\""), "{err}");

    // the flags: one store, named once; the prefix only with --nats
    let db = dir.path().join("gw.db");
    let db = db.to_str().expect("UTF-8 path");
    for (args, wanted) in [
        (
            vec!["--db", db, "--nats", &url, "--gate", "g1"],
            "'--db <DB>' cannot be used with '--nats <URL>'",
        ),
        (
            vec!["--gate", "g1"],
            "required arguments were not provided: <--db <DB>|--nats <URL>>",
        ),
        // with --db the prefix would be ignored: refused instead
        (
            vec!["--db", db, "--nats-prefix", "X", "--gate", "g1"],
            "'--db <DB>' cannot be used with '--nats-prefix <PREFIX>'",
        ),
        (
            vec!["--nats-prefix", "X", "--gate", "g1"],
            "required arguments were not provided",
        ),
    ] {
        let (code, out, err) = history(&args);
        assert_eq!((code, out.as_str()), (2, ""), "{args:?}: {err}");
        assert!(err.starts_with("gatewatch: "), "{args:?}: {err}");
        assert!(err.contains(wanted), "{args:?}: {err}");
    }
}
