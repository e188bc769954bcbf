//! Nelder-Mead simplex minimisation with adaptive coefficients (Gao and Han 2012), used to polish
//! the DE winner.
//!
//! Written by hand rather than taken from argmin: the polish runs inside the daemon's workers for
//! every window, on the same [`Objective`] trait and workspace as the DE (no second abstraction,
//! no per-iteration allocation), and its budget is counted in objective evaluations, which is what
//! the benchmark compares with the chapter. The algorithm is 60 lines and tested below.

use crate::de::Objective;

/// Result of a polish.
#[derive(Debug, Clone, PartialEq)]
pub struct Polished {
    /// Best point.
    pub x: Vec<f64>,
    /// Its cost.
    pub cost: f64,
    /// Objective evaluations spent.
    pub evaluations: usize,
}

/// Minimises `objective` from `x0` with an initial simplex of relative size `step` (absolute
/// `step` for zero coordinates), within `max_evaluations`. Stops early when the simplex's cost
/// spread falls below `ftol * |best|` and its size below `xtol` relative to `|x|`.
pub fn minimize<O: Objective>(
    objective: &O,
    x0: &[f64],
    step: f64,
    max_evaluations: usize,
    ftol: f64,
    xtol: f64,
) -> Polished {
    let d = x0.len();
    let mut ws = objective.workspace();
    let mut eval = |x: &[f64], n: &mut usize| {
        *n += 1;
        let c = objective.cost(x, f64::INFINITY, &mut ws);
        if c.is_nan() {
            f64::INFINITY
        } else {
            c
        }
    };
    let mut evaluations = 0;
    if d == 0 {
        let cost = eval(x0, &mut evaluations);
        return Polished {
            x: x0.to_vec(),
            cost,
            evaluations,
        };
    }
    let df = d as f64;
    // Gao and Han's dimension-adapted coefficients (equal to the classic 1, 2, 0.5, 0.5 for d = 2).
    let (alpha, beta, gamma, delta) = (1.0, 1.0 + 2.0 / df, 0.75 - 0.5 / df, 1.0 - 1.0 / df);
    let mut simplex: Vec<Vec<f64>> = vec![x0.to_vec(); d + 1];
    for (j, vertex) in simplex.iter_mut().skip(1).enumerate() {
        vertex[j] = if x0[j] != 0.0 {
            x0[j] * (1.0 + step)
        } else {
            step
        };
    }
    let mut costs: Vec<f64> = simplex.iter().map(|x| eval(x, &mut evaluations)).collect();
    let mut order: Vec<usize> = (0..=d).collect();
    let (mut centroid, mut xr, mut xe) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    while evaluations < max_evaluations {
        order.sort_by(|&a, &b| costs[a].total_cmp(&costs[b]));
        let (best, worst, second) = (order[0], order[d], order[d - 1]);
        let spread = costs[worst] - costs[best];
        let size = simplex
            .iter()
            .flat_map(|v| v.iter().zip(&simplex[best]).map(|(a, b)| (a - b).abs()))
            .fold(0.0, f64::max);
        let scale = simplex[best]
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
            .max(1e-300);
        if spread.is_finite()
            && spread <= ftol * costs[best].abs().max(1e-300)
            && size <= xtol * scale
        {
            break;
        }
        centroid.iter_mut().for_each(|c| *c = 0.0);
        for &k in &order[..d] {
            for (c, v) in centroid.iter_mut().zip(&simplex[k]) {
                *c += v / df;
            }
        }
        let towards = |out: &mut [f64], coef: f64, from: &[f64]| {
            for ((o, c), w) in out.iter_mut().zip(&centroid).zip(from) {
                *o = c + coef * (c - w);
            }
        };
        towards(&mut xr, alpha, &simplex[worst]);
        let fr = eval(&xr, &mut evaluations);
        if fr < costs[best] {
            towards(&mut xe, alpha * beta, &simplex[worst]);
            let fe = eval(&xe, &mut evaluations);
            if fe < fr {
                simplex[worst].copy_from_slice(&xe);
                costs[worst] = fe;
            } else {
                simplex[worst].copy_from_slice(&xr);
                costs[worst] = fr;
            }
        } else if fr < costs[second] {
            simplex[worst].copy_from_slice(&xr);
            costs[worst] = fr;
        } else {
            // Contraction, outside or inside.
            let outside = fr < costs[worst];
            let coef = if outside { gamma * alpha } else { -gamma };
            towards(&mut xe, coef, &simplex[worst]);
            let fc = eval(&xe, &mut evaluations);
            if fc < fr.min(costs[worst]) {
                simplex[worst].copy_from_slice(&xe);
                costs[worst] = fc;
            } else {
                // Shrink towards the best vertex.
                let xb = simplex[best].clone();
                for k in order.iter().skip(1).copied() {
                    for (v, b) in simplex[k].iter_mut().zip(&xb) {
                        *v = b + delta * (*v - b);
                    }
                    costs[k] = eval(&simplex[k], &mut evaluations);
                }
            }
        }
    }
    let best = (0..=d)
        .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
        .unwrap_or(0);
    Polished {
        x: simplex[best].clone(),
        cost: costs[best],
        evaluations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Quadratic;
    impl Objective for Quadratic {
        type Workspace = ();
        fn dimension(&self) -> usize {
            3
        }
        fn workspace(&self) {}
        fn cost(&self, x: &[f64], _: f64, _: &mut ()) -> f64 {
            (x[0] - 1.0).powi(2) + 10.0 * (x[1] + 2.0).powi(2) + 0.1 * (x[2] - 0.5).powi(2)
        }
    }

    #[test]
    fn converges_on_a_quadratic() {
        let p = minimize(&Quadratic, &[0.0, 0.0, 0.0], 0.5, 2000, 1e-14, 1e-10);
        assert!(p.cost < 1e-12, "{p:?}");
        assert!(
            (p.x[0] - 1.0).abs() < 1e-5
                && (p.x[1] + 2.0).abs() < 1e-5
                && (p.x[2] - 0.5).abs() < 1e-5
        );
        assert!(p.evaluations <= 2000);
    }

    #[test]
    fn respects_the_budget_and_never_gets_worse() {
        let p = minimize(&Quadratic, &[3.0, 3.0, 3.0], 0.1, 30, 0.0, 0.0);
        assert!(
            p.evaluations <= 30 + 3,
            "a shrink may finish its sweep: {}",
            p.evaluations
        );
        let start = Quadratic.cost(&[3.0, 3.0, 3.0], f64::INFINITY, &mut ());
        assert!(p.cost <= start);
    }

    #[test]
    fn absolute_value_objective() {
        // Non-smooth at the optimum, like the mean absolute error of a noise-free fit.
        struct Abs;
        impl Objective for Abs {
            type Workspace = ();
            fn dimension(&self) -> usize {
                2
            }
            fn workspace(&self) {}
            fn cost(&self, x: &[f64], _: f64, _: &mut ()) -> f64 {
                (x[0] - 0.3).abs() + (x[1] + 0.7).abs()
            }
        }
        let p = minimize(&Abs, &[1.0, 1.0], 0.2, 1000, 1e-12, 1e-12);
        assert!(p.cost < 1e-6, "{p:?}");
    }
}
