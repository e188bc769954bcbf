//! Cost of one right-hand-side evaluation (`Model::accel`), the innermost call of every
//! identification: the integrators call it millions of times per fit.

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

criterion_group!(benches, accel);
criterion_main!(benches);
