//! Cost of the damping trend's fit (`analysis::fit_trend`), which the daemon runs on every
//! trusted window of every gate: the weighted robust line, its scale, and the slope's overlap
//! factor over every pair of figures whose records overlap (`analysis::trend`).
//!
//! Figures every 5 s, each with a 20 s record (`lag` 10 s: the 5 Hz lock gate's 100 cycles),
//! a 1.5-point interval and a drift with scatter, for the default 10-minute horizon (120
//! figures), an hour (720) and the cap (`MAX_TREND_POINTS`, 1024).
//!
//! Run: `cargo bench --bench trend -- --warm-up-time 1 --measurement-time 5`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gatewatch::analysis::{fit_trend, TrendPoint, MAX_TREND_POINTS};
use std::hint::black_box;

fn points(n: usize, lag: f64) -> Vec<TrendPoint> {
    (0..n)
        .map(|i| {
            let t = 5.0 * i as f64;
            // a deterministic scatter of about half a point about a slow decline
            let zeta0 = 2.0 - 0.002 * t + 0.5 * (0.7 * i as f64).sin();
            TrendPoint {
                t,
                lag,
                zeta0,
                low: zeta0 - 0.75,
                high: zeta0 + 0.75,
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("fit_trend");
    for n in [120, 720, MAX_TREND_POINTS] {
        for lag in [10.0, 25.0] {
            let p = points(n, lag);
            group.bench_with_input(
                BenchmarkId::new(format!("record {} s", 2.0 * lag), n),
                &p,
                |b, p| b.iter(|| fit_trend(black_box(p), 0.0)),
            );
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
