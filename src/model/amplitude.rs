//! Amplitude exponents: how each coefficient changes with the unit of the displacement.
//!
//! `ydd + (c1 + c2*y^2)*yd + y = 0` has the solution `y(t)` for `(c1, c2)` exactly when it has
//! `lambda*y(t)` for `(c1, c2/lambda^2)`: the same record written in millimetres instead of
//! metres is the same gate with `c2` a million times smaller. The search starts its
//! coefficients in `[-1, 1]`, where the chapter's records (amplitudes of order one) put them;
//! on a record a thousand times larger it draws `c2` a million times too large, the equation
//! turns stiff, and no trial integrates (a record of amplitude 1e4 failed so). Knowing each
//! coefficient's exponent `p_j` (here `(0, -2)`), the identification searches `c_j / u^p_j`
//! for the record's unit `u` instead: the problem it then solves is the unit-scale one.
//!
//! The exponents are found numerically, from the compiled model alone, like the scale groups
//! of [`super::scaling`] and for the same reasons: with `a(t, y, yd; c) = -R/M`, the exponents
//! `p` are right when `a(t, lambda*y, lambda*yd; lambda^p * c) = lambda * a(t, y, yd; c)` at
//! random points, for several `lambda`. Candidates come from the degrees of homogeneity of
//! each coefficient's term: where `E = M*ydd + R` without its coefficients (`ydd + y` above)
//! has degree `q`, a coefficient whose term `dE/dc_j` has degree `d_j` gets `p_j = q - d_j`;
//! a coefficient whose term does not depend on the state (`c4` in `c3*sin(c4*t)`, degree 0)
//! may instead keep its value (`p_j = 0`), and both choices are tried. A model with no such
//! exponents (a fixed `y^3` beside a fixed `y`: the record's scale is physical) has none, and
//! its coefficients are searched as given.

use super::Model;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Random test points.
const POINTS: usize = 24;
/// Fewest points with a finite, non-zero `(M, R)` for a verdict.
const MIN_FINITE_POINTS: usize = 8;
/// Scale factors of the verification: two powers of two and one that is not.
const LAMBDAS: [f64; 3] = [2.0, 0.125, 3.0];
/// Relative tolerance of the proportionality test (far above rounding).
const TOLERANCE: f64 = 1e-8;
/// Tolerance of a degree, and of its rounding to a multiple of 1/12 (halves, thirds and
/// quarters exactly): the degrees only propose exponents, the proportionality test decides.
const DEGREE_TOLERANCE: f64 = 1e-4;
/// Coefficients whose term is state-free and may keep their value, at most (`2^N` choices).
const MAX_STATE_FREE: usize = 8;

/// A test point: time, state `(y, yd, ydd)` and coefficients.
struct Point {
    t: f64,
    s: [f64; 3],
    c: Vec<f64>,
}

fn points(n: usize) -> Vec<Point> {
    let mut rng = ChaCha8Rng::seed_from_u64(0xa3b1);
    (0..POINTS)
        .map(|_| {
            let t = rng.random_range(0.0..10.0);
            let s = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let c = super::scaling::random_coefficients(&mut rng, n);
            Point { t, s, c }
        })
        .collect()
}

impl Model {
    /// `E = M*ydd + R` at a point.
    fn equation_at(&self, t: f64, [y, yd, ydd]: [f64; 3], c: &[f64]) -> f64 {
        self.mass(t, y, yd, c) * ydd + self.residual(t, y, yd, c)
    }

