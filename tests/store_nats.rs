//! The NATS JetStream store ([`NatsStore`]) against a REAL `nats-server` on loopback (skipped
//! when it is not installed, failed under CI): the shared store checks (`store_conformance`),
//! run on the SQLite store too so the two cannot drift; the data surviving a restart of the
//! server on the same store directory; a server that is down giving, within the timeout, an
//! error naming its URL.

use std::time::{Duration, Instant};

use gatewatch::store::{
    HistoryQuery, NatsOptions, NatsStore, SqliteStore, Store, StoreError, WriteBatch,
};

use crate::nats_common;
use crate::store_conformance;
use nats_common::{nats_installed, NatsServer};
use store_conformance::{record, CHECKS};

/// The call timeout of the tests' stores: short, so the server-down checks are quick.
const TEST_TIMEOUT: Duration = Duration::from_secs(2);

fn options(url: &str) -> NatsOptions {
    NatsOptions {
        timeout: TEST_TIMEOUT,
        ..NatsOptions::new(url, Duration::from_secs(3600), 1_000_000)
    }
}

#[test]
fn the_sqlite_store_passes_the_store_checks() {
    for (name, check) in CHECKS {
        let dir = tempfile::tempdir().expect("tempdir");
        let s = SqliteStore::open(&dir.path().join("gw.db"), 64).expect("open");
        eprintln!("sqlite: {name}");
        check(&s);
    }
}

#[test]
fn the_nats_store_passes_the_store_checks() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    for (i, (name, check)) in CHECKS.iter().enumerate() {
        // each check on streams of its own
        // with the owner lease and the default gates' sample lead `serve` opens it with:
        // neither may get in the way of the checks
        let s = NatsStore::open(&NatsOptions {
            prefix: format!("CHECK{i}"),
            owner_lease: Some(gatewatch::store::NATS_LEASE_TTL),
            sample_lead: Some(Duration::from_secs(600)),
            ..options(&server.url())
        })
        .expect("open");
        eprintln!("nats: {name}");
        check(&s);
    }
}

#[test]
fn history_alert_state_and_outbox_survive_a_restart_of_the_server() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut server = NatsServer::start(dir.path());
    let url = server.url();
    let ids = {
        let s = NatsStore::open(&options(&url)).expect("open");
        s.write(&WriteBatch {
            identifications: vec![record("g1", 100.0, 0.02), record("g1", 105.0, -0.01)],
            alert_states: vec![("g1".into(), "{\"state\":\"firing\"}".into())],
            outbox: vec![gatewatch::store::NewOutboxRow {
                target: "webhook http://x".into(),
                fingerprint: "f".into(),
                status: "firing".into(),
                created: 1.0,
                batch: 3,
                payload: "{\"a\":1}".into(),
                supersedes: true,
            }],
            ..Default::default()
        })
        .expect("write")
    };
    server.restart();
    let s = NatsStore::open(&options(&url)).expect("open after the restart");
    let rows = s
        .history(&HistoryQuery {
            gate: "g1".into(),
            from: None,
            to: None,
            limit: 10,
        })
        .expect("history");
    assert_eq!(
        rows,
        [record("g1", 100.0, 0.02), record("g1", 105.0, -0.01)]
    );
    assert_eq!(
        s.alert_states().expect("states"),
        [("g1".to_string(), "{\"state\":\"firing\"}".to_string())]
    );
    let outbox = s.outbox().expect("outbox");
    assert_eq!(outbox.len(), 1);
    assert_eq!((outbox[0].id, outbox[0].row.batch), (ids[0], 3));
    assert!(s.location().contains(&url), "{}", s.location());
}

/// The error of a call to a server that is down: a `StoreError` naming the URL, within the
/// timeout (and a margin for a loaded machine), never a hang.
fn assert_down_error<T: std::fmt::Debug>(
    what: &str,
    url: &str,
    started: Instant,
    r: Result<T, StoreError>,
) {
    let e = r.expect_err(what);
    let message = e.to_string();
    assert!(message.contains(url), "{what}: {message}");
    assert!(
        started.elapsed() < TEST_TIMEOUT + Duration::from_secs(3),
        "{what}: took {:?}",
        started.elapsed()
    );
}

