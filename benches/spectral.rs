//! Throughput of the model-free window analysis and of the gate simulator.

use criterion::{criterion_group, criterion_main, Criterion};
use gatewatch::simulate::{GateParams, GateSimulator, Scenario};
use gatewatch::spectral::{SpectralAnalyzer, WindowOptions};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 1);
    let mut x = vec![0.0; 6000];
    sim.fill(&mut x);
    let mut sa = SpectralAnalyzer::new(x.len(), 200.0).unwrap();
    let opts = WindowOptions::default();
    c.bench_function("analyze_window 30 s @ 200 Hz", |b| {
        b.iter(|| sa.analyze_window(black_box(&x), &opts).unwrap())
    });
    let mut buf = vec![0.0; 200];
    c.bench_function("simulate 1 s @ 200 Hz", |b| {
        b.iter(|| {
            sim.fill(&mut buf);
            black_box(buf[199])
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
