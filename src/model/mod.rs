//! The model language: an equation of motion as an engineer writes it, compiled once.
//!
//! ```text
//! ydd + (c1 + c2*y + c3*y^2)*yd + y = 0
//! c1*ydd + c2*yd + c3*y = c4*sin(c5*t)
//! ```
//!
//! Symbols `t`, `y`, `yd`, `ydd`, unknown coefficients `c1..cN` and named known constants
//! (`--param k=81360`); operators `+ - * / ^`, unary minus, parentheses; functions
//! `sin cos tan exp ln sqrt abs sign tanh min max step`. The equation must be linear in `ydd`:
//! it is rearranged as `M(t, y, yd) * ydd + R(t, y, yd) = 0` and the engine integrates
//! `ydd = -R / M`.
//!
//! A [`Model`] evaluates without allocation or name lookups, takes `&self` only, and is
//! `Send + Sync`, so one compiled model serves every thread of a parallel search.

use crate::ode::System;

/// A parse or compile error, with the 1-based column where it was found when there is one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ModelError {
    /// The whole message, e.g. `unknown symbol 'z' at column 14`.
    pub message: String,
    /// 1-based character column in the equation text, when the error has a place.
    pub column: Option<usize>,
}

/// A compiled equation of motion `M(t, y, yd) * ydd + R(t, y, yd) = 0`.
#[derive(Debug, Clone)]
pub struct Model {
    _private: (),
}

impl Model {
    /// Parses and compiles `equation`. `params` are the known named constants.
    pub fn parse(_equation: &str, _params: &[(String, f64)]) -> Result<Model, ModelError> {
        todo!("model language not yet implemented")
    }

    /// The equation text as given.
    pub fn equation(&self) -> &str {
        todo!()
    }

    /// Number of unknown coefficients `N` (`c1..cN`).
    pub fn n_coeffs(&self) -> usize {
        todo!()
    }

    /// Whether `t` appears in the equation (the system is non-autonomous).
    pub fn uses_time(&self) -> bool {
        todo!()
    }

    /// `M(t, y, yd)`, the factor of `ydd`. `c.len()` must be `n_coeffs()`.
    pub fn mass(&self, _t: f64, _y: f64, _yd: f64, _c: &[f64]) -> f64 {
        todo!()
    }

    /// `R(t, y, yd)`, everything else moved to the left-hand side.
    pub fn residual(&self, _t: f64, _y: f64, _yd: f64, _c: &[f64]) -> f64 {
        todo!()
    }

    /// `ydd = -R / M` (NaN or infinite when `M` vanishes; the integrators report that).
    pub fn accel(&self, _t: f64, _y: f64, _yd: f64, _c: &[f64]) -> f64 {
        todo!()
    }

    /// The equation with the coefficients' values put in, e.g.
    /// `ydd + (-0.1434 + 0*y)*yd + y = 0`, for reports.
    pub fn substitute(&self, _c: &[f64]) -> String {
        todo!()
    }
}

/// A model with a coefficient vector bound to it: the first-order system `[y, yd]' = [yd, ydd]`.
#[derive(Debug, Clone, Copy)]
pub struct Bound<'a> {
    /// The compiled model.
    pub model: &'a Model,
    /// Its coefficients `c1..cN`.
    pub coeffs: &'a [f64],
}

impl System<2> for Bound<'_> {
    #[inline]
    fn rhs(&self, t: f64, s: &[f64; 2], ds: &mut [f64; 2]) {
        ds[0] = s[1];
        ds[1] = self.model.accel(t, s[0], s[1], self.coeffs);
    }
}
