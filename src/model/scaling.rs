//! Scale-free structures: coefficients the equation of motion determines only up to a common
//! factor.
//!
//! `c1*ydd + c2*yd + c3*y = c4*sin(c5*t)` has the same solutions for `(c1, c2, c3, c4)` and
//! `(2 c1, 2 c2, 2 c3, 2 c4)`: the acceleration `-R/M` does not change when `M` and `R` are
//! multiplied by the same number. A search on displacement data then returns any point of a
//! line (the fit is right, the numbers are arbitrary), so the coefficients have to be reported
//! normalised.
//!
//! The same search finds sign ambiguities that are not scale ones: in `c4*sin(c5*t)` the pair
//! `(c4, c5)` and `(-c4, -c5)` give the same force, so a search returns either; those groups
//! are reported as `sign_only` and normalised to a positive first member.
//!
//! Detection is numerical, from the compiled model alone: a subset `S` of the coefficients is
//! scale-free when scaling every `c_j`, `j` in `S`, by `lambda` leaves `(M, R)` proportional at
//! random points `(t, y, yd, c)`, for several `lambda`. Why numerical rather than symbolic: it
//! covers every way the language can express the invariance (a common factor, a ratio
//! `c1/c2`, a mass written `(c1 + c2)*ydd`), and it needs no second copy of the algebra the
//! parser already did. Why proportionality of `(M, R)` and not equality of `-R/M`: it does not
//! suffer when the acceleration is small by cancellation.

use super::Model;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Largest number of coefficients whose subsets are searched (`2^N` subsets); larger models
/// are not checked (no identifiable model of this project comes near).
pub const MAX_SCALE_SEARCH: usize = 12;

/// Random points each subset is tested at.
const POINTS: usize = 24;
/// Fewest points with a finite `(M, R)` for a verdict (a model undefined almost everywhere gets
/// none).
const MIN_FINITE_POINTS: usize = 8;
/// Scale factors tried: two exact powers of two and one that is not (so that a function
/// periodic in `log2 c` cannot pass).
const LAMBDAS: [f64; 3] = [2.0, 0.125, 3.0];
/// Relative tolerance of the proportionality test: far above rounding (about 1e-15 of the
/// products), far below any real change.
const TOLERANCE: f64 = 1e-8;

/// A set of coefficients the equation of motion determines only up to a common factor.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ScaleGroup {
    /// 0-based indices of the coefficients (`c1` is 0), ascending.
    pub members: Vec<usize>,
    /// The member reported as 1: the lowest-numbered member that multiplies `ydd` (it sets the
    /// mass), else the lowest-numbered member.
    pub fixed: usize,
    /// Whether a negative factor leaves the equation unchanged too; then the normalisation
    /// divides by the fixed coefficient (which becomes 1), otherwise by its magnitude (it
    /// becomes +1 or -1).
    pub sign_free: bool,
    /// The group is determined only up to a common sign, not a factor (`(c4, c5)` of
    /// `c4*sin(c5*t)`): the normalisation flips the group's signs so that the fixed member
    /// (its lowest-numbered member not fixed by a scale group) is positive.
    pub sign_only: bool,
}

impl ScaleGroup {
    /// `coefficients` with this group divided by its fixed member (see [`ScaleGroup::sign_free`]);
    /// `None` when that member is 0 or not finite (no normalisation exists).
    pub fn normalize(&self, coefficients: &[f64]) -> Option<Vec<f64>> {
        let pivot = *coefficients.get(self.fixed)?;
        let divisor = if self.sign_only {
            pivot.signum() * (pivot != 0.0) as u8 as f64
        } else if self.sign_free {
            pivot
        } else {
            pivot.abs()
        };
        if divisor == 0.0 || !divisor.is_finite() {
            return None;
        }
        let mut out = coefficients.to_vec();
        for &j in &self.members {
            out[j] /= divisor;
        }
        Some(out)
    }
}

/// Random test points `(t, y, yd, c)` for a model with `n` coefficients, seeded so the
/// detection is deterministic.
fn points(n: usize) -> Vec<(f64, f64, f64, Vec<f64>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5ca1e);
    (0..POINTS)
        .map(|_| {
            let t = rng.random_range(0.0..10.0);
            let y = rng.random_range(-1.0..1.0);
            let yd = rng.random_range(-1.0..1.0);
            let c = random_coefficients(&mut rng, n);
            (t, y, yd, c)
        })
        .collect()
}

/// `n` test coefficients: magnitudes away from 0 (from 0.5 to 2) with either sign, since a
/// coefficient near 0 hides its terms.
pub(super) fn random_coefficients(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let m: f64 = rng.random_range(0.5..2.0);
            if rng.random_bool(0.5) {
                m
            } else {
                -m
            }
        })
        .collect()
}

