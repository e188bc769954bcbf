//! Throughput of the model-free window analysis, of the prediction-error reading of a departed
//! window, and of the gate simulator.

use criterion::{criterion_group, criterion_main, Criterion};
use gatewatch::analysis::prediction_error_zeta;
use gatewatch::simulate::{
    GateParams, GatePreset, GateSimulator, NoiseLevel, Scenario, ScenarioName,
};
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
    // the window that ends at 165 s of the lock gate's onset (true mean -0.67 %), 10 s at
    // 100 Hz, and the lab gate's, 10 s at 200 Hz: what a departed window costs the worker
    for preset in [GatePreset::Lock, GatePreset::Lab] {
        let p = preset.params();
        let mut onset = ScenarioName::Onset
            .def(&p)
            .simulator(&p, NoiseLevel::Relative(0.125), 1)
            .unwrap();
        while onset.time() < -1e-9 {
            onset.next_sample();
        }
        let mut w = vec![0.0; (165.0 * p.rate_hz) as usize];
        onset.fill(&mut w);
        let window = &w[w.len() - (10.0 * p.rate_hz) as usize..];
        let omega = (p.stiffness / p.mass).sqrt();
        c.bench_function(
            &format!(
                "prediction_error_zeta 10 s @ {} Hz ({})",
                p.rate_hz,
                preset.as_str()
            ),
            |b| b.iter(|| prediction_error_zeta(black_box(window), p.rate_hz, omega)),
        );
    }
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
