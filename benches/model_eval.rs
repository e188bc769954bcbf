//! Cost of one right-hand-side evaluation (`Model::accel`), the innermost call of every
//! identification: the integrators call it millions of times per fit. Also the lockstep form
//! (`Model::accel_lanes`, 8 candidates per call) on the daemon's model, and a parse (with the
//! translation to machine code).

use criterion::{criterion_group, criterion_main, Criterion};
use gatewatch::model::Model;
use std::hint::black_box;

fn accel(c: &mut Criterion) {
    let cases: [(&str, &str, &[f64]); 3] = [
        (
            "polynomial_damping",
            "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0",
            &[-0.1434, 0.0001, 0.02],
        ),
        (
            "forced_linear",
            "c1*ydd + c2*yd + c3*y = c4*sin(c5*t)",
            &[1.0, 0.1, 4.0, 0.5, 1.3],
        ),
        (
            "state_dependent_mass",
            "(c1 + c2*y + c3*y^2)*ydd + y = 0",
            &[1.0, 0.1, 0.01],
        ),
    ];
    for (name, eq, coeffs) in cases {
        let model = Model::parse(eq, &[]).expect("benchmark equation parses");
        c.bench_function(&format!("accel/{name}"), |b| {
            b.iter(|| {
                model.accel(
                    black_box(0.25),
                    black_box(0.3),
                    black_box(-0.7),
                    black_box(coeffs),
                )
            })
        });
    }
}

/// The daemon's model (`config/gatewatch.toml`) for 8 candidates at once, as the lockstep
/// integrators call it (`Model::accel_lanes`): ns per call of 8 lanes.
fn accel_lanes(c: &mut Criterion) {
    let model = Model::parse(
        "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
        &[("k".to_string(), 81_000.0)],
    )
    .expect("benchmark equation parses");
    let coeffs: Vec<[f64; 8]> = (0..3)
        .map(|k| std::array::from_fn(|l| 1.0 + 0.01 * (8 * k + l) as f64))
        .collect();
    let t = [0.25; 8];
    let y: [f64; 8] = std::array::from_fn(|l| 0.3 + 0.01 * l as f64);
    let yd: [f64; 8] = std::array::from_fn(|l| -0.7 + 0.01 * l as f64);
    c.bench_function("accel_lanes/daemon_model_8_lanes", |b| {
        b.iter(|| {
            model.accel_lanes::<8>(
                black_box(&t),
                black_box(&y),
                black_box(&yd),
                black_box(&coeffs),
            )
        })
    });
}

/// What a parse costs: the daemon pays it once per configured gate at start-up, `identify` once
/// per run. Most of it is the translation to machine code (`GATEWATCH_JIT=off` for without).
fn parse(c: &mut Criterion) {
    c.bench_function("parse/daemon_model", |b| {
        b.iter(|| {
            Model::parse(
                black_box("c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0"),
                &[("k".to_string(), 81_360.0)],
            )
        })
    });
}

criterion_group!(benches, accel, accel_lanes, parse);
criterion_main!(benches);
