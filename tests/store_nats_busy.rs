//! The NATS store read while a writer is busy, against a REAL `nats-server` (skipped when it
//! is not installed, failed under CI): a reader of the alert states, the outbox and a gate's
//! history, on its own connection as `gatewatch history --nats` and the e2e tests read, while a
//! writer replaces two gates' alert states, supersedes outbox rows and appends history rows
//! every 2 ms. Every read answers well inside the call timeout and sees both gates.
//!
//! Before `read::read_each` ended at the stream's last sequence at its start and the alert
//! states were read by subject, these reads chased the writer (the consumer's count of what is
//! left grows with every write, and nats-server 2.9 holds a no-wait fetch whose counted
//! messages were deleted until the next write arrives): 12 to 15 of them in 30 s ran into a 2 s
//! timeout (docs/benchmarks.md, "NATS reads that chased their writer").

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gatewatch::store::{HistoryQuery, NatsOptions, NatsStore, Store, WriteBatch};

use crate::nats_common;
use crate::store_conformance;
use nats_common::{nats_installed, NatsServer};
use store_conformance::{outbox_row, record};

/// The reader's call timeout: a chase or a held fetch runs into it.
const READ_TIMEOUT: Duration = Duration::from_secs(2);
/// How long the reader reads while the writer writes.
const BUSY: Duration = Duration::from_secs(5);
/// The writer's pause between two writes.
const WRITE_PAUSE: Duration = Duration::from_millis(2);

#[test]
fn reads_end_while_a_writer_replaces_and_appends() {
    if !nats_installed() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let server = NatsServer::start(dir.path());
    let writer = NatsStore::open(&NatsOptions {
        prefix: "BUSY".into(),
        ..NatsOptions::new(&server.url(), Duration::from_secs(3600), 1_000_000)
    })
    .expect("open the writer's store");
    let reader = NatsStore::open_read_only(&server.url(), "BUSY", READ_TIMEOUT)
        .expect("open the reader's store");
    let first = WriteBatch {
        alert_states: vec![("g0".into(), "{}".into()), ("g1".into(), "{}".into())],
        ..Default::default()
    };
    writer.write(&first).expect("first write");

    let stop = Arc::new(AtomicBool::new(false));
    let writing = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut writes = 0u32;
            while !stop.load(Ordering::Relaxed) {
                let k = writes % 2;
                let batch = WriteBatch {
                    identifications: vec![record("g0", f64::from(writes), 0.02)],
                    alert_states: vec![(format!("g{k}"), format!("{{\"write\":{writes}}}"))],
                    outbox: vec![outbox_row("webhook x", &format!("f{k}"), "firing", true)],
                    ..Default::default()
                };
                writer.write(&batch).expect("write");
                writes += 1;
                std::thread::sleep(WRITE_PAUSE);
            }
            writes
        })
    };

    let query = HistoryQuery {
        gate: "g0".into(),
        from: None,
        to: None,
        limit: 10,
    };
    let (mut reads, mut slowest) = (0, Duration::ZERO);
    let started = Instant::now();
    while started.elapsed() < BUSY {
        let t = Instant::now();
        let states = reader.alert_states().expect("alert states");
        let gates: Vec<&str> = states.iter().map(|(g, _)| g.as_str()).collect();
        assert_eq!(gates, ["g0", "g1"], "read {reads}");
        // two fingerprints, each row superseded by the next (a read between a supersede's
        // publication and its deletion may see both)
        let outbox = reader.outbox().expect("outbox");
        assert!(outbox.len() <= 4, "{} outbox rows", outbox.len());
        // the oldest rows of the gate, in order
        let rows = reader.history_rows(&query).expect("history");
        let ends: Vec<f64> = rows.iter().map(|r| r.window_end).collect();
        let expected: Vec<f64> = (0..ends.len()).map(|i| i as f64).collect();
        assert_eq!(ends, expected, "read {reads}");
        slowest = slowest.max(t.elapsed());
        reads += 1;
    }
    stop.store(true, Ordering::Relaxed);
    let writes = writing.join().expect("the writer");
    eprintln!("{reads} reads of three kinds, slowest {slowest:?}, beside {writes} writes");
    // the writer was busy throughout (one write per 2 ms pause and its round trip)
    assert!(writes >= 100, "only {writes} writes in {BUSY:?}");
    assert!(reads >= 10, "only {reads} reads in {BUSY:?}");
}
