//! Reads of the NATS store beside a busy writer, against a running `nats-server -js` (figures
//! in docs/benchmarks.md, "NATS reads that chased their writer"): two threads replace two
//! gates' alert states (or, with `outbox`, supersede two outbox rows) with a pause between
//! writes, while the main thread reads them back on its own connection with a short call
//! timeout, as `gatewatch history --nats` and the e2e tests read beside a daemon. Prints the
//! reads, how many failed, the slowest, and the writes.
//!
//! ```sh
//! nats-server -js -p 14222 -sd /tmp/js &
//! cargo run --release --example nats_busy_reads -- nats://127.0.0.1:14222 30 2000 2 [outbox]
//! #                                                  server               s  pause_us timeout_s
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gatewatch::store::{NatsOptions, NatsStore, NewOutboxRow, Store, WriteBatch};

/// The prefix of the streams this program writes (its own, beside any daemon's).
const PREFIX: &str = "BUSYREADS";

/// Argument `i`, or `default`; exits naming the argument when it does not parse.
fn arg<T: std::str::FromStr>(i: usize, name: &str, default: T) -> T {
    match std::env::args().nth(i) {
        None => default,
        Some(s) => s.parse().unwrap_or_else(|_| {
            eprintln!("argument {i} ({name}): cannot read {s:?}");
            std::process::exit(2)
        }),
    }
}

/// Writer `k`'s `n`-th write: its gate's alert state, or its fingerprint's outbox row.
fn write_of(k: u32, n: u64, outbox: bool) -> WriteBatch {
    if outbox {
        WriteBatch {
            outbox: vec![NewOutboxRow {
                target: "webhook x".into(),
                fingerprint: format!("f{k}"),
                status: "firing".into(),
                created: 1.0,
                batch: n,
                payload: "{}".into(),
                supersedes: true,
            }],
            ..Default::default()
        }
    } else {
        WriteBatch {
            alert_states: vec![(format!("g{k}"), format!("{{\"write\":{n}}}"))],
            ..Default::default()
        }
    }
}

fn main() {
    let url: String = arg(1, "server URL", "nats://127.0.0.1:4222".to_string());
    let seconds: f64 = arg(2, "seconds", 30.0);
    let pause = Duration::from_micros(arg(3, "pause between writes, us", 2000));
    let timeout = Duration::from_secs_f64(arg(4, "read timeout, s", 2.0));
    let outbox = std::env::args().nth(5).as_deref() == Some("outbox");
    let options = NatsOptions {
        prefix: PREFIX.into(),
        ..NatsOptions::new(&url, Duration::from_secs(3600), 100_000)
    };
    let writer = Arc::new(NatsStore::open(&options).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    }));
    let reader = NatsStore::open_read_only(&url, PREFIX, timeout).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    });
    let stop = Arc::new(AtomicBool::new(false));
    let writers: Vec<_> = (0..2)
        .map(|k| {
            let (writer, stop) = (writer.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut n = 0;
                while !stop.load(Ordering::Relaxed) {
                    n += 1;
                    if let Err(e) = writer.write(&write_of(k, n, outbox)) {
                        eprintln!("write: {e}");
                    }
                    std::thread::sleep(pause);
                }
                n
            })
        })
        .collect();
    let started = Instant::now();
    let (mut reads, mut failed, mut slowest) = (0, 0, Duration::ZERO);
    while started.elapsed().as_secs_f64() < seconds {
        let t = Instant::now();
        let read = if outbox {
            reader.outbox().map(|rows| rows.len())
        } else {
            reader.alert_states().map(|states| states.len())
        };
        if let Err(e) = read {
            failed += 1;
            eprintln!("after {:.2} s: {e}", t.elapsed().as_secs_f64());
        }
        slowest = slowest.max(t.elapsed());
        reads += 1;
    }
    stop.store(true, Ordering::Relaxed);
    let writes: u64 = writers.into_iter().map(|w| w.join().unwrap_or(0)).sum();
    println!(
        "reads {reads} failed {failed} slowest {:.3} s writes {writes}",
        slowest.as_secs_f64()
    );
}
