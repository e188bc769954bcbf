//! The lockstep lane path against the scalar path it replaces: integrators, fitness, whole
//! identifications. Equality is bit for bit (docs/design.md, "A generation in lanes").

use gatewatch::cases::{self, SeedCase};
use gatewatch::de::Objective;
use gatewatch::identify::{self, Config, Fitness, Initial, Output, Problem, Protocol, Search};
use gatewatch::model::{Bound, BoundLanes, Model};
use gatewatch::ode::{self, lanes, Method, Options, Outcome};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::ops::ControlFlow;

/// `L` candidates around the truth: mostly within +-30 %, one with wild coefficients (often a
/// blow-up or a failure) and, every other batch, one with the truth itself.
fn candidates<const L: usize>(
    case: &SeedCase,
    rng: &mut ChaCha8Rng,
    batch: usize,
) -> Vec<Vec<f64>> {
    (0..L)
        .map(|l| {
            case.truth
                .iter()
                .map(|v| match l {
                    0 if batch % 2 == 0 => *v,
                    3 => v * rng.random_range(-20.0..20.0) + rng.random_range(-5.0..5.0),
                    _ => v * rng.random_range(0.7..1.3),
                })
                .collect()
        })
        .collect()
}

fn soa<const L: usize>(xs: &[Vec<f64>]) -> Vec<[f64; L]> {
    (0..xs[0].len())
        .map(|k| std::array::from_fn(|l| xs[l][k]))
        .collect()
}

fn options(case: &SeedCase, y: &[f64], method: Method) -> Options {
    let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    Options {
        rtol: 1e-3,
        atol: 1e-6 * scale,
        substeps: if method == Method::Rk4 { 2 } else { 1 },
        bound: 1e6 * scale,
        max_steps: 50 * case.n + 10_000,
        max_rhs_evals: 100 * 2 * case.n + 50_000,
        initial_step: None,
    }
}

type Trace = Vec<(usize, [u64; 2])>;

fn scalar_run(
    model: &Model,
    x: &[f64],
    y0: [f64; 2],
    t: &[f64],
    o: &Options,
    m: Method,
) -> (Outcome, Trace) {
    let mut trace = Vec::new();
    let sys = Bound { model, coeffs: x };
    let out = ode::integrate(m, &sys, y0, t, o, |i, s| {
        trace.push((i, s.map(f64::to_bits)));
        ControlFlow::Continue(())
    });
    (out, trace)
}

/// Every seed case, 6 batches of 8 random candidates, RK4 and Dormand-Prince: each lane's
/// observed states and outcome equal the scalar integration's bit for bit, including lanes that
/// fail while the others go on.
#[test]
fn lane_integrators_equal_scalar_on_every_seed_case() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut failures = 0;
    for case in cases::CASES.iter() {
        let model = case.compiled().unwrap();
        let data = case.generate().unwrap();
        for method in [Method::Rk4, Method::Dopri5] {
            let o = options(case, &data.y, method);
            for batch in 0..6 {
                let xs = candidates::<8>(case, &mut rng, batch);
                let c = soa::<8>(&xs);
                let sys = BoundLanes {
                    model: &model,
                    coeffs: &c,
                };
                let y0 = [[case.y0; 8], [case.v0; 8]];
                let mut traces: Vec<Trace> = vec![Vec::new(); 8];
                let outs = match method {
                    Method::Rk4 => lanes::rk4(&sys, &y0, [true; 8], &data.t, &o, |i, s, live| {
                        for l in 0..8 {
                            if live[l] {
                                traces[l].push((i, [s[0][l].to_bits(), s[1][l].to_bits()]));
                            }
                        }
                    }),
                    _ => lanes::dopri5(&sys, &y0, [true; 8], &data.t, &o, |l, i, s| {
                        traces[l].push((i, s.map(f64::to_bits)));
                        ControlFlow::Continue(())
                    }),
                };
                for l in 0..8 {
                    let (so, st) =
                        scalar_run(&model, &xs[l], [case.y0, case.v0], &data.t, &o, method);
                    assert_eq!(outs[l], so, "{} {method} batch {batch} lane {l}", case.id);
                    assert_eq!(traces[l], st, "{} {method} batch {batch} lane {l}", case.id);
                    failures += usize::from(!so.is_complete());
                }
            }
        }
    }
    assert!(
        failures > 0,
        "the wild candidates should make some lanes fail"
    );
}

