//! Matrix decompositions that always return: nalgebra's, with an iteration cap.
//!
//! Why: `Matrix::complex_eigenvalues`, `SymmetricEigen::new` and `Matrix::svd` iterate until
//! they converge, with no cap (`max_niter = 0`). One window of `bench warning` (the lab gate's
//! slow drift, seed 10, with `ssi_reference = "common"`) gave SSI-COV a state matrix whose Schur
//! iteration never converged: the worker analysing it spun at 100 % for ever, and a daemon would
//! have lost that worker and every later window of the gate. The cap is LAPACK's for the
//! Hessenberg QR (`dhseqr`: 30 sweeps per row, at least 300), generous for the small matrices here
//! (at most a few dozen rows); a decomposition that exhausts it, or a matrix with a NaN or an
//! infinity, gives `None`, which each caller reads as "no estimate from this matrix".

use nalgebra::{DMatrix, Schur, SymmetricEigen, SVD};
use rustfft::num_complex::Complex;

/// Iteration cap for a square matrix of `n` rows: LAPACK's `30 * max(10, n)`.
pub fn max_iterations(n: usize) -> usize {
    30 * n.max(10)
}

fn finite(m: &DMatrix<f64>) -> bool {
    m.iter().all(|v| v.is_finite())
}

/// Eigenvalues of a square matrix (real Schur form), or `None`.
pub fn complex_eigenvalues(a: DMatrix<f64>) -> Option<Vec<Complex<f64>>> {
    if !finite(&a) || !a.is_square() {
        return None;
    }
    let cap = max_iterations(a.nrows());
    let schur = Schur::try_new(a, f64::EPSILON, cap)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}

/// Eigen-decomposition of a symmetric matrix (its lower triangle is read), or `None`.
pub fn symmetric_eigen(h: DMatrix<f64>) -> Option<SymmetricEigen<f64, nalgebra::Dyn>> {
    if !finite(&h) || !h.is_square() {
        return None;
    }
    let cap = max_iterations(h.nrows());
    SymmetricEigen::try_new(h, f64::EPSILON, cap)
}

/// Singular value decomposition, or `None`.
pub fn svd(
    m: DMatrix<f64>,
    compute_u: bool,
    compute_v: bool,
) -> Option<SVD<f64, nalgebra::Dyn, nalgebra::Dyn>> {
    if !finite(&m) {
        return None;
    }
    let cap = max_iterations(m.nrows().max(m.ncols()));
    SVD::try_new(m, compute_u, compute_v, f64::EPSILON, cap)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn eigenvalues_of_a_rotation_and_a_symmetric_matrix() {
        let (c, s) = (0.6_f64, 0.8_f64);
        let a = DMatrix::from_row_slice(2, 2, &[c, -s, s, c]);
        let mut z = complex_eigenvalues(a).expect("converges");
        z.sort_by(|p, q| p.im.total_cmp(&q.im));
        assert_relative_eq!(z[1].re, c, epsilon = 1e-12);
        assert_relative_eq!(z[1].im, s, epsilon = 1e-12);
        let h = DMatrix::from_row_slice(2, 2, &[2.0, 1.0, 1.0, 2.0]);
        let mut e: Vec<f64> = symmetric_eigen(h)
            .expect("converges")
            .eigenvalues
            .iter()
            .copied()
            .collect();
        e.sort_by(f64::total_cmp);
        assert_relative_eq!(e[0], 1.0, epsilon = 1e-12);
        assert_relative_eq!(e[1], 3.0, epsilon = 1e-12);
        let m = DMatrix::from_row_slice(3, 2, &[3.0, 0.0, 0.0, 4.0, 0.0, 0.0]);
        let sv = svd(m, true, true).expect("converges").singular_values;
        assert_relative_eq!(sv.max(), 4.0, epsilon = 1e-12);
        assert_relative_eq!(sv.min(), 3.0, epsilon = 1e-12);
    }

    #[test]
    fn non_finite_matrices_give_none_instead_of_spinning() {
        let mut a = DMatrix::<f64>::identity(4, 4);
        a[(2, 1)] = f64::NAN;
        assert!(complex_eigenvalues(a.clone()).is_none());
        assert!(symmetric_eigen(a.clone()).is_none());
        assert!(svd(a, true, true).is_none());
        let mut b = DMatrix::<f64>::identity(3, 3);
        b[(0, 2)] = f64::INFINITY;
        assert!(complex_eigenvalues(b).is_none());
        assert!(complex_eigenvalues(DMatrix::zeros(2, 3)).is_none());
    }
}
