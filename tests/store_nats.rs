//! The NATS JetStream store ([`NatsStore`]) against a REAL `nats-server` on loopback (skipped
//! when it is not installed, failed under CI): the shared store checks (`store_conformance`),
//! run on the SQLite store too so the two cannot drift; the data surviving a restart of the
//! server on the same store directory; a server that is down giving, within the timeout, an
//! error naming its URL.

use std::time::{Duration, Instant};

use gatewatch::store::{
    HistoryQuery, NatsOptions, NatsStore, SqliteStore, Store, StoreError, WriteBatch,
};

mod nats_common;
mod store_conformance;
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
        // with the owner lease `serve` takes: its checks must not get in the way
        let s = NatsStore::open(&NatsOptions {
            prefix: format!("CHECK{i}"),
            owner_lease: Some(gatewatch::store::NATS_LEASE_TTL),
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