#[test]
fn a_server_that_is_down_gives_an_error_naming_its_url_within_the_timeout() {
    if !nats_installed() {
        return;
    }
    // nothing listens: the open fails
    let url = format!("nats://127.0.0.1:{}", nats_common::free_port());
    let started = Instant::now();
    let open = NatsStore::open(&options(&url));
    if let Err(e) = &open {
        // a server, not a file ("storage file NATS server ..." before)
        assert!(
            e.to_string()
                .starts_with(&format!("storage NATS server {url}")),
            "{e}"
        );
    }
    assert_down_error("open", &url, started, open);

    // the server goes away after the open: each call fails, then works again once it is back
    let dir = tempfile::tempdir().expect("tempdir");
    let mut server = NatsServer::start(dir.path());
    let url = server.url();
    let s = NatsStore::open(&options(&url)).expect("open");
    server.stop();
    let batch = WriteBatch {
        alert_states: vec![("g".into(), "s".into())],
        ..Default::default()
    };
    let started = Instant::now();
    assert_down_error("write", &url, started, s.write(&batch));
    let started = Instant::now();
    assert_down_error("alert states", &url, started, s.alert_states());
    server.restart();
    let deadline = Instant::now() + Duration::from_secs(20);
    // the client reconnects by itself
    while s.write(&batch).is_err() {
        assert!(Instant::now() < deadline, "no reconnection");
        std::thread::sleep(Duration::from_millis(200));
    }
    assert_eq!(
        s.alert_states().expect("states"),
        [("g".to_string(), "s".to_string())]
    );
}

#[test]
fn the_history_stream_keeps_at_most_max_history_rows() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let s = NatsStore::open(&NatsOptions {
        max_history_rows: 5,
        ..options(&server.url())
    })
    .expect("open");
    s.write(&WriteBatch {
        identifications: (0..8).map(|i| record("g", f64::from(i), 0.0)).collect(),
        ..Default::default()
    })
    .expect("write");
    let ends: Vec<f64> = s
        .latest_history_rows("g", 100)
        .expect("rows")
        .iter()
        .map(|r| r.window_end)
        .collect();
    assert_eq!(ends, [3.0, 4.0, 5.0, 6.0, 7.0], "the oldest went first");
}

/// The streams' limits follow the options at every open: a daemon restarted with fewer
/// history rows (or another retention) changes the stream it finds, and one restarted with
/// the same options finds it as it was (`ops::ensure` changes a stream only when its limits
/// differ: an update racing another client's create kills Debian's nats-server 2.9).
#[test]
fn a_reopen_with_other_limits_changes_the_streams_and_one_with_the_same_keeps_them() {
    use futures_util::StreamExt;
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let open = |rows: u64, retention_seconds: u64| {
        NatsStore::open(&NatsOptions {
            max_history_rows: rows,
            retention: Duration::from_secs(retention_seconds),
            ..options(&server.url())
        })
        .expect("open")
    };
    let ends = |s: &NatsStore| -> Vec<f64> {
        s.latest_history_rows("g", 100)
            .expect("rows")
            .iter()
            .map(|r| r.window_end)
            .collect()
    };
    // the server's advisories of changed streams, read by a client of our own
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    // the client's tasks live on this runtime, and so does its drop at the end
    let _context = rt.enter();
    let mut updated = rt.block_on(async {
        let client = async_nats::connect(server.url()).await.expect("connect");
        let sub = client
            .subscribe("$JS.EVENT.ADVISORY.STREAM.UPDATED.>")
            .await
            .expect("subscribe");
        client.flush().await.expect("flush");
        (client, sub)
    });
    // the streams changed since the last call, by name (waiting 500 ms for stragglers)
    let mut changed = || -> Vec<String> {
        rt.block_on(async {
            let mut names = Vec::new();
            while let Ok(Some(m)) =
                tokio::time::timeout(Duration::from_millis(500), updated.1.next()).await
            {
                names.push(
                    m.subject
                        .as_str()
                        .rsplit('.')
                        .next()
                        .unwrap_or("")
                        .to_string(),
                );
            }
            names
        })
    };
    let s = open(5, 3600);
    s.write(&WriteBatch {
        identifications: (0..8).map(|i| record("g", f64::from(i), 0.0)).collect(),
        ..Default::default()
    })
    .expect("write");
    drop(s);
    assert_eq!(changed(), Vec::<String>::new(), "created, not changed");
    // the same options: nothing is changed, and the five rows are still there
    let s = open(5, 3600);
    assert_eq!(changed(), Vec::<String>::new(), "the same limits");
    assert_eq!(ends(&s), [3.0, 4.0, 5.0, 6.0, 7.0]);
    drop(s);
    // fewer rows: the history stream is changed at the open and keeps the newest three
    let s = open(3, 7200);
    assert_eq!(changed(), ["GATEWATCH_HISTORY"]);
    assert_eq!(ends(&s), [5.0, 6.0, 7.0]);
    s.write(&WriteBatch {
        identifications: vec![record("g", 8.0, 0.0)],
        ..Default::default()
    })
    .expect("write");
    assert_eq!(ends(&s), [6.0, 7.0, 8.0]);
}