/// A lane stopped by its observer (the fitness's early abandonment) stops alone, with the
/// scalar method's outcome; the work caps stop every lane as they stop the scalar method.
#[test]
fn stopping_a_lane_and_work_caps_match_scalar() {
    let case = cases::find("van_der_pol_2").unwrap();
    let model = case.compiled().unwrap();
    let data = case.generate().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let xs = candidates::<4>(case, &mut rng, 0);
    let c = soa::<4>(&xs);
    let sys = BoundLanes {
        model: &model,
        coeffs: &c,
    };
    let y0 = [[case.y0; 4], [case.v0; 4]];
    for method in [Method::Rk4, Method::Dopri5] {
        for cap in [None, Some(37), Some(400)] {
            let mut o = options(case, &data.y, method);
            if let Some(cap) = cap {
                o.max_rhs_evals = cap;
            }
            // Lane 1 stops at output 9, lane 2 at 100.
            let stop_at = [usize::MAX, 9, 100, usize::MAX];
            let outs = match method {
                Method::Rk4 => lanes::rk4(&sys, &y0, [true; 4], &data.t, &o, |i, _, live| {
                    for l in 0..4 {
                        if i == stop_at[l] {
                            live[l] = false;
                        }
                    }
                }),
                _ => lanes::dopri5(&sys, &y0, [true; 4], &data.t, &o, |l, i, _| {
                    if i == stop_at[l] {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                }),
            };
            for l in 0..4 {
                let sys1 = Bound {
                    model: &model,
                    coeffs: &xs[l],
                };
                let so = ode::integrate(method, &sys1, [case.y0, case.v0], &data.t, &o, |i, _| {
                    if i == stop_at[l] {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                });
                assert_eq!(outs[l], so, "{method} cap {cap:?} lane {l}");
            }
        }
    }
}

fn fitness_for<'a>(
    case: &SeedCase,
    model: &'a Model,
    data: &'a gatewatch::data::TimeSeries,
    output: Output,
    method: Method,
) -> (Problem<'a>, Vec<bool>, Search) {
    let initial = if case.fit_initial {
        Initial::Fit
    } else {
        Initial::Known {
            y0: case.y0,
            v0: case.v0,
        }
    };
    let problem = Problem::new(model, data)
        .and_then(|p| p.with_initial(initial))
        .unwrap()
        .with_output(output);
    let (train, _) = identify::split(data.len(), 0.5, 1).unwrap();
    let mut is_train = vec![false; data.len()];
    for &i in &train {
        is_train[i] = true;
    }
    let search = Search::default()
        .with_solver(method, 1e-3)
        .and_then(|s| s.with_substeps(1))
        .unwrap();
    (problem, is_train, search)
}

/// The fitness's batch entry point equals its scalar cost on every seed case, for both outputs,
/// both solvers, lane widths 4 and 8, odd batch sizes (padding lanes), and bounds that make
/// some candidates abandon early while their neighbours complete.
#[test]
fn batched_fitness_equals_scalar_on_every_seed_case() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut abandoned, mut failed) = (0, 0);
    for case in cases::CASES.iter() {
        let model = case.compiled().unwrap();
        let data = case.generate().unwrap();
        for output in [Output::Displacement, Output::Force] {
            for method in [Method::Rk4, Method::Dopri5] {
                let (problem, is_train, search) = fitness_for(case, &model, &data, output, method);
                let base = Fitness::new(&problem, is_train, &search);
                let d = base.dimension();
                let n = 11; // one full batch of 8 and a padded one of 3; 2 of 4 and 3
                let mut xs = Vec::new();
                for b in 0..2 {
                    for x in candidates::<8>(case, &mut rng, b)
                        .into_iter()
                        .take(n - 8 * b)
                    {
                        // DE coordinates: the fitted initial conditions come last.
                        xs.extend(x);
                        if d > case.truth.len() {
                            xs.extend([case.y0 * rng.random_range(0.9..1.1), case.v0]);
                        }
                    }
                }
                let mut ws = base.workspace();
                let scalar_unbounded: Vec<f64> = (0..n)
                    .map(|k| base.cost(&xs[k * d..(k + 1) * d], f64::INFINITY, &mut ws))
                    .collect();
                // Bounds at the median: about half the candidates abandon.
                let mut sorted = scalar_unbounded.clone();
                sorted.sort_by(f64::total_cmp);
                let median = sorted[n / 2];
                let bounds: Vec<f64> = (0..n)
                    .map(|k| if k % 3 == 0 { f64::INFINITY } else { median })
                    .collect();
                let scalar: Vec<f64> = (0..n)
                    .map(|k| base.cost(&xs[k * d..(k + 1) * d], bounds[k], &mut ws))
                    .collect();
                abandoned += scalar.iter().filter(|c| c.is_infinite()).count();
                // A failing candidate costs at least the blow-up bound, 1e6 times the data.
                let ymax = data.y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                failed += scalar_unbounded.iter().filter(|c| **c > 1e5 * ymax).count();
                for lanes in [1, 4, 8] {
                    let f = base.with_lanes(lanes);
                    let mut ws = f.workspace();
                    let mut out = vec![0.0; n];
                    f.cost_batch(&xs, &bounds, &mut out, &mut ws);
                    for k in 0..n {
                        assert_eq!(
                            out[k].to_bits(),
                            scalar[k].to_bits(),
                            "{} {output:?} {method} lanes {lanes} candidate {k}: {} vs {}",
                            case.id,
                            out[k],
                            scalar[k]
                        );
                    }
                }
            }
        }
    }
    assert!(
        abandoned > 0 && failed > 0,
        "abandoned {abandoned}, failed {failed}"
    );
}

