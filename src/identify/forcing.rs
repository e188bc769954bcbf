//! The coefficients' covariance of a free-vibration fit to a *forced* record: the turbulent
//! forcing propagated through the fitted model, instead of estimated from the residuals'
//! autocovariance (`covariance`'s Newey-West sum).
//!
//! Why: a free-vibration fit reads the forcing's response as measurement error. That response
//! starts at zero where the fit pins the initial conditions and accumulates over the window,
//! narrow-band at the gate's own frequency and coherent over many cycles: exactly the error a
//! Newey-West sum over a quarter of the window sees only in part. Its covariance is known
//! once the forcing's intensity is, because the fitted model says how a kick at time `u`
//! travels to every later sample. Along the fitted trajectory the deviation `dx = [dy, dyd]`
//! obeys the linearised model `dx' = A(t) dx + [0, 1] w(t)`, `w` white with intensity `q` (the
//! force per unit mass), so the prediction error `d = C(t) dx` (`C = [1, 0]` for displacement,
//! the support force's gradient for force) is a linear functional of `w`, and
//!
//! ```text
//! J^T Cov(d) J = q sum_u g(u) g(u)^T du,   g(u) = sum_{t > u} J(t)^T C(t) Phi(t, u) [0, 1]^T
//! ```
//!
//! where `Phi` is the linearised flow. One backward (adjoint) sweep gives every `g(u)`: `O(n p)`,
//! no integration beyond the Jacobian's. With white sensor noise of variance `s2` on top,
//!
//! ```text
//! Cov(c) = B (q sum g g^T du + s2 J^T J) B,   B = (J^T J)^+.
//! ```
//!
//! `s2` is read from the residuals' second differences (a sensor's white noise has `6 s2`
//! there; the forcing's response, smooth at ten or more samples a period, under 2 % of its
//! variance). `q` is the value that makes the expected residual sum of squares at the optimum
//! equal the observed one: `E[RSS] = q tr((I - P) Sigma_F) + s2 (n - rank)`, `P` the fit's
//! projection, `tr(P Sigma_F) = tr(B J^T Sigma_F J)`. Anything else the model does not explain
//! (a ramp in the damping, a wrong structure) is read as forcing too, which widens the interval:
//! the honest direction. The covariance is then a model's, not an estimate's, so its critical
//! value is the normal 1.96.

use super::covariance::{jacobian, Covariance, Middle, Optimum};
use super::problem::Output;
use nalgebra::DMatrix;

/// Relative step of the linearisation's central differences, on the trajectory's RMS
/// displacement and velocity. Value: the model is evaluated exactly (no integration), so a
/// step far below the state's scale and far above rounding serves.
const LINEARISATION_STEP: f64 = 1e-6;

/// `[dy, dyd]`'s 2 x 2 matrices, row-major.
type M2 = [[f64; 2]; 2];

fn mul(a: &M2, b: &M2) -> M2 {
    [
        [
            a[0][0] * b[0][0] + a[0][1] * b[1][0],
            a[0][0] * b[0][1] + a[0][1] * b[1][1],
        ],
        [
            a[1][0] * b[0][0] + a[1][1] * b[1][0],
            a[1][0] * b[0][1] + a[1][1] * b[1][1],
        ],
    ]
}

fn add_scaled(a: &M2, b: &M2, s: f64) -> M2 {
    [
        [a[0][0] + s * b[0][0], a[0][1] + s * b[0][1]],
        [a[1][0] + s * b[1][0], a[1][1] + s * b[1][1]],
    ]
}

const IDENTITY: M2 = [[1.0, 0.0], [0.0, 1.0]];

