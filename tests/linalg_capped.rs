//! The capped decompositions of `gatewatch::linalg` on the matrix that made nalgebra's uncapped
//! Schur iteration spin for ever: SSI-COV's 16 x 16 state matrix of one window of
//! `bench warning --seeds 1 --first-seed 10 --gates lab --scenarios slow-drift
//! --ssi-reference common` (session 53; `linalg_capped/stuck_schur.json`, column-major).
//! `nalgebra::Matrix::complex_eigenvalues` never returned on it.

use gatewatch::linalg;
use nalgebra::DMatrix;

fn stuck() -> DMatrix<f64> {
    let text = include_str!("linalg_capped/stuck_schur.json");
    let v: Vec<f64> = serde_json::from_str(text).expect("a JSON array of numbers");
    assert_eq!(v.len(), 256);
    DMatrix::from_column_slice(16, 16, &v)
}

#[test]
fn the_stuck_state_matrix_returns_instead_of_spinning() {
    let a = stuck();
    assert!(a.iter().all(|v| v.is_finite()), "a finite matrix");
    // Its Schur iteration does not converge within LAPACK's cap: no eigenvalues, so SSI-COV
    // takes no pole from this model order, and the worker goes on.
    assert!(linalg::complex_eigenvalues(a.clone()).is_none());
    // Its singular values are ordinary: the matrix is not degenerate, only the QR iteration.
    let sv = linalg::svd(a, false, false)
        .expect("the SVD converges")
        .singular_values;
    assert!(sv.max() < 2.0 && sv.min() > 1e-3, "{sv}");
}