/// The residual vectors of a batch (the polish's forward-difference Jacobian, integrated in
/// lanes) equal the scalar ones bit for bit on every seed case, both outputs, both solvers, at
/// the polish tolerance, with batches of 3 (4 lanes), 5 and 11 (8 lanes, padded) points, failing
/// points among them.
#[test]
fn batched_residuals_equal_scalar_on_every_seed_case() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let (mut compared, mut failed) = (0, 0);
    for case in cases::CASES.iter() {
        let model = case.compiled().unwrap();
        let data = case.generate().unwrap();
        for output in [Output::Displacement, Output::Force] {
            for method in [Method::Rk4, Method::Dopri5] {
                let (problem, is_train, search) = fitness_for(case, &model, &data, output, method);
                let f = Fitness::new(&problem, is_train, &search).with_tolerance(method, 1e-8);
                let d = f.dimension();
                let mut ws = f.workspace();
                for n in [3, 5, 11] {
                    let mut xs = Vec::new();
                    for b in 0..2 {
                        for x in candidates::<8>(case, &mut rng, b) {
                            if xs.len() == n * d {
                                break;
                            }
                            xs.extend(x);
                            if d > case.truth.len() {
                                xs.extend([case.y0 * rng.random_range(0.9..1.1), case.v0]);
                            }
                        }
                    }
                    xs.truncate(n * d);
                    let batch = f.residuals_batch(&xs);
                    assert_eq!(batch.len(), xs.len() / d);
                    for (k, got) in batch.iter().enumerate() {
                        let x = &xs[k * d..(k + 1) * d];
                        let want = f.residuals(x);
                        // The residuals (a force output's evaluated after the integration, 8
                        // samples at a time) sum to the cost (evaluated sample by sample as
                        // the integrator passes them), bit for bit.
                        if let Some(w) = &want {
                            assert_eq!(
                                f.cost_of_residuals(w).to_bits(),
                                f.cost(x, f64::INFINITY, &mut ws).to_bits(),
                                "{} {output:?} {method} point {k}",
                                case.id
                            );
                        }
                        let bits = |r: &Option<Vec<f64>>| {
                            r.as_ref()
                                .map(|r| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
                        };
                        assert_eq!(
                            bits(got),
                            bits(&want),
                            "{} {output:?} {method} n {n} point {k}",
                            case.id
                        );
                        compared += 1;
                        failed += usize::from(want.is_none());
                    }
                }
            }
        }
    }
    assert!(
        compared > 0 && failed > 0,
        "compared {compared}, failed {failed}"
    );
}

/// Everything a run reports, as bits.
fn fingerprint(r: &identify::Identification) -> String {
    let runs: Vec<_> = r
        .runs
        .iter()
        .map(|x| {
            (
                x.seed,
                x.coefficients
                    .iter()
                    .map(|c| c.to_bits())
                    .collect::<Vec<_>>(),
                x.train_mae.to_bits(),
                x.test_nmae.map(f64::to_bits),
                x.evaluations,
                x.restarts,
                x.history.iter().map(|h| h.to_bits()).collect::<Vec<_>>(),
            )
        })
        .collect();
    format!("{runs:?}")
}