/// A history message that is not a row (written by something else on the subject) is a decode
/// error naming the message and the gate, for a range and for the newest rows alike; not a
/// server's failure, and not a row silently dropped.
#[test]
fn a_history_message_that_is_no_row_is_a_decode_error_naming_it() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let s = NatsStore::open(&options(&server.url())).expect("open");
    s.write(&WriteBatch {
        identifications: vec![record("g", 1.0, 0.01)],
        ..Default::default()
    })
    .expect("write");
    let subject = format!(
        "GATEWATCH.history.{}",
        gatewatch::store::encode_nats_name("g")
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let client = async_nats::connect(server.url()).await.expect("connect");
        let js = async_nats::jetstream::new(client);
        js.publish(subject, "not a row".into())
            .await
            .expect("publish")
            .await
            .expect("ack");
    });
    let q = HistoryQuery {
        gate: "g".into(),
        from: None,
        to: None,
        limit: 10,
    };
    for e in [
        s.history_rows(&q).expect_err("a range over it"),
        s.latest_history_rows("g", 1).expect_err("the newest row"),
    ] {
        assert!(matches!(e, StoreError::Decode { .. }), "{e:?}");
        let text = e.to_string();
        assert!(text.contains("history message 2 of gate g"), "{text}");
    }
}

/// Unix seconds now.
fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64()
}

/// With `sample_lead` (the daemon's gates bound how far ahead of its clock a sample may be), a
/// range reads the gate's subject only from the messages stored since `from - lead - margin`:
/// a row that claims to end later than its writer's clock allowed and was stored before that
/// instant is not read (which is how the shortcut is seen to work), a backfilled row stored
/// later is, and a reader that does not know the bound reads the whole subject.
#[test]
fn a_range_reads_from_the_messages_stored_since_its_start() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let s = NatsStore::open(&NatsOptions {
        owner_lease: Some(gatewatch::store::NATS_LEASE_TTL),
        sample_lead: Some(Duration::ZERO),
        clock_margin: Duration::from_millis(500),
        ..options(&server.url())
    })
    .expect("open");
    let t0 = unix_now();
    let write = |end: f64| {
        s.write(&WriteBatch {
            identifications: vec![record("g", end, 0.01)],
            ..Default::default()
        })
        .expect("write")
    };
    // stored at t0, claiming an end 50 s ahead: against the contract
    write(t0 + 50.0);
    std::thread::sleep(Duration::from_millis(2500));
    let t1 = unix_now();
    // stored at t1: a window ending 60 s ahead, and one of yesterday (a backfill)
    write(t0 + 60.0);
    write(t0 - 86_400.0);
    let ends = |store: &NatsStore, from: f64| -> Vec<f64> {
        let q = HistoryQuery {
            gate: "g".into(),
            from: Some(from),
            to: None,
            limit: 10,
        };
        let rows = store.history_rows(&q).expect("history");
        rows.iter().map(|r| r.window_end - t0).collect()
    };
    // from t1: the read starts at t1 - 0.5 s, after the first message was stored
    assert_eq!(
        ends(&s, t1),
        [60.0],
        "the message stored before the start is not read"
    );
    // from two days back: every message is stored after its start; the backfill included
    assert_eq!(ends(&s, t0 - 2.0 * 86_400.0), [-86_400.0, 50.0, 60.0]);
    // a reader beside the daemon does not know the gates' bound: the whole subject
    let reader =
        NatsStore::open_read_only(&server.url(), "GATEWATCH", TEST_TIMEOUT).expect("reader");
    assert_eq!(ends(&reader, t1), [50.0, 60.0]);
}
