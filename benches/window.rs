//! One 10 s force window of the daemon's default gate (200 Hz, model
//! `c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0`, population 20 x 40 generations): analysed cold (the
//! full search, `Analyzer::analyze`) and tracked (`Analyzer::analyze_tracked` with the gate's
//! memory after the previous, half-overlapping window), as `gatewatch bench daemon` section 2
//! runs them, on the seeded simulator's stable lab gate.
//!
//! Run: `cargo bench --bench window -- --warm-up-time 1 --measurement-time 5`.
//! Profile the tracked path alone (no analysis by criterion, a fixed time in the routine):
//! `perf record -g target/release/deps/window-<hash> --bench --profile-time 20 tracked`.

use criterion::{criterion_group, criterion_main, Criterion};
use gatewatch::analysis::{Analyzer, Path, Previous, WindowInput};
use gatewatch::service::config::Config;
use gatewatch::simulate::{GateParams, GateSimulator, Scenario};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let config = Config::embedded();
    let analyzer = Analyzer::new(config.defaults.analysis_settings())
        .expect("analyzer")
        .with_tracking(config.defaults.tracking.clone())
        .expect("tracking");
    let n = config.defaults.window_samples();
    let hop = config.defaults.every_samples();
    let rate = config.defaults.rate_hz;
    let mut sim = GateSimulator::scenario(GateParams::default(), Scenario::Stable, 1);
    let mut signal = vec![0.0; n + 8 * hop];
    sim.fill(&mut signal);
    let input = |w: usize| WindowInput {
        t0: (w * hop) as f64 / rate,
        rate_hz: rate,
        values: &signal[w * hop..w * hop + n],
        history: &[],
    };
    // The memory after the first windows, as the worker pool carries it; the window benched as
    // tracked is the first after it that takes the tracked path.
    let mut previous: Option<Previous> = None;
    let mut tracked = None;
    for w in 0..8 {
        let seed = (w * hop + n) as u64;
        let a = analyzer
            .analyze_tracked(input(w), previous.as_ref(), seed)
            .expect("window");
        if a.path == Path::Tracked && tracked.is_none() {
            tracked = Some((w, previous.clone().expect("tracked after a window")));
        }
        let t0 = input(w).t0;
        previous = Some(Previous::after(
            previous.as_ref(),
            &a,
            t0,
            t0 + (n - 1) as f64 / rate,
        ));
    }
    let (w, memory) = tracked.expect("no window of the stable gate was tracked");
    let seed = (w * hop + n) as u64;
    println!("window {w} is tracked after the memory of window {}", w - 1);

    let mut group = c.benchmark_group("window");
    group.sample_size(10);
    group.bench_function("cold", |b| {
        b.iter(|| black_box(analyzer.analyze(input(w), None, seed).expect("cold")))
    });
    group.bench_function("tracked", |b| {
        b.iter(|| {
            let a = analyzer
                .analyze_tracked(input(w), Some(&memory), seed)
                .expect("tracked");
            assert_eq!(a.path, Path::Tracked);
            black_box(a)
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
