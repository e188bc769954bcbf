//! The identified model linearised at rest, and its energy balance at an amplitude: the damping
//! figures of `docs/damping.md` (zeta0, zeta_eq, energy per cycle, limit cycle, time to limit).

use crate::model::Model;
use serde::Serialize;

/// The model linearised at rest: `M0*ydd + C0*yd + K0*y` (derivatives of `R` at `y = yd = 0`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Linearization {
    /// `M(t0, 0, 0)`.
    pub m0: f64,
    /// `dR/dyd` at rest.
    pub c0: f64,
    /// `dR/dy` at rest.
    pub k0: f64,
}

impl Linearization {
    /// Central differences of the compiled model at `(t0, 0, 0)`, with steps relative to the
    /// displacement and velocity scales of the problem.
    pub fn of(model: &Model, c: &[f64], t0: f64, y_scale: f64, v_scale: f64) -> Linearization {
        let (hy, hv) = (
            1e-6 * y_scale.abs().max(1e-300),
            1e-6 * v_scale.abs().max(1e-300),
        );
        let r = |y: f64, yd: f64| model.residual(t0, y, yd, c);
        Linearization {
            m0: model.mass(t0, 0.0, 0.0, c),
            c0: (r(0.0, hv) - r(0.0, -hv)) / (2.0 * hv),
            k0: (r(hy, 0.0) - r(-hy, 0.0)) / (2.0 * hy),
        }
    }

    /// Undamped natural angular frequency `sqrt(K0/M0)`, when `K0/M0 > 0`.
    pub fn omega0(&self) -> Option<f64> {
        let w2 = self.k0 / self.m0;
        (w2 > 0.0 && w2.is_finite()).then(|| w2.sqrt())
    }

    /// Damping ratio at rest `C0 / (2 sqrt(K0 M0))` (signs normalised by `M0`), when the rest
    /// position is an oscillator (`K0/M0 > 0`).
    pub fn zeta0(&self) -> Option<f64> {
        let w = self.omega0()?;
        let z = (self.c0 / self.m0) / (2.0 * w);
        z.is_finite().then_some(z)
    }
}

/// Equivalent damping at displacement amplitude `a`: the energy the velocity-odd part of `R`
/// dissipates over one harmonic cycle `y = a cos(theta)`, `yd = -a w sin(theta)` at the
/// linearised frequency, expressed as a viscous damping ratio (first-order averaging, as in
/// Krylov-Bogoliubov). Returns `(zeta_eq, energy fed in per cycle)`.
pub fn equivalent_damping(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    a: f64,
    t0: f64,
) -> Option<(f64, f64)> {
    let w = lin.omega0()?;
    const N: usize = 256;
    let mut work = 0.0;
    for k in 0..N {
        let th = 2.0 * std::f64::consts::PI * k as f64 / N as f64;
        let (y, yd) = (a * th.cos(), -a * w * th.sin());
        let odd = 0.5 * (model.residual(t0, y, yd, c) - model.residual(t0, y, -yd, c));
        // dt = dtheta / w, so the integral of odd * yd dt is sum(odd * yd) * (2 pi / N) / w.
        work += odd * yd;
    }
    let dissipated = work * 2.0 * std::f64::consts::PI / N as f64 / w;
    let c_eq = dissipated / (std::f64::consts::PI * w * a * a);
    let zeta_eq = (c_eq / lin.m0) / (2.0 * w);
    (zeta_eq.is_finite() && dissipated.is_finite()).then_some((zeta_eq, -dissipated))
}

/// The damping ratio at rest that makes displacement amplitude `a` a limit cycle of the model's
/// non-linear damping: `zeta0 - zeta_eq(a)`, the opposite of the non-linear part at `a`
/// (`zeta_eq(a) = zeta0 + b a^p`, so this is `-b a^p`). At the model's own limit cycle it is the
/// model's `zeta0`; as a function of the coefficients it is the damping law a growth window
/// carries to the cycle after it (`analysis::CycleAmplitude`), whose interval is this
/// function's, not zeta0's (`docs/damping.md`, "The cycle's amplitude").
pub fn cycle_zeta0(model: &Model, c: &[f64], lin: &Linearization, a: f64, t0: f64) -> Option<f64> {
    let (zeta_eq, _) = equivalent_damping(model, c, lin, a, t0)?;
    let z = lin.zeta0()? - zeta_eq;
    z.is_finite().then_some(z)
}

/// The smallest displacement amplitude above `from / 1000` where `zeta_eq` turns from negative to
/// non-negative (a stable limit cycle), searched up to `1000 * from`.
pub fn limit_cycle(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    from: f64,
    t0: f64,
) -> Option<f64> {
    let z = |a: f64| equivalent_damping(model, c, lin, a, t0).map(|(z, _)| z);
    let (lo, hi) = (from * 1e-3, from * 1e3);
    const STEPS: usize = 120;
    let mut prev = (lo, z(lo)?);
    for k in 1..=STEPS {
        let a = lo * (hi / lo).powf(k as f64 / STEPS as f64);
        let za = z(a)?;
        if prev.1 < 0.0 && za >= 0.0 {
            let (mut l, mut h) = (prev.0, a);
            for _ in 0..60 {
                let m = (l * h).sqrt();
                if z(m)? < 0.0 {
                    l = m;
                } else {
                    h = m;
                }
            }
            return Some((l * h).sqrt());
        }
        prev = (a, za);
    }
    None
}

/// Time for the amplitude to grow from `now` to `limit` by the averaged amplitude equation
/// `da/dt = -zeta_eq(a) w a`; `Some(0)` when already there, `None` when it never gets there
/// (damped somewhere on the way).
pub fn time_to_amplitude(
    model: &Model,
    c: &[f64],
    lin: &Linearization,
    now: f64,
    limit: f64,
    t0: f64,
) -> Option<f64> {
    if now >= limit {
        return Some(0.0);
    }
    let w = lin.omega0()?;
    const STEPS: usize = 200;
    let step = (limit / now).ln() / STEPS as f64;
    let mut t = 0.0;
    for k in 0..STEPS {
        let a = now * ((k as f64 + 0.5) * step).exp();
        let (z, _) = equivalent_damping(model, c, lin, a, t0)?;
        if z >= 0.0 {
            return None;
        }
        t += step / (-z * w);
    }
    Some(t)
}
