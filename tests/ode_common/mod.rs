//! Test systems and helpers shared by the `ode_*` integration tests.
#![allow(dead_code)]

use gatewatch::ode::{integrate, Method, Options, Outcome, System};
use std::cell::Cell;
use std::ops::ControlFlow;

pub const METHODS: [Method; 3] = [Method::Dopri5, Method::Rk4, Method::Rosenbrock];

/// `y'' + 2 zeta w y' + w^2 y = 0` as `[y, y']`; counts its right-hand-side calls.
pub struct Oscillator {
    pub zeta: f64,
    pub w: f64,
    pub calls: Cell<usize>,
}

impl Oscillator {
    pub fn new(zeta: f64, w: f64) -> Self {
        Oscillator {
            zeta,
            w,
            calls: Cell::new(0),
        }
    }

    /// The exact solution from `y(0) = y0`, `y'(0) = v0` (|zeta| < 1).
    pub fn exact(&self, t: f64, y0: f64, v0: f64) -> [f64; 2] {
        let a = -self.zeta * self.w; // real part of the eigenvalues
        let wd = self.w * (1.0 - self.zeta * self.zeta).sqrt();
        let c1 = y0;
        let c2 = (v0 - a * y0) / wd;
        let (s, c) = (wd * t).sin_cos();
        let e = (a * t).exp();
        let y = e * (c1 * c + c2 * s);
        let yd = a * y + e * wd * (-c1 * s + c2 * c);
        [y, yd]
    }
}

impl System<2> for Oscillator {
    fn rhs(&self, _t: f64, y: &[f64; 2], dy: &mut [f64; 2]) {
        self.calls.set(self.calls.get() + 1);
        dy[0] = y[1];
        dy[1] = -2.0 * self.zeta * self.w * y[1] - self.w * self.w * y[0];
    }
}

/// `m y'' + c y' + k y = F sin(W t)`, non-autonomous.
pub struct Forced {
    pub m: f64,
    pub c: f64,
    pub k: f64,
    pub f: f64,
    pub w: f64,
}

impl Forced {
    pub fn chapter() -> Self {
        Forced {
            m: 2.5,
            c: 0.35,
            k: 0.3,
            f: 3.0,
            w: 2.2,
        }
    }

    /// Particular + homogeneous solution with `y(0) = y0`, `y'(0) = v0` (underdamped).
    pub fn exact(&self, t: f64, y0: f64, v0: f64) -> [f64; 2] {
        let d = self.k - self.m * self.w * self.w;
        let den = d * d + (self.c * self.w).powi(2);
        let a = self.f * d / den; // coefficient of sin(W t)
        let b = -self.f * self.c * self.w / den; // coefficient of cos(W t)
        let alpha = self.c / (2.0 * self.m);
        let wd = (self.k / self.m - alpha * alpha).sqrt();
        let c1 = y0 - b;
        let c2 = (v0 - a * self.w + alpha * c1) / wd;
        let (sw, cw) = (self.w * t).sin_cos();
        let (sd, cd) = (wd * t).sin_cos();
        let e = (-alpha * t).exp();
        let y = a * sw + b * cw + e * (c1 * cd + c2 * sd);
        let yd = self.w * (a * cw - b * sw) - alpha * e * (c1 * cd + c2 * sd)
            + e * wd * (-c1 * sd + c2 * cd);
        [y, yd]
    }
}

impl System<2> for Forced {
    fn rhs(&self, t: f64, y: &[f64; 2], dy: &mut [f64; 2]) {
        dy[0] = y[1];
        dy[1] = (self.f * (self.w * t).sin() - self.c * y[1] - self.k * y[0]) / self.m;
    }
}

/// Van der Pol `y'' - mu (1 - y^2) y' + y = 0`.
pub struct VanDerPol {
    pub mu: f64,
}

impl System<2> for VanDerPol {
    fn rhs(&self, _t: f64, y: &[f64; 2], dy: &mut [f64; 2]) {
        dy[0] = y[1];
        dy[1] = self.mu * (1.0 - y[0] * y[0]) * y[1] - y[0];
    }
}

/// `n` uniformly spaced times on `[a, b]`, both ends included.
pub fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            if i + 1 == n {
                b
            } else {
                a + (b - a) * i as f64 / (n - 1) as f64
            }
        })
        .collect()
}

/// Integrates and collects every delivered state (checking the indices arrive in order).
pub fn run<S: System<2>>(
    method: Method,
    sys: &S,
    y0: [f64; 2],
    times: &[f64],
    opts: &Options,
) -> (Outcome, Vec<[f64; 2]>) {
    let mut out = Vec::with_capacity(times.len());
    let outcome = integrate(method, sys, y0, times, opts, |i, y| {
        assert_eq!(i, out.len(), "observer indices must arrive in order");
        out.push(*y);
        ControlFlow::Continue(())
    });
    assert_eq!(
        outcome.reached,
        out.len(),
        "reached must count delivered states"
    );
    (outcome, out)
}

/// Largest `|y_num - y_exact|` of the first component over all delivered times.
pub fn max_error(times: &[f64], got: &[[f64; 2]], exact: impl Fn(f64) -> [f64; 2]) -> f64 {
    times
        .iter()
        .zip(got)
        .map(|(&t, y)| (y[0] - exact(t)[0]).abs())
        .fold(0.0, f64::max)
}

pub fn opts(rtol: f64, atol: f64) -> Options {
    Options {
        rtol,
        atol,
        ..Options::default()
    }
}