    /// How each coefficient scales with the unit of the displacement (see the module docs):
    /// exponents `p` such that `lambda*y(t)` solves the equation with `c_j * lambda^p_j` when
    /// `y(t)` solves it with `c`. `None` when the model has no such exponents (its solutions'
    /// size is physical) or when too few test points are finite.
    pub fn amplitude_exponents(&self) -> Option<Vec<f64>> {
        let n = self.n_coeffs();
        let pts = points(n);
        let zeros = vec![0.0; n];
        // The coefficient-free part's degree; 1 (linear coefficients keep their values) when
        // every term carries a coefficient.
        let q = match degree(&pts, |t, s, _| self.equation_at(t, s, &zeros)) {
            Degree::Of(q) => q,
            Degree::Zero => 1.0,
            Degree::None => return None,
        };
        let mut p = Vec::with_capacity(n);
        let mut state_free = Vec::new();
        for j in 0..n {
            let term = |t: f64, s: [f64; 3], c: &[f64]| {
                // A wide step: exact for a term linear in `c_j` (most are), and the fixed terms'
                // rounding (a stiffness of 1e5 beside a velocity cubed of 1e-4) stays small.
                let h = 0.5 * c[j].abs();
                let mut cp = c.to_vec();
                let mut cm = c.to_vec();
                cp[j] += h;
                cm[j] -= h;
                (self.equation_at(t, s, &cp) - self.equation_at(t, s, &cm)) / (2.0 * h)
            };
            match degree(&pts, term) {
                Degree::Of(d) => {
                    if d == 0.0 {
                        state_free.push(j);
                    }
                    p.push(q - d);
                }
                // A coefficient that changes nothing keeps its value.
                Degree::Zero => p.push(0.0),
                Degree::None => return None,
            }
        }
        state_free.truncate(MAX_STATE_FREE);
        // Fewest coefficients kept first: the exponents of the degrees, then one kept, ...
        let mut masks: Vec<u32> = (0..1u32 << state_free.len()).collect();
        masks.sort_by_key(|m| (m.count_ones(), *m));
        let mut trial = p.clone();
        for m in masks {
            for (k, &j) in state_free.iter().enumerate() {
                trial[j] = if m & (1 << k) != 0 { 0.0 } else { p[j] };
            }
            if self.scales_with_amplitude(&pts, &trial)? {
                return Some(trial);
            }
        }
        None
    }

    /// Whether `a(t, lambda*y, lambda*yd; lambda^p * c) = lambda * a(t, y, yd; c)` at the
    /// usable points for every test `lambda`; `None` when too few points are usable.
    fn scales_with_amplitude(&self, pts: &[Point], p: &[f64]) -> Option<bool> {
        let mut usable = 0;
        let mut scaled = vec![0.0; p.len()];
        for Point {
            t,
            s: [y, yd, _],
            c,
        } in pts
        {
            let (m, r) = (self.mass(*t, *y, *yd, c), self.residual(*t, *y, *yd, c));
            if !(m.is_finite() && r.is_finite()) || m == 0.0 {
                continue;
            }
            usable += 1;
            for lambda in LAMBDAS {
                for ((sc, cj), pj) in scaled.iter_mut().zip(c).zip(p) {
                    *sc = cj * lambda.powf(*pj);
                }
                let (ms, rs) = (
                    self.mass(*t, lambda * y, lambda * yd, &scaled),
                    self.residual(*t, lambda * y, lambda * yd, &scaled),
                );
                // -rs/ms = lambda * (-r/m): (ms, rs) parallel to (m, lambda*r).
                let det = (rs * m - lambda * r * ms).abs();
                let size = (rs * m).abs() + (lambda * r * ms).abs();
                // A NaN (an overflow) or a vanished mass counts as a change.
                let proportional = det <= TOLERANCE * size;
                if !proportional || ms == 0.0 {
                    return Some(false);
                }
            }
        }
        (usable >= MIN_FINITE_POINTS).then_some(true)
    }
}

/// The degree of homogeneity of `f` in the state.
#[derive(Debug, PartialEq)]
enum Degree {
    /// `f(t, lambda*s) = lambda^d * f(t, s)` at every usable point.
    Of(f64),
    /// `f` is 0 at every finite point.
    Zero,
    /// Not homogeneous, or too few finite points.
    None,
}