/// Whole identifications: the same seed gives the same runs with 1, 4 or 8 lanes, serial or on
/// 1 to 3 threads, with RK4 and with Dormand-Prince.
#[test]
fn identification_is_the_same_whatever_lanes_and_threads() {
    let case = cases::find("van_der_pol_2").unwrap();
    let model = case.compiled().unwrap();
    let data = case.generate().unwrap();
    for solver in [Method::Rk4, Method::Dopri5] {
        let config = |lanes: usize, parallel: bool| Config {
            search: Search {
                population: 20,
                generations: 25,
                solver,
                substeps: 1,
                lanes,
                parallel,
                ..Search::default()
            },
            protocol: Protocol {
                runs: 2,
                seed: 4,
                ..Protocol::default()
            },
            ..Config::default()
        };
        let go = |c: &Config| identify::identify(&model, &data, c, |_, _, _| {}).unwrap();
        let reference = fingerprint(&go(&config(1, false)));
        for lanes in [4, 8] {
            assert_eq!(
                fingerprint(&go(&config(lanes, false))),
                reference,
                "{solver} lanes {lanes}"
            );
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let par = pool.install(|| go(&config(lanes, true)));
                assert_eq!(
                    fingerprint(&par),
                    reference,
                    "{solver} lanes {lanes} threads {threads}"
                );
            }
        }
    }
}

/// Every operation of the language, on lanes that include zero, negatives, NaN and
/// infinity: each lane equals the scalar evaluator bit for bit.
#[test]
fn lanes_equal_scalar_bit_for_bit() {
    let equations = [
        "ydd + (c1 + c2*y^2)*yd + c3*y = 0",
        "c1*ydd + c2*yd + c3*y = c4*sin(c5*t)",
        "(1 + c1*y^2)*ydd + c2*sign(yd) + tanh(c3*y) + exp(-abs(yd))*c4 = 0",
        "ydd + min(c1*y, max(yd, c2)) + (y + 2)^c3 + sqrt(abs(y))/(c1 - yd) + ln(abs(t) + 1) = 0",
        "ydd + step(y - c1)*c2 + y^5 + cos(t)*tan(yd) + (c3 - y)^(c1 + yd) + 2/(y*yd + c2) = 0",
        "ydd + y^-2 + c1 = 0",
    ];
    let vals = [
        0.0,
        -0.0,
        1.5,
        -2.25,
        3.0e5,
        -7.5e-4,
        f64::NAN,
        f64::INFINITY,
    ];
    for eq in equations {
        let m = Model::parse(eq, &[]).unwrap();
        let nc = m.n_coeffs();
        for shift in 0..8 {
            let pick = |k: usize, l: usize| vals[(k * 3 + l * 5 + shift) % vals.len()];
            let t: [f64; 8] = std::array::from_fn(|l| pick(0, l) * 0.5);
            let y: [f64; 8] = std::array::from_fn(|l| pick(1, l));
            let yd: [f64; 8] = std::array::from_fn(|l| pick(2, l + 1));
            let c: Vec<[f64; 8]> = (0..nc)
                .map(|k| std::array::from_fn(|l| pick(k + 3, l) + 0.125 * k as f64))
                .collect();
            let a = m.accel_lanes(&t, &y, &yd, &c);
            let r = m.residual_lanes(&t, &y, &yd, &c);
            for l in 0..8 {
                let cl: Vec<f64> = c.iter().map(|v| v[l]).collect();
                let sa = m.accel(t[l], y[l], yd[l], &cl);
                let sr = m.residual(t[l], y[l], yd[l], &cl);
                // NaN payloads may differ (a vector add may take its operands in the other
                // order); every other value must match bit for bit.
                let same = |u: f64, v: f64| u.to_bits() == v.to_bits() || u.is_nan() && v.is_nan();
                assert!(same(a[l], sa), "{eq} lane {l}: {} vs {sa}", a[l]);
                assert!(same(r[l], sr), "{eq} lane {l}: {} vs {sr}", r[l]);
            }
        }
    }
}

#[test]
fn missing_coefficient_reads_nan() {
    let m = Model::parse("ydd + c1*y + c2 = 0", &[]).unwrap();
    let a = m.accel_lanes(&[0.0; 4], &[1.0; 4], &[0.0; 4], &[[1.0; 4]]);
    assert!(a.iter().all(|v| v.is_nan()));
}
