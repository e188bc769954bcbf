//! Nanoseconds per right-hand-side evaluation per candidate: the fitness of 8 candidates
//! evaluated one by one (`lanes 1`, the scalar path) and in lockstep (`lanes 4`, `lanes 8`),
//! with RK4 (2 substeps) and Dormand-Prince (rtol 1e-3), on van_der_pol_2 and forced_linear
//! (500 samples, 250 training samples, split seed 1), displacement output, known initial
//! conditions, coefficients 0.5 % to 4 % off the truth (a different offset per candidate).
//!
//! The right-hand-side evaluations of the 8 candidates are counted once by integrating each with
//! the scalar integrator and the fitness's options; criterion's throughput is set to that count,
//! so its "elements/s" reads as evaluations per second, and the printed table divides the time
//! per batch by it.
//!
//! Run: `cargo bench --bench lanes -- --warm-up-time 1 --measurement-time 3`.

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
const BATCH: usize = 8;

fn bench(c: &mut Criterion) {
    println!(
        "fitness of 8 candidates, 250 training samples of 500; ns per RHS evaluation per candidate"
    );
    println!("case            solver  lanes  rhs_evals/8  ns/batch   ns/rhs_eval  (plain loop)");
    let mut group = c.benchmark_group("lanes");
    for id in ["van_der_pol_2", "forced_linear"] {
        let case = cases::find(id).expect("case");
        let data = case.generate().expect("case data");
        let model = case.compiled().expect("case model");
        let (train, _) = identify::split(data.len(), 0.5, 1).expect("split");
        let mut is_train = vec![false; data.len()];
        for &i in &train {
            is_train[i] = true;
        }
        let xs: Vec<f64> = (0..BATCH)
            .flat_map(|k| {
                let f = 1.005 + 0.005 * k as f64;
                case.truth.iter().map(move |v| v * f)
            })
            .collect();
        let d = case.truth.len();
        let problem = Problem::new(&model, &data)
            .and_then(|p| {
                p.with_initial(Initial::Known {
                    y0: case.y0,
                    v0: case.v0,
                })
            })
            .expect("problem")
            .with_output(Output::Displacement);
        let n = data.len();
        let scale = data.y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for method in [Method::Rk4, Method::Dopri5] {
            // The options `Fitness::new` uses, to count the work of the 8 integrations.
            let opts = Options {
                rtol: RTOL,
                atol: RTOL * 1e-3 * scale,
                substeps: SUBSTEPS,
                bound: 1e6 * scale,
                max_steps: 50 * n + 10_000,
                max_rhs_evals: 100 * SUBSTEPS.max(2) * n + 50_000,
                initial_step: None,
            };
            let evals: usize = (0..BATCH)
                .map(|k| {
                    let sys = Bound {
                        model: &model,
                        coeffs: &xs[k * d..(k + 1) * d],
                    };
                    let o = integrate(method, &sys, [case.y0, case.v0], &data.t, &opts, |_, _| {
                        ControlFlow::Continue(())
                    });
                    assert!(o.is_complete(), "{id} {method}: {:?}", o.failure);
                    o.stats.rhs_evals
                })
                .sum();
            let search = Search::default()
                .with_solver(method, RTOL)
                .and_then(|s| s.with_substeps(SUBSTEPS))
                .expect("search");
            let bounds = [f64::INFINITY; BATCH];
            let mut reference = None;
            for lanes in [1, 4, 8] {
                let f = Fitness::new(&problem, is_train.clone(), &search).with_lanes(lanes);
                let mut ws = f.workspace();
                let mut out = [0.0; BATCH];
                f.cost_batch(&xs, &bounds, &mut out, &mut ws);
                // The same costs whatever the lane width.
                let bits = out.map(f64::to_bits);
                assert_eq!(
                    *reference.get_or_insert(bits),
                    bits,
                    "{id} {method} lanes {lanes}"
                );
                let runs = 300;
                let start = Instant::now();
                for _ in 0..runs {
                    f.cost_batch(black_box(&xs), &bounds, &mut out, &mut ws);
                    black_box(&out);
                }
                let ns = start.elapsed().as_nanos() as f64 / runs as f64;
                println!(
                    "{id:<15} {:<7} {lanes:>5}  {evals:>11}  {ns:>9.0}  {:>11.2}",
                    method.name(),
                    ns / evals as f64
                );
                group.throughput(Throughput::Elements(evals as u64));
                group.bench_function(format!("{id}/{}/lanes{lanes}", method.name()), |b| {
                    b.iter(|| {
                        f.cost_batch(black_box(&xs), &bounds, &mut out, &mut ws);
                        black_box(out[0])
                    })
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
