//! Does the hand-written line-protocol parser earn its place? (issue 11)
//!
//! The daemon's workload: Telegraf-like bodies of 1000 lines (Telegraf's default
//! `metric_batch_size`), 4 gates at 200 Hz interleaved (10 s of 4 gates is 8 such bodies),
//! plain `m,gate=gNN force=123.456 1700000000000000000` lines and lines with extra tags and
//! fields. Each variant turns the body into the same per-gate samples with the same checks:
//! - `gatewatch`: `line_protocol::parse` + `to_batches`, as the daemon runs them;
//! - `crate per line`: the `influxdb-line-protocol` crate on each `\n`-split line, then the
//!   same grouping, checks and line numbers (`tests/lp_common`), i.e. the same work;
//! - `crate whole body`: the crate's own splitter over the body, no line numbers (less work:
//!   the crate's best case).
//!
//! Throughput is in lines; ns/line is the reported time per body / 1000. Agreement of the
//! variants is tested in `tests/line_protocol_crate.rs`.

#[path = "../tests/lp_common/mod.rs"]
mod lp_common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gatewatch::service::config::Precision;
use gatewatch::service::ingest::line_protocol::{parse, parse_to_batches, to_batches, Mapping};
use lp_common::{crate_to_batches, crate_whole_body, telegraf_body};
use std::hint::black_box;

/// Lines per body (Telegraf's default batch size).
const LINES: usize = 1000;
/// Gates interleaved in a body.
const GATES: usize = 4;
/// Sample rate of each gate.
const RATE_HZ: f64 = 200.0;

fn bench(c: &mut Criterion) {
    let fields = vec!["force".to_string()];
    let m = Mapping {
        gate_tag: "gate",
        value_fields: &fields,
        precision: Precision::Ns,
        now: 0.0,
        max_gates: usize::MAX,
    };
    for (name, extra) in [("plain", false), ("extra tags+fields", true)] {
        let body = telegraf_body(LINES, GATES, RATE_HZ, 0, extra);
        let mut g = c.benchmark_group(format!("line_protocol {name}, {LINES} lines"));
        g.throughput(Throughput::Elements(LINES as u64));
        g.bench_function("gatewatch", |b| {
            b.iter(|| {
                let lines = parse(black_box(&body)).expect("valid body");
                to_batches(&lines, &m).expect("valid samples")
            })
        });
        g.bench_function("crate per line", |b| {
            b.iter(|| crate_to_batches(black_box(&body), &m).expect("valid body"))
        });
        g.bench_function("crate whole body", |b| {
            b.iter(|| crate_whole_body(black_box(&body), &m).expect("valid body"))
        });
        g.finish();
    }
    // a hostile body: every line another gate (the daemon refuses it past `max_gates`, but
    // only once it is parsed): linear since the batches are indexed, about 30 s before
    let many: String = (0..MANY_GATES)
        .map(|i| format!("m,gate=g{i} force=1 1700000000000000000\n"))
        .collect();
    let mut g = c.benchmark_group(format!("line_protocol {MANY_GATES} gates, one line each"));
    g.throughput(Throughput::Elements(MANY_GATES as u64));
    g.sample_size(10);
    g.bench_function("gatewatch", |b| {
        b.iter(|| parse_to_batches(black_box(&many), &m).expect("valid body"))
    });
    g.finish();
}

/// Lines (each its own gate) of the hostile body: about 4 MB, the default body limit.
const MANY_GATES: usize = 95_000;

criterion_group!(benches, bench);
criterion_main!(benches);