fn degree(pts: &[Point], f: impl Fn(f64, [f64; 3], &[f64]) -> f64) -> Degree {
    let mut found: Option<f64> = None;
    let (mut usable, mut zero) = (0, 0);
    for Point { t, s, c } in pts {
        let base = f(*t, *s, c);
        if !base.is_finite() {
            continue;
        }
        if base == 0.0 {
            zero += 1;
            continue;
        }
        for lambda in LAMBDAS {
            let v = f(*t, s.map(|x| lambda * x), c);
            // The sign must be kept (an odd function scaled by a positive factor) and the
            // ratio a power of lambda.
            if !(v.is_finite() && v.signum() == base.signum()) {
                return Degree::None;
            }
            let d = (v / base).ln() / lambda.ln();
            match found {
                None => found = Some(d),
                Some(d0) if (d - d0).abs() <= DEGREE_TOLERANCE * d0.abs().max(1.0) => {}
                Some(_) => return Degree::None,
            }
        }
        usable += 1;
    }
    match found {
        // A term that vanishes at some points and not at others is not a power law (|y|^d
        // vanishes only where y does, which random points miss).
        Some(d) if usable >= MIN_FINITE_POINTS && zero == 0 => {
            let twelfths = (12.0 * d).round() / 12.0;
            Degree::Of(if (d - twelfths).abs() <= DEGREE_TOLERANCE {
                twelfths
            } else {
                d
            })
        }
        None if zero >= MIN_FINITE_POINTS => Degree::Zero,
        _ => Degree::None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn exponents(eq: &str) -> Option<Vec<f64>> {
        Model::parse(eq, &[("k".to_string(), 81360.0)])
            .unwrap()
            .amplitude_exponents()
    }

    #[test]
    fn the_chapter_models_scale_their_nonlinear_coefficients() {
        assert_eq!(
            exponents("ydd + (c1 + c2*y^2)*yd + y = 0"),
            Some(vec![0.0, -2.0])
        );
        assert_eq!(
            exponents("c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0"),
            Some(vec![0.0, 0.0, -2.0])
        );
        assert_eq!(
            exponents("ydd + (c1 + c2*y + c3*y^2)*yd + y = 0"),
            Some(vec![0.0, -1.0, -2.0])
        );
        // Every term carries a coefficient: linear ones keep their values.
        assert_eq!(
            exponents("c1*ydd + c2*yd + c3*y + c4*y^3 = 0"),
            Some(vec![0.0, 0.0, 0.0, -2.0])
        );
    }

    #[test]
    fn a_forcing_amplitude_scales_and_its_frequency_does_not() {
        assert_eq!(
            exponents("ydd + c1*yd + y + c2*y^3 = c3*sin(c4*t)"),
            Some(vec![0.0, -2.0, 1.0, 0.0])
        );
        // Dry friction: its force does not grow with the amplitude.
        assert_eq!(exponents("ydd + c1*sign(yd) + y = 0"), Some(vec![1.0]));
        // Non-integer powers.
        assert_eq!(
            exponents("ydd + c1*abs(yd)^0.5*yd + y = 0"),
            Some(vec![-0.5])
        );
    }

    #[test]
    fn a_model_whose_amplitude_is_physical_has_none() {
        // Fixed linear and cubic stiffness: a larger record is a different gate.
        assert_eq!(exponents("ydd + c1*yd + y + y^3 = 0"), None);
        // A coefficient inside a non-homogeneous function of the state.
        assert_eq!(exponents("ydd + c1*yd + sin(c2*y) = 0"), None);
    }

    #[test]
    fn the_exponents_make_a_scaled_trajectory_a_solution() {
        // The acceleration at a scaled state with scaled coefficients is the scaled one.
        let m = Model::parse("ydd + (c1 + c2*y^2)*yd + y = c3*cos(c4*t)", &[]).unwrap();
        let p = m.amplitude_exponents().unwrap();
        let c = [-0.2, 0.4, 0.3, 1.7];
        let lambda: f64 = 1e4;
        let cs: Vec<f64> = c.iter().zip(&p).map(|(c, p)| c * lambda.powf(*p)).collect();
        for (t, y, yd) in [(0.3, 0.5, -0.2), (2.0, -1.5, 0.7)] {
            let a = -m.residual(t, y, yd, &c) / m.mass(t, y, yd, &c);
            let b = -m.residual(t, lambda * y, lambda * yd, &cs)
                / m.mass(t, lambda * y, lambda * yd, &cs);
            assert!(
                (b - lambda * a).abs() <= 1e-9 * b.abs(),
                "{b} vs {}",
                lambda * a
            );
        }
    }
}
