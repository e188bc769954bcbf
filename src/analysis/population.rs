//! The DE's initial population for a window (section 8.4.4, generalised): the previous window's
//! coefficients (warm start), then individuals moved onto the coefficients whose linearisation
//! matches the measured frequency and growth; the DE fills the rest uniformly.

use super::linearisation::Linearization;
use crate::model::Model;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Stream of the biased individuals' random starts: the DE seeds its own generator with the
/// settings' seed, so the bias draws from a different stream of the same seed.
const BIAS_STREAM: u64 = 0x000f_b1a5;
/// Stream of the fitted initial conditions of the biased individuals (another stream again).
const INITIAL_CONDITIONS_STREAM: u64 = 0x1c0d_5eed;

/// What the spectrum says about the linearisation: `K0/M0 = omega^2` and, when the envelope
/// growth is clean, `C0/M0 = -2 sigma`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpectralTarget {
    /// Measured angular frequency, rad/s.
    pub omega: f64,
    /// Measured envelope growth rate, 1/s, if trustworthy.
    pub sigma: Option<f64>,
}

/// `n` individuals (DE coordinates: coefficient `j` is `x[j] * scales[j]`) drawn uniformly from
/// `[-1, 1]` and then moved by a few damped Gauss-Newton steps, minimum-norm, onto the set of
/// coefficients whose linearisation matches `target` (the chapter's "line of possible values",
/// for any model structure). Individuals the projection cannot fix are returned unmoved.
#[allow(clippy::too_many_arguments)]
pub fn biased_population(
    model: &Model,
    scales: &[f64],
    target: SpectralTarget,
    n: usize,
    seed: u64,
    t0: f64,
    y_scale: f64,
    v_scale: f64,
) -> Vec<Vec<f64>> {
    let d = model.n_coeffs();
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ BIAS_STREAM);
    let w = target.omega;
    // Written as M0 w^2 - K0 and C0 + 2 sigma M0 rather than ratios: linear in the coefficients
    // of every model whose M0, C0 and K0 are, so that the minimum-norm step lands on the set in
    // one iteration (a ratio's 1/M0 makes Gauss-Newton overshoot from random starts).
    let residuals = |x: &[f64]| -> Option<([f64; 2], f64)> {
        let c: Vec<f64> = x.iter().zip(scales).map(|(x, s)| x * s).collect();
        let lin = Linearization::of(model, &c, t0, y_scale, v_scale);
        let r1 = lin.m0 * w * w - lin.k0;
        let r2 = match target.sigma {
            Some(sigma) => (lin.c0 + 2.0 * sigma * lin.m0) * w,
            None => 0.0,
        };
        let size = lin.m0.abs() * w * w + lin.k0.abs();
        (r1.is_finite() && r2.is_finite()).then_some(([r1, r2], size))
    };
    (0..n)
        .map(|_| {
            let mut x: Vec<f64> = (0..d).map(|_| rng.random_range(-1.0..=1.0)).collect();
            for _ in 0..8 {
                let Some((r, size)) = residuals(&x) else {
                    break;
                };
                if r[0].abs() <= 1e-9 * size && r[1].abs() <= 1e-9 * size {
                    break;
                }
                // J (2 x d) by forward differences, then dx = -J^T (J J^T + mu I)^-1 r.
                let mut jac = vec![[0.0; 2]; d];
                let mut ok = true;
                for j in 0..d {
                    let h = 1e-6 * x[j].abs().max(1e-3);
                    let mut xp = x.clone();
                    xp[j] += h;
                    match residuals(&xp) {
                        Some((rp, _)) => jac[j] = [(rp[0] - r[0]) / h, (rp[1] - r[1]) / h],
                        None => ok = false,
                    }
                }
                if !ok {
                    break;
                }
                // J J^T, regularised relative to its size (one constraint may be absent: r2 = 0).
                let mut a = [[0.0; 2]; 2];
                for col in &jac {
                    for p in 0..2 {
                        for q in 0..2 {
                            a[p][q] += col[p] * col[q];
                        }
                    }
                }
                let eps = 1e-12 * (a[0][0] + a[1][1]) + f64::MIN_POSITIVE;
                a[0][0] += eps;
                a[1][1] += eps;
                let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
                if !(det.abs() > 0.0 && det.is_finite()) {
                    break;
                }
                let lam = [
                    (a[1][1] * r[0] - a[0][1] * r[1]) / det,
                    (a[0][0] * r[1] - a[1][0] * r[0]) / det,
                ];
                for (xj, col) in x.iter_mut().zip(&jac) {
                    *xj -= col[0] * lam[0] + col[1] * lam[1];
                }
            }
            x
        })
        .collect()
}

/// Everything [`initial_population`] needs to know about the problem and the window.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PopulationInputs<'a> {
    /// Physical value per DE coordinate of each coefficient.
    pub scales: &'a [f64],
    /// The DE population size (the biased part is half of it).
    pub population: usize,
    /// The settings' seed.
    pub seed: u64,
    /// Whether the DE also fits `y0, v0` (two extra coordinates per individual).
    pub fit_initial_conditions: bool,
    /// Bias towards the spectrum (the FFT bias option).
    pub fft_bias: bool,
    /// What the spectrum says, when it found a dominant frequency.
    pub target: Option<SpectralTarget>,
    /// Window start, where the linearisation is taken.
    pub t0: f64,
    /// Displacement scale of the linearisation's steps.
    pub y_scale: f64,
    /// Velocity scale of the linearisation's steps.
    pub v_scale: f64,
}

/// The initial population in DE coordinates: the warm start (physical coefficients of the
/// previous window of the same gate, when usable), then the FFT-biased half.
pub(crate) fn initial_population(
    model: &Model,
    warm: Option<&[f64]>,
    p: &PopulationInputs<'_>,
) -> Vec<Vec<f64>> {
    let d = model.n_coeffs();
    let mut population: Vec<Vec<f64>> = Vec::new();
    if let Some(c) = warm.filter(|c| c.len() == d && c.iter().all(|v| v.is_finite())) {
        let mut x: Vec<f64> = c.iter().zip(p.scales).map(|(c, s)| c / s).collect();
        if p.fit_initial_conditions {
            x.extend_from_slice(&[0.0, 0.0]);
        }
        population.push(x);
    }
    // The bias assumes the window's dominant frequency is the natural one, which holds for free
    // and self-excited vibration but not for a forced or parametrically excited model (one that
    // depends on t): there it would pull the search to the forcing frequency.
    if !p.fft_bias || model.uses_time() {
        return population;
    }
    let Some(target) = p.target else {
        return population;
    };
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed ^ INITIAL_CONDITIONS_STREAM);
    let biased = biased_population(
        model,
        p.scales,
        target,
        p.population / 2,
        p.seed,
        p.t0,
        p.y_scale,
        p.v_scale,
    );
    for mut x in biased {
        if p.fit_initial_conditions {
            // Fitted initial conditions keep uniform random starts.
            x.extend_from_slice(&[rng.random_range(-1.0..=1.0), rng.random_range(-1.0..=1.0)]);
        }
        population.push(x);
    }
    population
}
