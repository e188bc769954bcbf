//! Cost of one fitness evaluation as the differential evolution pays it: van_der_pol_2 (500
//! samples on [0, 30], split 50 % with split seed 1, so 250 training samples), its true
//! coefficients perturbed by 1 %, known initial conditions, per fitness solver at the
//! identification's settings (dopri5 rtol 1e-3, rk4 with 2 substeps, stiff rtol 1e-3).
//!
//! Criterion reports the time per evaluation. Printed once per solver before it: the
//! right-hand-side evaluations of one integration with the fitness's options (counted by
//! integrating once with `gatewatch::ode::integrate` and reading `Outcome::stats.rhs_evals`) and
//! the nanoseconds per right-hand-side evaluation (time per fitness evaluation / that count).
//!
//! Run: `cargo bench --bench fitness -- --warm-up-time 1 --measurement-time 3`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gatewatch::cases;
use gatewatch::de::Objective;
use gatewatch::identify::{self, Fitness, Initial, Output, Problem, Search};
use gatewatch::model::Bound;
use gatewatch::ode::{integrate, Method, Options};
use std::hint::black_box;
use std::ops::ControlFlow;
use std::time::Instant;

const RTOL: f64 = 1e-3;
const SUBSTEPS: usize = 2;

fn bench(c: &mut Criterion) {
    let case = cases::find("van_der_pol_2").expect("case van_der_pol_2");
    let data = case.generate().expect("case data");
    let y_scale = data.y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let model = case.compiled().expect("case model");
    let (train, _) = identify::split(data.len(), 0.5, 1).expect("split");
    assert_eq!(train.len(), 250);
    let mut is_train = vec![false; data.len()];
    for &i in &train {
        is_train[i] = true;
    }
    let x: Vec<f64> = case.truth.iter().map(|v| v * 1.01).collect();
    let initial = Initial::Known {
        y0: case.y0,
        v0: case.v0,
    };
    // The options `Fitness::new` uses (src/identify/fitness.rs), to count the work of one integration.
    let n = data.len();
    let scale = data.y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let opts = Options {
        rtol: RTOL,
        atol: RTOL * 1e-3 * scale,
        substeps: SUBSTEPS,
        bound: 1e6 * scale,
        max_steps: 50 * n + 10_000,
        max_rhs_evals: 100 * SUBSTEPS.max(2) * n + 50_000,
        initial_step: None,
    };
    let methods = [Method::Dopri5, Method::Rk4, Method::Rosenbrock];
    let problem = Problem::new(&model, &data)
        .and_then(|p| p.with_initial(initial))
        .and_then(|p| p.with_y_scale(y_scale))
        .expect("problem")
        .with_output(Output::Displacement);
    let search = |method| {
        Search::default()
            .with_solver(method, RTOL)
            .and_then(|s| s.with_substeps(SUBSTEPS))
            .expect("search settings")
    };

    println!("fitness of van_der_pol_2, 250 training samples of 500, coefficients +1 %");
    println!("solver   rhs_evals  ns/evaluation  ns/rhs_eval   (plain loop, 2000 evaluations)");
    let mut counts = Vec::new();
    for method in methods {
        let sys = Bound {
            model: &model,
            coeffs: &x,
        };
        let outcome = integrate(method, &sys, [case.y0, case.v0], &data.t, &opts, |_, _| {
            ControlFlow::Continue(())
        });
        assert!(outcome.is_complete(), "{method}: {:?}", outcome.failure);
        let evals = outcome.stats.rhs_evals;
        counts.push(evals);
        let f = Fitness::new(&problem, is_train.clone(), &search(method));
        let mut ws = f.workspace();
        let cost = f.cost(&x, f64::INFINITY, &mut ws);
        assert!(cost.is_finite() && cost > 0.0, "{method}: cost {cost}");
        let runs = 2_000;
        let start = Instant::now();
        for _ in 0..runs {
            black_box(f.cost(black_box(&x), f64::INFINITY, &mut ws));
        }
        let ns = start.elapsed().as_nanos() as f64 / runs as f64;
        println!(
            "{:<8} {:>9}  {:>13.0}  {:>11.2}",
            method.name(),
            evals,
            ns,
            ns / evals as f64
        );
    }

    let mut group = c.benchmark_group("fitness_vdp2_250_train");
    for (method, evals) in methods.into_iter().zip(counts) {
        let f = Fitness::new(&problem, is_train.clone(), &search(method));
        let mut ws = f.workspace();
        // Criterion's throughput then reads as right-hand-side evaluations per second.
        group.throughput(Throughput::Elements(evals as u64));
        group.bench_function(method.name(), |b| {
            b.iter(|| f.cost(black_box(&x), f64::INFINITY, &mut ws))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