/// The flow of `dx' = A(t) dx` over one step `dt` (classical Runge-Kutta with `A` at the step's
/// ends and their mean at its middle): fourth order, as the polish's own integration.
fn flow(a0: &M2, a1: &M2, dt: f64) -> M2 {
    let sum = add_scaled(a0, a1, 1.0);
    let am = add_scaled(&sum, &sum, -0.5);
    let k1 = *a0;
    let k2 = mul(&am, &add_scaled(&IDENTITY, &k1, 0.5 * dt));
    let k3 = mul(&am, &add_scaled(&IDENTITY, &k2, 0.5 * dt));
    let k4 = mul(a1, &add_scaled(&IDENTITY, &k3, dt));
    let sum = add_scaled(&add_scaled(&add_scaled(&k1, &k2, 2.0), &k3, 2.0), &k4, 1.0);
    add_scaled(&IDENTITY, &sum, dt / 6.0)
}

/// The covariance at `optimum` under turbulent forcing and white sensor noise (module docs),
/// with the Jacobian of [`super::covariance`] (its cost plus `O(n p^2)`). `None` when that has
/// nothing to estimate, the sample times are not increasing, or the linearisation is not
/// finite.
pub fn covariance_under_forcing(optimum: &Optimum<'_>) -> Option<Covariance> {
    let Optimum {
        model,
        series,
        coefficients,
        output,
        ..
    } = *optimum;
    let at = jacobian(optimum)?;
    let n = at.states.len();
    if n < 8 || series.t.windows(2).any(|w| w[1] <= w[0]) {
        return None;
    }
    let rms = |k: usize| (at.states.iter().map(|s| s[k] * s[k]).sum::<f64>() / n as f64).sqrt();
    let (hy, hv) = (
        LINEARISATION_STEP * rms(0).max(f64::MIN_POSITIVE),
        LINEARISATION_STEP * rms(1).max(f64::MIN_POSITIVE),
    );
    // A(t) and C(t) at every sample.
    let mut a = Vec::with_capacity(n);
    let mut c = Vec::with_capacity(n);
    for (s, &t) in at.states.iter().zip(&series.t) {
        let f = |y: f64, v: f64| model.accel(t, y, v, coefficients);
        let dy = (f(s[0] + hy, s[1]) - f(s[0] - hy, s[1])) / (2.0 * hy);
        let dv = (f(s[0], s[1] + hv) - f(s[0], s[1] - hv)) / (2.0 * hv);
        a.push([[0.0, 1.0], [dy, dv]]);
        c.push(match output {
            Output::Displacement => [1.0, 0.0],
            Output::Force | Output::RestoringForce => {
                let r = |y: f64, v: f64| model.residual(t, y, output.force_yd(v), coefficients);
                [
                    (r(s[0] + hy, s[1]) - r(s[0] - hy, s[1])) / (2.0 * hy),
                    (r(s[0], s[1] + hv) - r(s[0], s[1] - hv)) / (2.0 * hv),
                ]
            }
        });
    }
    if a.iter()
        .flatten()
        .flatten()
        .chain(c.iter().flatten())
        .any(|v| !v.is_finite())
    {
        return None;
    }
    // The linearised flow between consecutive samples.
    let phis: Vec<M2> = (0..n - 1)
        .map(|i| flow(&a[i], &a[i + 1], series.t[i + 1] - series.t[i]))
        .collect();
    let residuals = at.residuals;
    // White sensor noise from the second differences.
    let s2 = residuals
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).powi(2))
        .sum::<f64>()
        / (6.0 * (n - 2) as f64);
    let rss: f64 = residuals.iter().map(|r| r * r).sum();
    Covariance::build(&at.jacobian, &residuals, |scaled, rank, pinv| {
        let p = scaled.ncols();
        // Backward sweep: lambda[k] = sum_{j > i} J_j[k] C_j Phi(j, i), a row per column.
        let mut lambda = vec![[0.0f64; 2]; p];
        let mut omega_f = DMatrix::<f64>::zeros(p, p);
        let mut g = vec![0.0f64; p];
        // Forward: the forcing response's variance at each sample, for tr(Sigma_F).
        let mut cov = [[0.0f64; 2]; 2];
        let mut trace_f = 0.0;
        for (i, phi) in phis.iter().enumerate() {
            let dt = series.t[i + 1] - series.t[i];
            let kicked = add_scaled(&cov, &[[0.0, 0.0], [0.0, 1.0]], dt);
            cov = mul(
                &mul(phi, &kicked),
                &[[phi[0][0], phi[1][0]], [phi[0][1], phi[1][1]]],
            );
            let ci = c[i + 1];
            trace_f += ci[0] * (cov[0][0] * ci[0] + cov[0][1] * ci[1])
                + ci[1] * (cov[1][0] * ci[0] + cov[1][1] * ci[1]);
        }
        for (i, phi) in phis.iter().enumerate().rev() {
            let dt = series.t[i + 1] - series.t[i];
            let ci = c[i + 1];
            for (k, row) in lambda.iter_mut().enumerate() {
                let jk = scaled[(i + 1, k)];
                let v = [row[0] + jk * ci[0], row[1] + jk * ci[1]];
                *row = [
                    v[0] * phi[0][0] + v[1] * phi[1][0],
                    v[0] * phi[0][1] + v[1] * phi[1][1],
                ];
                g[k] = row[1];
            }
            for x in 0..p {
                for y in 0..p {
                    omega_f[(x, y)] += dt * g[x] * g[y];
                }
            }
        }
        let projected = (pinv * &omega_f).trace();
        let denominator = trace_f - projected;
        // Every excess over the sensor's noise counts as forcing, significant or not: the
        // forcing's response is coherent over the window, so even one below the noise's level
        // decides zeta0's error (the forced decays of the tests: 15 of 40 covered by Newey-West,
        // 37 by this), and a clean record's fluctuation then widens its interval for nothing.
        let q = if denominator > 0.0 {
            ((rss - s2 * (n - rank) as f64) / denominator).max(0.0)
        } else {
            0.0
        };
        let omega = omega_f * q + scaled.transpose() * scaled * s2;
        Some(Middle {
            omega,
            factor: 1.0,
            bandwidth: 0,
            critical_95: 1.959_964,
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::TimeSeries;
    use crate::identify::{covariance, difference_steps, Config, Initial, InitialValues};
    use crate::model::Model;
    use crate::simulate::{GateParams, GateSimulator, Output as SimOutput, ZetaSchedule};

    const ZETA: f64 = 0.02;
    const OMEGA: f64 = 2.0 * std::f64::consts::PI * 2.0;
    const RATE: f64 = 50.0;

    /// A 2 Hz oscillator at +2 % released from `y = 1` under turbulent forcing of
    /// `forcing_std` per sample (force per unit mass), with white sensor noise: 10 s at 50 Hz.
    fn forced_decay(seed: u64, forcing_std: f64, noise_std: f64) -> TimeSeries {
        let params = GateParams {
            mass: 1.0,
            stiffness: OMEGA * OMEGA,
            c3: 0.0,
            forcing_std,
            rate_hz: RATE,
            substeps: 4,
            output: SimOutput::Displacement,
            noise_std,
            y0: 1.0,
            ..GateParams::default()
        };
        let mut sim = GateSimulator::new(params, ZetaSchedule::Constant(ZETA), seed);
        let n = (10.0 * RATE) as usize;
        let y: Vec<f64> = (0..n).map(|_| sim.next_sample()).collect();
        let t = (0..n).map(|i| i as f64 / RATE).collect();
        TimeSeries::new(t, y).unwrap()
    }

    /// zeta0's half width (1.96 sd, or the fixed-b value for Newey-West) and whether the
    /// interval covers the truth, for the least-squares fit from the truth.
    fn interval(series: &TimeSeries, forcing: bool) -> (f64, bool) {
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let truth = [2.0 * ZETA * OMEGA, OMEGA * OMEGA];
        let config = Config::default();
        let problem = config
            .problem(&model, series)
            .unwrap()
            .with_initial(Initial::Known { y0: 1.0, v0: 0.0 })
            .unwrap();
        let id = crate::identify::refine(&problem, &config.search, &config.protocol, &truth, 400)
            .unwrap();
        let run = id.best_run();
        let c = &run.coefficients;
        let steps = difference_steps(c, &[]);
        let f = if forcing {
            covariance_under_forcing
        } else {
            covariance
        };
        let cov = f(&Optimum {
            model: &model,
            series,
            coefficients: c,
            init: run.initial,
            output: Output::Displacement,
            steps: &steps,
            initial_steps: None,
        })
        .unwrap();
        // zeta0 = c1 / (2 sqrt(c2)).
        let z = c[0] / (2.0 * c[1].sqrt());
        let gradient = [1.0 / (2.0 * c[1].sqrt()), -c[0] / (4.0 * c[1].powf(1.5))];
        let half = cov.critical_value_95() * cov.std_dev_of(&gradient).unwrap();
        (half, (z - ZETA).abs() <= half)
    }

    #[test]
    fn forced_decays_are_covered_at_the_nominal_rate_where_newey_west_is_short() {
        // The forcing's response (about a fifth of the release amplitude by the window's end)
        // dominates the error of zeta0: coherent over the whole window.
        let seeds = 40;
        let (mut forcing, mut newey_west) = (0, 0);
        let mut ratios = Vec::new();
        for seed in 0..seeds {
            let series = forced_decay(seed, 0.5, 0.01);
            let (hf, cf) = interval(&series, true);
            let (hn, cn) = interval(&series, false);
            forcing += usize::from(cf);
            newey_west += usize::from(cn);
            ratios.push(hf / hn);
        }
        ratios.sort_by(f64::total_cmp);
        eprintln!(
            "forcing {forcing}/{seeds}, Newey-West {newey_west}/{seeds}, median width ratio {}",
            ratios[ratios.len() / 2]
        );
        assert!(forcing >= 35, "forcing covered {forcing} of {seeds}");
        assert!(
            forcing > newey_west,
            "forcing {forcing}, Newey-West {newey_west} of {seeds}"
        );
    }

    #[test]
    fn without_forcing_it_covers_at_the_textbook_width_or_wider() {
        // No forcing: the white-noise textbook `s2 (J^T J)^-1` (Newey-West with white
        // residuals) is right. q is read from the residuals' excess over the sensor's noise, so
        // a fluctuation can widen the interval (the price of counting a forcing below the
        // noise's level, above); it does not narrow it by more than the estimates' scatter.
        let seeds = 20;
        let (mut covered, mut ratios) = (0, Vec::new());
        for seed in 0..seeds {
            let series = forced_decay(seed, 0.0, 0.05);
            let (hf, cf) = interval(&series, true);
            let (hn, _) = interval(&series, false);
            covered += usize::from(cf);
            ratios.push(hf / hn);
        }
        ratios.sort_by(f64::total_cmp);
        eprintln!("covered {covered}/{seeds}, width ratios {ratios:?}");
        assert!(covered >= 18, "covered {covered} of {seeds}");
        assert!(ratios[0] > 0.8, "width ratios {ratios:?}");
        assert!(ratios[seeds as usize / 2] < 3.0, "width ratios {ratios:?}");
    }

    #[test]
    fn a_record_that_determines_nothing_gives_none() {
        // At rest with zero initial conditions the Jacobian is zero: None, not a panic.
        let model = Model::parse("ydd + c1*yd + c2*y = 0", &[]).unwrap();
        let t: Vec<f64> = (0..200).map(|i| i as f64 / 50.0).collect();
        let series = TimeSeries::new(t, vec![0.0; 200]).unwrap();
        let init = InitialValues { y0: 0.0, v0: 0.0 };
        let c = [0.5, 100.0];
        let steps = difference_steps(&c, &[]);
        let cov = covariance_under_forcing(&Optimum {
            model: &model,
            series: &series,
            coefficients: &c,
            init,
            output: Output::Displacement,
            steps: &steps,
            initial_steps: None,
        });
        assert!(cov.is_none());
    }
}