/// Whether scaling the coefficients in `members` by each of `lambdas` keeps `(M, R)`
/// proportional at the usable points; `None` when too few points are usable.
fn invariant(
    model: &Model,
    pts: &[(f64, f64, f64, Vec<f64>)],
    members: &[usize],
    lambdas: &[f64],
) -> Option<bool> {
    let mut usable = 0;
    let mut scaled = Vec::new();
    for (t, y, yd, c) in pts {
        let (m, r) = (model.mass(*t, *y, *yd, c), model.residual(*t, *y, *yd, c));
        if !(m.is_finite() && r.is_finite()) || (m == 0.0 && r == 0.0) {
            continue;
        }
        usable += 1;
        for &lambda in lambdas {
            scaled.clear();
            scaled.extend_from_slice(c);
            for &j in members {
                scaled[j] *= lambda;
            }
            let (ms, rs) = (
                model.mass(*t, *y, *yd, &scaled),
                model.residual(*t, *y, *yd, &scaled),
            );
            // (ms, rs) parallel to (m, r): the 2x2 determinant vanishes.
            let det = (ms * r - rs * m).abs();
            let size = (ms * r).abs() + (rs * m).abs();
            // A NaN determinant (an overflow) counts as a change too.
            let proportional = det <= TOLERANCE * size;
            if !proportional || (ms == 0.0 && rs == 0.0) {
                return Some(false);
            }
        }
    }
    (usable >= MIN_FINITE_POINTS).then_some(true)
}

impl Model {
    /// The groups of coefficients the equation determines only up to a common factor (see the
    /// module docs), smallest first; empty for most models. Only groups of two or more are
    /// reported (a lone coefficient whose size does not matter is not a scale ambiguity of the
    /// reported numbers), and groups are disjoint. Models with more than [`MAX_SCALE_SEARCH`]
    /// coefficients are not searched.
    pub fn scale_groups(&self) -> Vec<ScaleGroup> {
        let n = self.n_coeffs();
        if !(2..=MAX_SCALE_SEARCH).contains(&n) {
            return Vec::new();
        }
        let pts = points(n);
        let mut groups: Vec<ScaleGroup> = Vec::new();
        let mut taken = 0u32;
        // Subsets by size, so that each group found is minimal; a subset touching a group
        // already found is a union or an overlap, not a new ambiguity.
        let mut subsets: Vec<u32> = (1u32..(1 << n)).filter(|s| s.count_ones() >= 2).collect();
        subsets.sort_by_key(|s| (s.count_ones(), *s));
        for s in subsets {
            if s & taken != 0 {
                continue;
            }
            let members: Vec<usize> = (0..n).filter(|j| s & (1 << j) != 0).collect();
            if invariant(self, &pts, &members, &LAMBDAS) != Some(true) {
                continue;
            }
            let sign_free = invariant(self, &pts, &members, &[-1.0, -2.5]) == Some(true);
            let fixed = members
                .iter()
                .copied()
                .find(|&j| self.moves_mass(&pts, j))
                .unwrap_or(members[0]);
            taken |= s;
            groups.push(ScaleGroup {
                members,
                fixed,
                sign_free,
                sign_only: false,
            });
        }
        self.sign_groups(&pts, &mut groups);
        groups
    }

    /// Appends the sign ambiguities (see the module docs): the smallest subsets whose sign flip
    /// leaves `(M, R)` proportional and that are not combinations (symmetric differences) of
    /// flips already accounted for, the sign-free scale groups included.
    fn sign_groups(&self, pts: &[(f64, f64, f64, Vec<f64>)], groups: &mut Vec<ScaleGroup>) {
        let n = self.n_coeffs();
        let fixed_by_scale: Vec<usize> = groups.iter().map(|g| g.fixed).collect();
        // The GF(2) span of the flips known so far (as bit masks).
        let mut span: Vec<u32> = vec![0];
        let add = |span: &mut Vec<u32>, mask: u32| {
            if !span.contains(&mask) {
                let more: Vec<u32> = span.iter().map(|x| x ^ mask).collect();
                span.extend(more);
            }
        };
        for g in groups.iter().filter(|g| g.sign_free) {
            add(&mut span, g.members.iter().fold(0, |m, &j| m | (1 << j)));
        }
        let mut subsets: Vec<u32> = (1u32..(1 << n)).collect();
        subsets.sort_by_key(|s| (s.count_ones(), *s));
        for s in subsets {
            if span.contains(&s) {
                continue;
            }
            let members: Vec<usize> = (0..n).filter(|j| s & (1 << j) != 0).collect();
            if invariant(self, pts, &members, &[-1.0]) != Some(true) {
                continue;
            }
            let fixed = members
                .iter()
                .copied()
                .find(|j| !fixed_by_scale.contains(j))
                .unwrap_or(members[0]);
            add(&mut span, s);
            groups.push(ScaleGroup {
                members,
                fixed,
                sign_free: false,
                sign_only: true,
            });
        }
    }

