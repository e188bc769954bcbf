//! Cost of one integration as the differential evolution sees it: the Van der Pol oscillator
//! `y'' + (-1.2218 + 1.2218 y^2) y' + y = 0` from (0.5, 0) over 250 uniformly spaced times on
//! [0, 30], with each method at the settings the identification uses.
//!
//! Criterion reports the time per integration and, through `Throughput::Elements(rhs_evals)`,
//! right-hand-side evaluations per second; the summary printed first divides a plain timing
//! loop by `rhs_evals` to give nanoseconds per evaluation directly.
//!
//! Run: `cargo bench --bench ode` (add `-- --quick` for a short run).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gatewatch::ode::{integrate, Method, Options, System};
use std::hint::black_box;
use std::ops::ControlFlow;
use std::time::Instant;

struct VanDerPol;

impl System<2> for VanDerPol {
    #[inline]
    fn rhs(&self, _t: f64, y: &[f64; 2], dy: &mut [f64; 2]) {
        dy[0] = y[1];
        dy[1] = -(-1.2218 + 1.2218 * y[0] * y[0]) * y[1] - y[0];
    }
}

fn times() -> Vec<f64> {
    (0..250).map(|i| 30.0 * i as f64 / 249.0).collect()
}

fn settings() -> [(Method, Options); 3] {
    let base = Options::default();
    [
        (Method::Dopri5, Options { rtol: 1e-3, ..base }),
        (
            Method::Rk4,
            Options {
                substeps: 2,
                ..base
            },
        ),
        (Method::Rosenbrock, Options { rtol: 1e-3, ..base }),
    ]
}

/// One integration, folding the delivered states into a checksum so nothing is optimised away.
#[inline(never)]
fn one(method: Method, times: &[f64], opts: &Options) -> (f64, usize) {
    let mut sum = 0.0;
    let outcome = integrate(method, &VanDerPol, [0.5, 0.0], times, opts, |_, y| {
        sum += y[0];
        ControlFlow::Continue(())
    });
    assert!(outcome.is_complete());
    (sum, outcome.stats.rhs_evals)
}

fn bench(c: &mut Criterion) {
    let times = times();
    println!("method   rhs_evals  ns/integration  ns/rhs_eval   (plain loop, 20000 runs)");
    for (method, opts) in settings() {
        let (_, evals) = one(method, &times, &opts);
        let runs = 20_000;
        let start = Instant::now();
        for _ in 0..runs {
            black_box(one(method, black_box(&times), &opts));
        }
        let ns = start.elapsed().as_nanos() as f64 / runs as f64;
        println!(
            "{:<8} {:>9}  {:>14.0}  {:>11.2}",
            method.name(),
            evals,
            ns,
            ns / evals as f64
        );
    }
    let mut group = c.benchmark_group("vdp_250_samples");
    for (method, opts) in settings() {
        let (_, evals) = one(method, &times, &opts);
        group.throughput(Throughput::Elements(evals as u64));
        group.bench_function(method.name(), |b| {
            b.iter(|| one(method, black_box(&times), &opts))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