    /// Whether coefficient `j` changes `M` (multiplies `ydd`) at some test point.
    fn moves_mass(&self, pts: &[(f64, f64, f64, Vec<f64>)], j: usize) -> bool {
        pts.iter().any(|(t, y, yd, c)| {
            let mut c2 = c.clone();
            c2[j] *= 1.5;
            let (a, b) = (self.mass(*t, *y, *yd, c), self.mass(*t, *y, *yd, &c2));
            a.is_finite() && b.is_finite() && (a - b).abs() > 1e-12 * a.abs().max(b.abs())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn groups(eq: &str) -> Vec<ScaleGroup> {
        Model::parse(eq, &[("k".to_string(), 81360.0)])
            .unwrap()
            .scale_groups()
    }

    #[test]
    fn the_forced_linear_structure_is_scale_free_in_c1_to_c4() {
        let g = groups("c1*ydd + c2*yd + c3*y = c4*sin(c5*t)");
        assert_eq!(
            g,
            vec![
                ScaleGroup {
                    members: vec![0, 1, 2, 3],
                    fixed: 0,
                    sign_free: true,
                    sign_only: false,
                },
                // sin(c5*t) is odd: (c4, c5) and (-c4, -c5) give the same force
                ScaleGroup {
                    members: vec![3, 4],
                    fixed: 3,
                    sign_free: false,
                    sign_only: true,
                }
            ]
        );
    }

    #[test]
    fn sign_groups_make_their_fixed_member_positive() {
        let g = groups("ydd + c1*yd + c2*y + c3*y^3 = c4*sin(c5*t)");
        assert_eq!(g.len(), 1);
        assert_eq!((g[0].members.clone(), g[0].fixed), (vec![3, 4], 3));
        assert!(g[0].sign_only);
        let n = g[0].normalize(&[0.1, 1.0, 0.5, -3.0, -2.2]).unwrap();
        assert_eq!(n, vec![0.1, 1.0, 0.5, 3.0, 2.2]);
        let n = g[0].normalize(&[0.1, 1.0, 0.5, 3.0, 2.2]).unwrap();
        assert_eq!(n, vec![0.1, 1.0, 0.5, 3.0, 2.2]);
        assert_eq!(g[0].normalize(&[0.1, 1.0, 0.5, 0.0, 2.2]), None);
        // an even function of a lone coefficient is a sign ambiguity of one
        let g = groups("ydd + c1^2*yd + c2*y = 0");
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].members, vec![0]);
    }

    #[test]
    fn other_forms_of_the_ambiguity_are_found() {
        // A ratio (degree 0), and a mass that is not the first coefficient.
        let g = groups("ydd + (c1/c2)*yd + y = 0");
        assert_eq!(g.len(), 1);
        assert_eq!(g[0].members, vec![0, 1]);
        assert_eq!(g[0].fixed, 0);
        let g = groups("c2*yd + c3*y + c1*ydd = 0");
        assert_eq!(g[0].members, vec![0, 1, 2]);
        assert_eq!(g[0].fixed, 0);
        let g = groups("c3*ydd + c1*yd + c2*y = 0");
        assert_eq!(g[0].fixed, 2, "the coefficient of ydd is fixed");
        // Only positively homogeneous: the sign matters.
        let g = groups("c1*ydd + abs(c2)*yd + c2*y = 0");
        assert_eq!(g[0].members, vec![0, 1]);
        assert!(!g[0].sign_free);
    }

    #[test]
    fn identifiable_structures_have_no_group() {
        for eq in [
            "ydd + c1*yd + y = 0",
            "ydd + (c1 + c2*y)*yd + y = 0",
            "ydd + (c1 + c2*y + c3*y^2)*yd + y = 0",
            "ydd + c1*(y^2 - 1)*yd + c2*y = 0",
            "c1*ydd + (c2 + c3*yd^2)*yd + k*y = 0",
            "c1*ydd + c2*yd + k*y = 0",
            "ydd + c1*yd + c2*y = c2*c3",
        ] {
            assert_eq!(groups(eq), vec![], "{eq}");
        }
    }

    #[test]
    fn normalisation_divides_the_group_by_its_fixed_member() {
        let g = ScaleGroup {
            members: vec![0, 1, 2, 3],
            fixed: 0,
            sign_free: true,
            sign_only: false,
        };
        let n = g.normalize(&[-5.0, -0.7, -0.6, -6.0, 2.2]).unwrap();
        for (got, want) in n.iter().zip([1.0, 0.14, 0.12, 1.2, 2.2]) {
            approx::assert_relative_eq!(*got, want, max_relative = 1e-15);
        }
        assert_eq!(g.normalize(&[0.0, 1.0, 1.0, 1.0, 1.0]), None);
        let g = ScaleGroup {
            sign_free: false,
            ..g
        };
        assert_eq!(g.normalize(&[-2.0, 1.0, 1.0, 1.0, 1.0]).unwrap()[0], -1.0);
    }
}
